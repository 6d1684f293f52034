"""Ablations: every setting of a grid trained with several seeds, logged as MLflow child runs.

The grid (``ablations.grid``, by default ``configs/ablations.yaml``) has the form of
:mod:`talkingface.stages.grid`. Each child trains only its ``mapping.method`` (the paper's
mapping unless the child sets a baseline) on the run's corpus and Motion Units, once per seed
(``ablations.seeds``), as tasks on ``cluster.scheduler``; each task logs its MLflow child run
(tags ``ablation.setting``, ``ablation.seed``, …) under the stage's parent run. The stage is
described by :data:`talkingface.stages.grid.ABLATIONS`.

Files (``runs/<name>/ablations/``): the children's folders (:mod:`talkingface.stages.grid`),
``replicates.csv`` (one row per child and seed) and ``results.csv`` (one row per child: the mean
over seeds of every figure, the 95 % interval of R, and the paired test of R against the
``paper`` setting, Holm-corrected over the settings: :mod:`analysis.replicates`).

The look-ahead curve (issue 13): the children named ``lookahead-*`` vary only the look-ahead
(``mapping.context_forward``) and the window alignment; each row of ``results.csv`` carries its
algorithmic latency (:func:`mapping.features.algorithmic_latency_s` at the corpus's rate), and
``lookahead.png`` plots test R and closure on /p b m/ against it, per method, with the paper's
setting (``paper``, ``baseline-gru``: 3 frames, centred window) beside them.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.lines import Line2D

from analysis.figures import report_figure
from analysis.replicates import summarise_replicates
from face_model.corpus import read_manifest
from mapping.features import algorithmic_latency_s
from talkingface.paths import RunPaths
from talkingface.stages.base import write_csv
from talkingface.stages.child_runs import log_for
from talkingface.stages.grid import ABLATIONS, child_metrics, run_grid
from talkingface.stages.motion import training_corpus


def run_ablations(grid: dict, corpus_dir: Path, units_path: Path, out_dir: Path, *,
                  seeds: int = 1, scheduler: str = "local", workers: int = 0,
                  progress: bool = True, log=None, cache=None) -> list[dict]:
    """Train every child of an ablation grid and tabulate them.

    Parameters
    ----------
    grid : dict
        ``{child: Config}`` (:func:`talkingface.stages.grid_files.load_grid`).
    corpus_dir, units_path : Path
        The corpus and the ``motion_units.npz`` every child trains on.
    out_dir : Path
        The stage's folder: the children's folders, ``replicates.csv`` (one row per child and
        seed), ``results.csv`` (one row per child: means over seeds, 95 % intervals and the
        paired test against the reference setting) and, when the grid has a look-ahead curve,
        ``lookahead.png``.
    seeds : int
        Training seeds (replicates) per child.
    scheduler, workers : str, int
        Where the tasks run (``cluster.scheduler``) and how many processes (0: all cores).
    log : talkingface.stages.child_runs.ChildLog or None
        Where each task logs its MLflow child run (None: nowhere).
    cache : Path or None
        The content-keyed cache the tasks share.

    Returns
    -------
    list of dict
        The rows of ``results.csv``.
    """
    results = run_grid({name: (corpus_dir, units_path, c) for name, c in grid.items()}, out_dir,
                       seeds=seeds, scheduler=scheduler, workers=workers, desc="ablations",
                       progress=progress, log=log, stage=ABLATIONS.tag, cache=cache)
    sr = corpus_sample_rate(corpus_dir)
    reps = [{**_result_row(name, grid[name], res, sr), "replicate": k, "seed": res["seed"]}
            for (name, k), res in results.items()]
    write_csv(out_dir / "replicates.csv", reps)
    rows = summarise_replicates(reps, reference=reference_setting(grid))
    write_csv(out_dir / "results.csv", rows)
    curve = lookahead_rows(rows)
    if curve:
        lookahead_figure(curve, out_dir / "lookahead.png")
    return rows


def reference_setting(grid) -> str:
    """The setting the others are tested against: ``paper`` if the grid has it, else its first
    child (:meth:`talkingface.stages.grid.GridStage.reference_child`)."""
    return ABLATIONS.reference_child(grid)


def corpus_sample_rate(corpus_dir) -> int:
    """The sample rate of a corpus's first utterance (its manifest), Hz."""
    rows = read_manifest(Path(corpus_dir) / "manifest.csv", ("sample_rate",))
    return int(rows[0]["sample_rate"])


def _result_row(name: str, cfg, res: dict, sample_rate: int) -> dict:
    m = cfg.mapping
    metrics = child_metrics(res["summary"], m.method)
    row = {"setting": name, "method": m.method, "n_classes": m.n_classes,
           "context": f"{m.context_back}+1+{m.context_forward}", "n_mfcc": m.n_mfcc,
           "deltas": m.deltas, "hidden": f"{m.hidden_min}-{m.hidden_max}",
           "expression_model": m.expression_model, "look_ahead": m.context_forward,
           "window_align": m.window_align,
           "latency_ms": 1000 * algorithmic_latency_s(m.context_forward, sample_rate,
                                                      align=m.window_align)}
    for split in m.splits:
        row[f"{split}_R"] = metrics.get(f"{split}.mean_test_R", np.nan)
        row[f"{split}_MSE"] = metrics.get(f"{split}.mean_test_MSE", np.nan)
        row[f"{split}_LVE"] = metrics.get(f"{split}.mean_test_LVE", np.nan)
        row[f"{split}_closure"] = metrics.get(f"{split}.mean_test_closure", np.nan)
        row[f"{split}_gate_acc"] = metrics.get(f"{split}.gate.neutral_test", np.nan)
    row["seconds"] = res["seconds"]
    return row


PAPER_POINTS = ("paper", "baseline-gru")  # the paper's 3 frames with a centred window


def lookahead_rows(rows: list[dict]) -> list[dict]:
    """The rows of the look-ahead curve: the ``lookahead-*`` children and, beside them, the
    paper's setting of the same methods; none when the grid has no ``lookahead-*`` child."""
    curve = [r for r in rows if str(r["setting"]).startswith("lookahead-")]
    methods = {r["method"] for r in curve}
    return curve + [r for r in rows if r["setting"] in PAPER_POINTS and r["method"] in methods]


def lookahead_figure(curve: list[dict], path: Path, split: str = "utterance", *,
                     width: float = 1.0) -> Path:
    """Test R and /p b m/ closure against algorithmic latency (ms), one line per method (the
    ``lookahead-*`` children: right-aligned window, and centred with no frame of look-ahead)
    with their 95 % intervals over seeds, and the paper's setting as a marker."""
    with report_figure(path, width=width, height_in=2.9) as fig:
        axes = fig.subplots(1, 2)
        for ax, key, label in ((axes[0], f"{split}_R", "test R (Eq. 6)"),
                               (axes[1], f"{split}_closure",
                                "/p b m/ closed (fraction)")):
            for method in sorted({r["method"] for r in curve}):
                pts = sorted((float(r["latency_ms"]), float(r[key]),
                              float(r.get(f"{key}_ci95") or "nan")) for r in curve
                             if r["method"] == method
                             and str(r["setting"]).startswith("lookahead-"))
                line = None
                if pts:  # with the 95 % interval over seeds where there is one
                    x, y, ci = map(np.asarray, zip(*pts))
                    line = ax.errorbar(x, y, yerr=np.where(np.isfinite(ci), ci, 0), marker="o",
                                       capsize=2, label=method).lines[0]
                for r in curve:
                    if r["method"] == method and r["setting"] in PAPER_POINTS:
                        ax.plot(float(r["latency_ms"]), float(r[key]), marker="*",
                                markersize=10, color=line.get_color() if line else None,
                                linestyle="none")
            ax.set_xlabel("algorithmic latency (ms)")
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
        handles, labels = axes[0].get_legend_handles_labels()
        handles.append(Line2D([], [], marker="*", markersize=10, color="k", linestyle="none"))
        labels.append("the paper's window (centred), in its method's colour")
        fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 4))
        fig.suptitle(f"Accuracy against look-ahead ({split} split)")
    return Path(path)


def ablate(paths: RunPaths, cfg) -> dict:
    """Every setting of the ablation grid trained on the run's training corpus, with
    ``ablations.seeds`` seeds each."""
    grid = ABLATIONS.children(cfg)
    rows = run_ablations(grid, training_corpus(paths, cfg), paths.units_model, paths.ablations,
                         seeds=ABLATIONS.seeds(cfg), scheduler=cfg.cluster.scheduler,
                         workers=cfg.ablations.workers, progress=True,
                         log=log_for(ABLATIONS.name), cache=paths.cache)
    return {"grid": str(ABLATIONS.grid_path(cfg)), "children": list(grid), "rows": rows}
