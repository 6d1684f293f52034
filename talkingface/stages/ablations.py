"""Ablations: one training per setting of a grid, in parallel, logged as MLflow child runs.

A grid file (``configs/ablations.yaml``)::

    base:                  # settings applied to every child (optional)
      mapping.splits: [utterance]
    children:              # one child run per entry: name → settings
      paper: {}
      classes-1: {mapping.n_classes: 1}
      context-5: {mapping.context_back: 5, mapping.context_forward: 5}

Keys are ``section.key`` as for ``--set``; an unknown key is an error naming the grid file and the
child. Each child trains only its ``mapping.method`` (the paper's mapping unless the child sets a
baseline) on the run's corpus and Motion Units and writes ``runs/<name>/ablations/<child>/``
(its tables and ``summary.json``). ``results.csv`` gathers the children's test figures. The
stage's grid is ``ablations.grid`` of the config; MLflow logs the children afterwards
(:func:`talkingface.experiment_log.log_ablations`).

The look-ahead curve (issue 13): the children named ``lookahead-*`` vary only the look-ahead
(``mapping.context_forward``) and the window alignment; each row of ``results.csv`` carries its
algorithmic latency (:func:`mapping.features.algorithmic_latency_s` at the corpus's rate), and
``lookahead.png`` plots test R and closure on /p b m/ against it, per method, with the paper's
setting (``paper``, ``baseline-gru``: 3 frames, centred window) beside them.
"""
from __future__ import annotations

import csv
import json
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np
from tqdm import tqdm

from analysis.evaluation import row_metrics
from face_model.errors import ParameterError
from mapping.features import algorithmic_latency_s
from talkingface.config import apply_overrides, parse_set, read_yaml
from talkingface.paths import RunPaths
from talkingface.stages.motion import training_corpus
from talkingface.stages.training import train_and_evaluate

DEFAULT_GRID = Path(__file__).resolve().parents[2] / "configs" / "ablations.yaml"
_CHILD_NAME = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_.-"


def load_grid(path, cfg, *, what: str = "ablation grid", extra_keys: tuple = (),
              shared_corpus: bool = True) -> dict:
    """``{child name: resolved Config}`` from a grid file, in file order. ``extra_keys``: other
    top-level keys the caller reads itself (the voices grid's ``model``). ``shared_corpus``: the
    children train on the run's training corpus, so none may change the visual source or the
    tracker (False: the caller builds each child's corpus, as the ceiling does)."""
    path = Path(path)
    if not path.is_file():
        raise ParameterError(f"{what} {path} not found")
    tree = read_yaml(path, what) or {}
    if not isinstance(tree, dict) or not isinstance(tree.get("children"), dict) \
            or not tree["children"]:
        raise ParameterError(f"{path}: {what} needs a non-empty 'children' mapping "
                             "(name → settings)")
    unknown = set(tree) - {"base", "children", *extra_keys}
    if unknown:
        raise ParameterError(f"{path}: unknown top-level keys {sorted(unknown)}; allowed: "
                             f"{', '.join(['base', 'children', *extra_keys])}")

    def settings(where, d) -> dict:
        if d is None:
            return {}
        if not isinstance(d, dict):
            raise ParameterError(f"{path}: {where} must map section.key to a value, got {d!r}")
        return parse_set([f"{k}={json.dumps(v)}" for k, v in d.items()])

    base = settings("base", tree.get("base"))
    out = {}
    for name, d in tree["children"].items():
        name = str(name)
        if not name or any(ch not in _CHILD_NAME for ch in name):
            raise ParameterError(f"{path}: child name {name!r} may use letters, digits, '_.-'")
        try:
            child = apply_overrides(apply_overrides(cfg, base), settings(name, d))
        except ParameterError as e:
            raise ParameterError(f"{path}: child {name!r}: {e}") from None
        if shared_corpus and (child.mapping.visual_source != cfg.mapping.visual_source
                              or child.tracker != cfg.tracker):
            raise ParameterError(f"{path}: child {name!r} changes the visual source or the "
                                 "tracker; the children share the run's training corpus, so set "
                                 "these for the whole run (--visual-source, --set tracker.…)")
        out[name] = child
    return out


def init_worker() -> None:
    import torch

    torch.set_num_threads(1)  # one core per child: the pool gives the parallelism


def run_child(name: str, corpus_dir: str, units_path: str, out_dir: str, cfg) -> dict:
    t0 = time.perf_counter()
    summary = train_and_evaluate(Path(corpus_dir), Path(units_path), Path(out_dir), cfg,
                                 methods=[cfg.mapping.method], progress=False)
    summary["seconds"] = time.perf_counter() - t0
    (Path(out_dir) / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    return {"name": name, "summary": summary, "seconds": summary["seconds"]}


def child_metrics(summary: dict, method: str) -> dict:
    """MLflow metrics of one child: ``<split>.<expression>.<part>.<metric>`` and means."""
    out = {}
    for r in summary["rows"]:
        if r["method"] != method:
            continue
        out.update(row_metrics(r))
    for split, rk in summary["ranking"].items():
        for x in rk:
            if x["method"] == method:
                out[f"{split}.mean_test_R"] = x["R"]
                out[f"{split}.mean_test_MSE"] = x["MSE"]
                for k in ("LVE", "R_lips", "closure"):
                    if k in x:
                        out[f"{split}.mean_test_{k}"] = x[k]
                out[f"{split}.fit_seconds"] = x["fit_seconds"]
    for key, g in summary["gate"].items():
        split = key.split("/")[1]
        out.update({f"{split}.gate.{k}": v for k, v in g.items() if isinstance(v, float)})
    return out


def run_children(jobs: dict, out_dir: Path, *, workers: int = 0, desc: str = "runs",
                 progress: bool = True) -> dict:
    """Train every job ``name → (corpus folder, motion_units.npz, Config)`` into
    ``out_dir/<name>`` with ``workers`` processes (0: all cores), one torch thread each;
    returns ``{name: run_child's result}``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    n = workers or os.cpu_count() or 1
    ctx = multiprocessing.get_context("spawn")  # torch is not fork-safe once its pools exist
    results = {}
    with ProcessPoolExecutor(max_workers=min(n, len(jobs)), mp_context=ctx,
                             initializer=init_worker) as pool:
        futs = [pool.submit(run_child, name, str(corpus), str(units), str(out_dir / name), c)
                for name, (corpus, units, c) in jobs.items()]
        for fut in tqdm(as_completed(futs), total=len(futs), desc=desc, unit="run",
                        disable=not progress):
            res = fut.result()
            results[res["name"]] = res
    return results


def run_ablations(grid: dict, corpus_dir: Path, units_path: Path, out_dir: Path, *,
                  workers: int = 0, progress: bool = True) -> list[dict]:
    """Train every child of ``grid`` (from :func:`load_grid`) with ``workers`` processes (0: all
    cores); write ``results.csv`` (and the look-ahead figure when the grid has a curve) and
    return its rows."""
    results = run_children({name: (corpus_dir, units_path, c) for name, c in grid.items()},
                           out_dir, workers=workers, desc="ablations", progress=progress)
    sr = corpus_sample_rate(corpus_dir)
    rows = [_result_row(name, grid[name], results[name], sr) for name in grid]
    fields = list(dict.fromkeys(k for r in rows for k in r))
    with open(out_dir / "results.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, restval="")
        w.writeheader()
        w.writerows(rows)
    curve = lookahead_rows(rows)
    if curve:
        lookahead_figure(curve, out_dir / "lookahead.png")
    return rows


def corpus_sample_rate(corpus_dir) -> int:
    """The sample rate of a corpus's first utterance (its manifest), Hz."""
    with open(Path(corpus_dir) / "manifest.csv", newline="", encoding="utf-8-sig") as f:
        return int(next(csv.DictReader(f))["sample_rate"])


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


def lookahead_figure(curve: list[dict], path: Path, split: str = "utterance") -> Path:
    """Test R and /p b m/ closure against algorithmic latency (ms), one line per method (the
    ``lookahead-*`` children, right-aligned window) and the paper's setting as a marker."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for ax, key, label in ((axes[0], f"{split}_R", "test R (Eq. 6)"),
                           (axes[1], f"{split}_closure", "/p b m/ closed (test)")):
        for method in sorted({r["method"] for r in curve}):
            pts = sorted((float(r["latency_ms"]), float(r[key])) for r in curve
                         if r["method"] == method and str(r["setting"]).startswith("lookahead-"))
            line, = ax.plot(*zip(*pts), marker="o", label=method) if pts else (None,)
            for r in curve:
                if r["method"] == method and r["setting"] in PAPER_POINTS:
                    ax.plot(float(r["latency_ms"]), float(r[key]), marker="*", markersize=12,
                            color=line.get_color() if line else None, linestyle="none",
                            label=f"{method}, paper's window")
        ax.set_xlabel("algorithmic latency (ms)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"Accuracy against look-ahead ({split} split)")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def resolve_grid(grid: str, default: Path) -> Path | None:
    """A grid setting as a file: ``default`` → the project's grid, ``none`` or empty → None."""
    if not grid or grid.lower() == "none":
        return None
    return default if grid == "default" else Path(grid)


def grid_path(cfg) -> Path | None:
    """The ablation grid file of ``ablations.grid`` (None: no ablations)."""
    return resolve_grid(cfg.ablations.grid, DEFAULT_GRID)


def has_grid(cfg) -> bool:
    return grid_path(cfg) is not None


def checked_grid(path: Path | None, cfg, *, what: str, setting: str, load=load_grid) -> list:
    """``[path]`` of a grid stage's grid file (its contents join the stage's key), ``[]`` for no
    grid; a missing or malformed grid (``load`` refuses it) is refused here, before the run is
    touched."""
    if path is None:
        return []
    if not path.is_file():
        raise ParameterError(f"{what} {path} not found ({setting}: default, none or a grid "
                             "file)")
    load(path, cfg)
    return [path]


def grid_file(paths: RunPaths, cfg) -> list:
    """The ablation grid file (its contents join the stage's key)."""
    return checked_grid(grid_path(cfg), cfg, what="ablation grid", setting="ablations.grid")


def ablate(paths: RunPaths, cfg) -> dict:
    """Every setting of the ablation grid trained on the run's training corpus."""
    grid = load_grid(grid_path(cfg), cfg)
    rows = run_ablations(grid, training_corpus(paths, cfg), paths.units_model, paths.ablations,
                         workers=cfg.ablations.workers, progress=True)
    return {"grid": str(grid_path(cfg)), "children": list(grid), "rows": rows}
