"""Where Table II stands (issue 13, part 4): the ``ceiling`` stage.

Our test R on the utterance split is far below the paper's 0.968. This stage measures why, one
step at a time, each a child of the grid ``ceiling.grid`` (by default ``configs/ceiling.yaml``,
the form of the ablation grid, :func:`talkingface.stages.grid_files.load_grid`): the run's own
setting, then each nuisance of the corpus switched off in turn (brow motion, marker noise, head
motion, the randomness of the expressions' onset and intensity), all of them together, and
the oracle that reads the true phones and their timing instead of the audio
(``mapping.gate_front_end: labels``): the ceiling of any audio model on that corpus. One step
goes the other way, toward the paper's data: ``tracked`` learns from the MUPs the MU-constrained
tracker recovers from rendered video of the corpus (``mapping.visual_source: tracked``), as the
paper's did, and is measured against them, as the paper's was.

A child that changes ``synth`` gets a corpus of its own (the run's seed and sentences, its
nuisances) and Motion Units fitted on it, as a replication would; a child that reads tracked MUPs
gets a tracked copy of its corpus; the others train on the run's training corpus and Motion
Units. Each child trains only ``mapping.method`` on the paper's frame split and
the utterance split (:func:`talkingface.stages.grid.run_child`), with ``ceiling.seeds``
seeds; ``results.csv`` has their means, the 95 % interval of R and the paired test against the
first step (:func:`analysis.replicates.summarise_replicates`), ``replicates.csv`` each
seed's figures.

The stage is described by :data:`talkingface.stages.grid.CEILING` (its children's MLflow tags
are ``ceiling.setting``, ``ceiling.seed``, …).

Files (``runs/<name>/ceiling/``)::

    <child>/          its tables.csv, summary.json, model
    corpora/<k>/      the corpora and Motion Units of the children that change synth, and the
                      tracked copies (``tracked/``) of those that read tracked MUPs
    results.csv       per child: what it changes, test R on both splits, MSE, LVE, closure
    ceiling.png       the steps as bars from our R to the oracle, the paper's value beside them
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.figures import report_figure
from analysis.metrics import PAPER_TABLES
from talkingface.config import flatten
from talkingface.paths import RunPaths
from talkingface.stages.child_runs import log_for
from talkingface.stages.foundation import fit_units_folder
from talkingface.stages.grid import CEILING, grid_corpus, grid_rows, run_grid
from talkingface.stages.motion import track_folder, training_corpus, uses_tracked_corpus

PAPER_TEST_R = sum(v[0] for v in PAPER_TABLES["test"].values()) / len(PAPER_TABLES["test"])


def _changes(child, cfg) -> str:
    """The settings a child changes from the run's, as ``key=value`` text."""
    ours, theirs = flatten(cfg), flatten(child)
    return "; ".join(f"{k}={theirs[k]}" for k in theirs
                     if theirs[k] != ours.get(k) and not k.startswith("mapping.splits")
                     and not k.startswith("mapping.baselines")) or "(the run's setting)"


def _inputs(children: dict, cfg, paths: RunPaths, out: Path) -> dict:
    """Child → (corpus folder, Motion Units file): the run's training corpus, or one built under
    ``out`` (once for every child with the same synth settings, visual source and tracker): the
    corpus of the child's synth settings with Motion Units fitted on it, and when the child reads
    tracked MUPs (``mapping.visual_source: tracked``) that corpus rendered as video and tracked."""
    built: dict = {}  # synth → (corpus folder, units file); (synth, tracker) → tracked folder
    where = {}
    for name, child in children.items():
        same_source = (child.mapping.visual_source == cfg.mapping.visual_source
                       and child.tracker == cfg.tracker)
        if child.synth == cfg.synth and same_source:
            where[name] = (training_corpus(paths, cfg), paths.units_model)
            continue
        if child.synth == cfg.synth:
            base = (paths.corpus, paths.units_model)
        elif child.synth not in built:
            folder = out / str(len(built))
            grid_corpus(folder / "corpus", child.synth, cfg.seed)
            fit_units_folder(folder / "corpus", folder / "units", child)
            base = built[child.synth] = (folder / "corpus",
                                         folder / "units" / "motion_units.npz")
        else:
            base = built[child.synth]
        if not uses_tracked_corpus(child):
            where[name] = base
            continue
        key = (child.synth, child.tracker)
        if key not in built:
            built[key] = out / str(len(built))
            track_folder(base[0], base[1], built[key] / "tracked", child)
        where[name] = (built[key] / "tracked", base[1])
    return where


def decompose(paths: RunPaths, cfg) -> dict:
    """Every step of the ceiling grid trained and measured (stage ``ceiling``)."""
    children = CEILING.children(cfg)
    out = paths.stage(CEILING.name)
    out.mkdir(parents=True, exist_ok=True)
    inputs = _inputs(children, cfg, paths, out / "corpora")
    results = run_grid({n: (*inputs[n], c) for n, c in children.items()}, out,
                       seeds=CEILING.seeds(cfg), scheduler=cfg.cluster.scheduler,
                       workers=cfg.ceiling.workers, desc="ceiling steps",
                       log=log_for(CEILING.name), stage=CEILING.tag, cache=paths.cache)
    run_corpus = training_corpus(paths, cfg)

    def describe(name, child) -> dict:
        m = child.mapping
        return {"changes": _changes(child, cfg), "method": m.method,
                "gate_front_end": m.gate_front_end,
                "corpus": ("the run's" if inputs[name][0] == run_corpus
                           else str(Path(inputs[name][0]).relative_to(out)))}

    rows = grid_rows(results, children, CEILING, out, describe)
    ceiling_figure(rows, out / "ceiling.png")
    return {"grid": str(CEILING.grid_path(cfg)), "children": list(children), "rows": rows}


def ceiling_figure(rows: list[dict], path: Path, *, width: float = 1.0) -> Path:
    """Mean test R of every step on both splits as points with their 95 % intervals over seeds
    (``<split>_R_ci95``; none where it is NaN), the paper's mean test R as a line.

    The y axis spans the points, their intervals and the paper's value (not from 0), so the
    differences between steps stay visible; points, not bars, as no bar starts at 0.
    """
    def _num(v) -> float:  # a missing value ("" in a CSV, None) as NaN
        try:
            return float(v)
        except (TypeError, ValueError):
            return float("nan")

    x = np.arange(len(rows))
    with report_figure(path, width=width, height_in=3.0) as fig:
        ax = fig.subplots()
        ends = [PAPER_TEST_R]
        for dx, split, label, marker in ((-0.15, "utterance", "utterance split", "o"),
                                         (0.15, "random_frames", "frame split (the paper's)",
                                          "s")):
            y = np.array([_num(r.get(f"{split}_R")) for r in rows])
            ci = np.array([_num(r.get(f"{split}_R_ci95")) for r in rows])
            has = np.isfinite(ci)
            ax.errorbar(x[has] + dx, y[has], yerr=ci[has], fmt=marker, capsize=2.5,
                        elinewidth=1.0, label=label)
            colour = ax.containers[-1].lines[0].get_color()
            ax.plot(x[~has] + dx, y[~has], marker, color=colour)
            ends += [*(y - np.where(has, ci, 0)), *(y + np.where(has, ci, 0))]
        ax.axhline(PAPER_TEST_R, color="k", linestyle="--", lw=1.0,
                   label=f"paper, Table II ({PAPER_TEST_R:.3f})")
        ends = np.asarray(ends)[np.isfinite(ends)]
        pad = 0.08 * max(float(np.ptp(ends)), 0.02)
        ax.set_ylim(float(ends.min()) - pad, float(ends.max()) + pad)
        ax.set_xticks(x, [r["step"] for r in rows], rotation=25, ha="right",
                      rotation_mode="anchor")
        ax.set_xlim(-0.6, len(rows) - 0.4)
        ax.set_ylabel("mean test R (Eq. 6)")
        ax.grid(axis="y", alpha=0.3)
        ax.legend(loc="best")
        ax.set_title("From our Table II toward the ceiling: one measured step per column")
    return Path(path)
