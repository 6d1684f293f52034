"""A grid stage's machinery: its grid file, its tasks and their seed replicates.

Each grid stage is described once, by a :class:`GridStage` (:data:`ABLATIONS`, :data:`CEILING`,
:data:`REAL_STEPS`, :data:`VOICES`; :data:`GRID_STAGES` by kind): the setting that names its grid
file, how the file is read and checked (:mod:`talkingface.stages.grid_files`), its children's
MLflow tags, whether it resumes. The stage table
(:data:`talkingface.stages.STAGES`), the stages, the command line and the MLflow logging read it.

A grid file (``configs/ablations.yaml``, ``configs/ceiling.yaml``, ``configs/real_steps.yaml``,
``configs/voices.yaml``)::

    base:                  # settings applied to every child (optional)
      mapping.splits: [utterance]
    children:              # one child per entry: name → settings
      paper: {}
      classes-1: {mapping.n_classes: 1}

Keys are ``section.key`` as for ``--set``; an unknown key is an error naming the grid file and the
child (:func:`talkingface.stages.grid_files.load_grid`).

Each child is one task per seed (:func:`run_grid`), run where ``cluster.scheduler`` says
(:mod:`talkingface.executor`). Replicate ``k`` of a child trains with the run seed plus
``1000 k`` (:func:`replicate_seed`): its split (that seed + 17), its model's initialisation and
batches, its augmentation (+ 31); the corpus is the run's. Replicate 0 is the run's own seed, so
one seed gives exactly the single-run results. Folders::

    <out>/<child>/                          replicate 0: tables.csv, summary.json, model
    <out>/replicates/seed-<s>/<child>/      replicate k >= 1, trained with seed s

A task writes its folder under ``<folder>.partial-<attempt>`` (its own, since a scheduler may run
a task again while the first attempt still lives) and swaps it in when complete
(:func:`groundwork.atomic.swap_in`), unless another attempt's finished folder got there first,
then logs its MLflow child run, keyed by setting and seed (:mod:`talkingface.stages.child_runs`):
attempts that race keep one folder and one run between them, and the partial folders and
unfinished runs of attempts killed with their workers are removed once the grid has ended. So
no child is ever doubled or left half-written.

A task whose folder is already finished under the same inputs and settings (its
``summary.json`` records them as ``task_key``: :func:`task_key`) is not trained again, only
logged. The grid stages are resumable (:class:`talkingface.stages.base.Stage`): a grid cut off
by a lost scheduler, a Ctrl-C or a dead machine goes on from its finished tasks when the same
command runs again.
"""
from __future__ import annotations

import hashlib
import json
import shutil
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from analysis.evaluation import row_metrics
from analysis.replicates import summarise_replicates
from data_synth.generate import synthesize_corpus
from groundwork.atomic import swap_in
from groundwork.errors import ParameterError
from mapping.experiment import METHOD_COST
from talkingface.config import flatten, to_dict
from talkingface.executor import map_tasks
from talkingface.stages.base import write_csv
from talkingface.stages.child_runs import artifact_files
from talkingface.stages.grid_files import (load_ceiling_grid, load_grid,
                                           load_real_steps_grid, voices_children)
from talkingface.stages.training import train_and_evaluate

REPLICATE_SEED_STEP = 1000
PARTIAL = ".partial-"  # a task's folder while it is written: <child>.partial-<attempt>


@dataclass(frozen=True)
class GridStage:
    """One grid stage, described once: its stage, its grid file, its children's MLflow tags.

    Parameters
    ----------
    name : str
        The stage (in :data:`talkingface.stages.STAGES`; its folder under the run), its config
        section (``<name>.grid``, ``<name>.workers``, ``<name>.seeds``) and the kind of grid
        its runs' ``grid`` tag names: ``ablations``, ``ceiling``, ``real_steps`` or ``voices``.
    tag : str
        Its MLflow ``stage`` tag: the parent run's, and its children's ``<prefix>.stage``.
    prefix : str
        The prefix of its children's tags (:meth:`child_tags`).
    what : str
        The grid in messages (``ablation grid``).
    default : Path
        The project's grid file, which ``<name>.grid: default`` names.
    load : callable
        ``(path, cfg) -> {child: Config}``: reads a grid file and refuses the children the
        stage cannot train.
    title : str
        The stage as its MLflow parent run's summary names it.
    reference : str or None
        The child the others are tested against, when the grid has it (else its first child).
    row_key : str
        The column of its ``results.csv`` that names a child.
    replicated : bool
        Its children train with ``<name>.seeds`` seeds each (False: one seed, the run's).
    resumable : bool
        A build cut off goes on from its finished tasks (:class:`talkingface.stages.base.Stage`).
    """

    name: str
    tag: str
    prefix: str
    what: str
    default: Path
    load: Callable
    title: str
    reference: str | None = None
    row_key: str = "setting"
    replicated: bool = True
    resumable: bool = True

    @property
    def settings(self) -> tuple:
        """Its own config keys, which join the stage's key: ``<name>.grid`` (and
        ``<name>.seeds`` when :attr:`replicated`)."""
        return (f"{self.name}.grid", *((f"{self.name}.seeds",) if self.replicated else ()))

    def grid_path(self, cfg) -> Path | None:
        """The grid file ``<name>.grid`` names: ``default`` → :attr:`default`, a file as given,
        ``none`` or empty → None (the stage is off)."""
        grid = getattr(cfg, self.name).grid
        if not grid or grid.lower() == "none":
            return None
        return self.default if grid == "default" else Path(grid)

    def has_grid(self, cfg) -> bool:
        """Whether ``cfg`` asks for the stage (a grid file, not ``none``)."""
        return self.grid_path(cfg) is not None

    def grid_file(self, paths, cfg) -> list:
        """``[grid file]`` (its contents join the stage's key), ``[]`` for no grid; a missing or
        malformed grid (:attr:`load` refuses it) is refused here, before the run is touched, in
        a line that begins with the setting (``ablations.grid: ...``).
        ``paths`` (the run's :class:`talkingface.paths.RunPaths`) is not read: this is the
        stage's ``files``."""
        path = self.grid_path(cfg)
        if path is None:
            return []
        if not path.is_file():
            raise ParameterError(f"{self.what} {path} not found ({self.name}.grid: default, "
                                 "none or a grid file)")
        try:
            self.load(path, cfg)
        except ParameterError as exc:  # the file's own problem, under the setting that names it
            raise ParameterError(f"{self.name}.grid: {exc}") from None
        return [path]

    def children(self, cfg) -> dict:
        """``{child: Config}`` of the grid file ``cfg`` names, in file order."""
        return self.load(self.grid_path(cfg), cfg)

    def seeds(self, cfg) -> int:
        """The training seeds per child: ``<name>.seeds``, or 1."""
        return getattr(cfg, self.name).seeds if self.replicated else 1

    def reference_child(self, children) -> str:
        """The child of ``children`` the others are tested against: :attr:`reference` if the
        grid has it, else its first child."""
        return self.reference if self.reference in children else next(iter(children))

    def child_tags(self, name: str, seed: int, k: int) -> dict:
        """The MLflow tags of replicate ``k`` (trained with ``seed``) of child ``name``:
        ``grid`` (:attr:`name`) and ``<prefix>.setting``, ``.seed``, ``.replicate``,
        ``.stage`` (:attr:`tag`)."""
        p = self.prefix
        return {"grid": self.name, f"{p}.setting": name, f"{p}.seed": seed,
                f"{p}.replicate": k, f"{p}.stage": self.tag}


_CONFIGS = Path(__file__).resolve().parents[2] / "configs"  # the project's grid files
ABLATIONS = GridStage("ablations", tag="ablate", prefix="ablation", what="ablation grid",
                      default=_CONFIGS / "ablations.yaml", load=load_grid, title="Ablations",
                      reference="paper")
CEILING = GridStage("ceiling", tag="ceiling", prefix="ceiling", what="ceiling grid",
                    default=_CONFIGS / "ceiling.yaml", load=load_ceiling_grid,
                    title="Where Table II stands: the ceiling steps", row_key="step")
REAL_STEPS = GridStage("real_steps", tag="real_steps", prefix="real_steps",
                       what="real-speaker steps grid", default=_CONFIGS / "real_steps.yaml",
                       load=load_real_steps_grid,
                       title="Where the real speaker's R goes: the trained steps",
                       row_key="step")
VOICES = GridStage("voices", tag="voices", prefix="voices", what="voices grid",
                   default=_CONFIGS / "voices.yaml", load=voices_children,
                   title="Voice-robust models", replicated=False)
GRID_STAGES = {g.name: g for g in (ABLATIONS, CEILING, REAL_STEPS, VOICES)}  # kind (the grid tag) → stage
_BY_TAG = {g.tag: g for g in GRID_STAGES.values()}


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


def grid_rows(results: dict, children: dict, grid: "GridStage", out: Path, describe
              ) -> list[dict]:
    """The rows of a trained, replicated grid (:func:`run_grid`'s ``results``): per task,
    ``describe(name, child)``'s columns, then test R, MSE, LVE and /p b m/ closure on the
    utterance and frame splits, seconds, replicate and seed (``out/replicates.csv``); per child
    their means, 95 % intervals and the paired test against the grid's reference child
    (``out/results.csv``, :func:`analysis.replicates.summarise_replicates`), returned."""
    reps = []
    for (name, k), res in results.items():
        child = children[name]
        metrics = child_metrics(res["summary"], child.mapping.method)
        row = {grid.row_key: name, **describe(name, child)}
        for split in ("utterance", "random_frames"):
            for key in ("R", "MSE", "LVE", "closure"):
                row[f"{split}_{key}"] = metrics.get(f"{split}.mean_test_{key}", float("nan"))
        row["seconds"] = round(res["seconds"], 1)
        reps.append({**row, "replicate": k, "seed": res["seed"]})
    write_csv(out / "replicates.csv", reps)
    rows = summarise_replicates(reps, reference=grid.reference_child(children),
                                key=grid.row_key)
    write_csv(out / "results.csv", rows)
    return rows


def task_cost(cfg) -> float:
    """The relative cost of a task of ``cfg``: its method's per split
    (:data:`mapping.experiment.METHOD_COST`), times its splits and training copies."""
    m = cfg.mapping
    return METHOD_COST.get(m.method, 7) * len(m.splits) * (1 + m.augment.copies)


def replicate_seed(seed: int, k: int) -> int:
    """The training seed of replicate ``k`` of a run with seed ``seed``."""
    return seed + REPLICATE_SEED_STEP * k


def replicate_folder(out_dir: Path, name: str, seed: int, k: int) -> Path:
    """The folder of replicate ``k`` (trained with ``seed``) of child ``name``."""
    return out_dir / name if k == 0 else out_dir / "replicates" / f"seed-{seed}" / name


def mlflow_child_metrics(metrics: dict) -> dict:
    """:func:`child_metrics` under the names a child run logs them, test figures first in
    MLflow's alphabetical lists (and so its default chart axes): ``test.<split>.<figure>`` for
    the means over expressions (``R``, ``MSE``, ``LVE``, ``R_lips``, ``closure``),
    ``<part>.<split>.<expression>.<figure>`` per expression (part ``test`` or ``train``),
    ``<part>.<split>.gate.<scope>`` for the gate's accuracy, ``time.<split>.fit_seconds``."""
    out = {}
    for k, v in metrics.items():
        split, _, rest = k.partition(".")
        if rest.startswith("mean_test_"):
            out[f"test.{split}.{rest[len('mean_test_'):]}"] = v
        elif rest.startswith("gate."):
            scope, _, part = rest[5:].rpartition("_")
            out[f"{part}.{split}.gate.{scope}"] = v
        elif rest == "fit_seconds":
            out[f"time.{split}.fit_seconds"] = v
        else:
            expr, part, figure = rest.split(".", 2)
            out[f"{part}.{split}.{expr}.{figure}"] = v
    return out


def log_child(log, stage: str, name: str, k: int, folder: Path, cfg, summary: dict) -> str:
    """Log one replicate of a child as an MLflow child run; idempotent.

    Parameters
    ----------
    log : talkingface.stages.child_runs.ChildLog
        Where the grid's child runs go.
    stage : str
        The grid stage's ``stage`` tag (:attr:`GridStage.tag`: ``ablate``, ``ceiling``,
        ``voices``).
    name, k : str, int
        The child (its setting) and its replicate.
    folder : Path
        The replicate's folder (its files become the run's artifacts).
    cfg : Config
        The child's settings, with the replicate's seed.
    summary : dict
        The task's ``summary.json``.

    Returns
    -------
    str
        The id of the child run that stays. It is named ``<setting>/<seed>``; the setting is a
        param (``setting``, so it can be a chart axis); its tags are the grid stage's
        (:meth:`GridStage.child_tags`: ``grid`` and ``<prefix>.setting`` …) and
        ``mapping.method``.
    """
    m = cfg.mapping
    return log.log(name, cfg.seed, run_name=f"{name}/{cfg.seed}",
                   tags={**_BY_TAG[stage].child_tags(name, cfg.seed, k),
                         "mapping.method": m.method},
                   params={"setting": name, **flatten(cfg)},
                   metrics={**mlflow_child_metrics(child_metrics(summary, m.method)),
                            "time.seconds": summary["seconds"]},
                   files=artifact_files(folder), config=to_dict(cfg))


def task_key(corpus_dir, units_path, cfg) -> str:
    """What one task's results depend on: its corpus and Motion Units (by path: they are the
    run's, or built in the stage's own folder from settings in the stage's key) and every
    setting but where and how fast it runs (``cluster``, ``mlflow``, worker counts)."""
    settings = {k: v for k, v in flatten(cfg).items()
                if not k.startswith(("cluster.", "mlflow.")) and not k.endswith(".workers")}
    text = json.dumps([str(corpus_dir), str(units_path), settings], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def finished_task(folder: Path, key: str) -> dict | None:
    """The summary of the task folder ``folder`` when it is finished under ``key``, else None."""
    try:
        summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return summary if isinstance(summary, dict) and summary.get("task_key") == key else None


def _keep_one(partial: Path, out: Path, key: str, summary: dict) -> dict:
    """Swap this attempt's finished ``partial`` (its ``summary``) in as ``out``, unless another
    attempt's finished folder is there already (then this one is dropped); the summary of the
    folder that stays."""
    for _ in range(5):
        other = finished_task(out, key)
        if other is not None:
            shutil.rmtree(partial, ignore_errors=True)
            return other
        try:
            swap_in(partial, out)
            return summary
        except OSError:  # another attempt was swapping its own folder in at the same moment
            time.sleep(0.2)
    raise OSError(f"{out}: could not swap in {partial.name} (another attempt of the task keeps "
                  "changing the folder)")


def run_child(name: str, k: int, corpus_dir: str, units_path: str, out_dir: str, cfg,
              log=None, stage: str = "", cache: str | None = None) -> dict:
    """One task: replicate ``k`` of child ``name`` (``cfg`` carries its seed) trained into
    ``out_dir`` (or found there finished under the same :func:`task_key`) and, with ``log``,
    logged as its MLflow child run. ``cache``: the content-keyed cache's folder, which the
    tasks share (a corpus's features and recognised phones are made once)."""
    out = Path(out_dir)
    key = task_key(corpus_dir, units_path, cfg)
    summary = finished_task(out, key)
    if summary is None:
        # this attempt's own folder: another attempt of the task may still be running
        partial = out.with_name(f"{out.name}{PARTIAL}{uuid.uuid4().hex[:8]}")
        out.parent.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        summary = train_and_evaluate(Path(corpus_dir), Path(units_path), partial, cfg,
                                     methods=[cfg.mapping.method], progress=False,
                                     cache=cache, figures=False)
        summary["seconds"] = time.perf_counter() - t0
        summary["seed"] = cfg.seed
        summary["task_key"] = key
        (partial / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
        summary = _keep_one(partial, out, key, summary)
    if log is not None:
        log_child(log, stage, name, k, out, cfg, summary)
    return {"name": name, "replicate": k, "seed": cfg.seed, "summary": summary,
            "seconds": summary["seconds"]}


def run_grid(jobs: dict, out_dir: Path, *, seeds: int = 1, scheduler: str = "local",
             workers: int = 0, desc: str = "runs", progress: bool = True, log=None,
             stage: str = "", cache=None) -> dict:
    """Train every job ``name → (corpus folder, motion_units.npz, Config)`` with ``seeds``
    replicates each, on ``scheduler`` with ``workers`` processes (0: all cores); returns
    ``{(name, k): run_child's result}``, in the order of ``jobs`` then replicates. ``cache``:
    the folder of the content-keyed cache the tasks share (None: none)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    tasks = {}
    for name, (corpus, units, c) in jobs.items():
        for k in range(seeds):
            ck = replace(c, seed=replicate_seed(c.seed, k))
            tasks[(name, k)] = (name, k, str(corpus), str(units),
                                str(replicate_folder(out_dir, name, ck.seed, k)), ck, log, stage,
                                None if cache is None else str(cache))
    # the dearest tasks first, so that no long task starts last while the other workers idle
    first = sorted(tasks, key=lambda key: -task_cost(tasks[key][5]))
    try:
        results = map_tasks(run_child, {key: tasks[key] for key in first}, scheduler=scheduler,
                            workers=workers, desc=desc, progress=progress)
    finally:  # what attempts killed with their workers, or failed (a full disk), left
        for left in out_dir.rglob(f"*{PARTIAL}*"):
            shutil.rmtree(left, ignore_errors=True)
    return {key: results[key] for key in tasks}


def run_children(jobs: dict, out_dir: Path, *, scheduler: str = "local", workers: int = 0,
                 desc: str = "runs", progress: bool = True, cache=None, log=None,
                 stage: str = "") -> dict:
    """:func:`run_grid` with one seed: ``{name: run_child's result}``."""
    res = run_grid(jobs, out_dir, scheduler=scheduler, workers=workers, desc=desc,
                   progress=progress, cache=cache, log=log, stage=stage)
    return {name: r for (name, _), r in res.items()}


def grid_corpus(folder: Path, synth, seed: int) -> Path:
    """A corpus a grid stage builds for its children in its own folder: synthesized, or kept
    when a resumed build of the stage (same key, so the same settings and seed) finished it
    (a corpus is swapped into place only when complete)."""
    if not (Path(folder) / "manifest.csv").is_file():
        synthesize_corpus(folder, synth, seed)
    return Path(folder)
