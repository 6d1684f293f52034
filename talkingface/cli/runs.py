"""The run-level commands: prepare ``runs/<name>``, run the stages a command needs, log them.

``replicate`` runs :data:`talkingface.stages.REPLICATION` in order; ``train``, ``track``,
``ablate`` and ``study stimuli`` run their own stages (and whatever upstream stages are missing or
stale). Reuse is decided by the stage layer alone (:mod:`talkingface.stages.base`); MLflow is
written here and in :mod:`talkingface.experiments.log`, nowhere below.
"""
from __future__ import annotations

import time

from groundwork.errors import ParameterError
from talkingface.executor import check_reachable, scheduler_address
from talkingface.experiments.log import (check_tracking, grid_runs, log_grid, log_replication,
                                        log_train, log_voices, mlflow_run, tracking_uri)
from talkingface.paths import RunPaths
from talkingface.stages import (ABLATIONS, CEILING, GRID_STAGES, REAL_STEPS, REPLICATION,
                                VOICES, off_for_corpus, preflight, prepare_run, run)
from talkingface.stages.base import time_summary
from talkingface.stages.front_end import front_end_applies


def open_run(name: str, cfg, stages, *, overwrite: bool = False, runs_dir="runs",
             reports_dir="reports") -> RunPaths:
    """``runs/<name>`` for ``cfg`` (refused if made with other settings, unless overwrite),
    after checking that every input the named ``stages`` read is there, and that the tracking
    server and the Dask scheduler it names answer: nothing is written for a command that
    cannot run."""
    check_workers_log(cfg)  # a mistake in the settings first, then what must answer
    check_tracking(cfg)
    check_reachable(cfg.cluster.scheduler)
    paths = RunPaths.create(name, runs_dir=runs_dir, reports_dir=reports_dir)
    prepare_run(paths, cfg, overwrite=overwrite, check=lambda: preflight(stages, paths, cfg))
    return paths


def check_workers_log(cfg) -> None:
    """Refuse a running Dask scheduler (``tcp://``) with a tracking store its workers cannot
    share: they log their child runs themselves, on their own machines, so the store must be
    one they all reach (a tracking server ``http(s)://``, or a database such as
    ``postgresql://``), not a local file such as the default ``mlflow.db``."""
    uri = tracking_uri(cfg)
    scheme = uri.partition("://")[0] if "://" in uri else ""
    if cfg.mlflow.enabled and scheduler_address(cfg.cluster.scheduler) is not None \
            and (scheme in ("", "file", "sqlite") or scheme.startswith("sqlite+")):
        raise ParameterError(f"cluster.scheduler {cfg.cluster.scheduler}: its workers log their "
                             f"child runs themselves and cannot share the tracking store {uri}; "
                             "set mlflow.uri to a tracking server they all reach "
                             "(http://HOST:PORT, `talkingface server`), or mlflow.enabled=false")


def replicate(name: str, cfg, *, overwrite: bool = False, runs_dir="runs",
              reports_dir="reports"):
    """Every stage into ``runs/<name>``, ``reports/<name>.pdf``, one MLflow run (the mapping's
    metrics and pyfunc model, the ablations as child runs). Returns the PDF's path."""
    paths = open_run(name, cfg, REPLICATION, overwrite=overwrite, runs_dir=runs_dir,
                     reports_dir=reports_dir)
    since = time.time()
    with mlflow_run(cfg, run_name=name, tags={"stage": "replicate"}) as mlf:
        with grid_runs(mlf, cfg, GRID_STAGES.values()) as logs:
            done = run(REPLICATION, paths, cfg)
        if mlf is not None:
            log_train(mlf, done["mapping"], paths.mapping, cfg)
            for grid in (ABLATIONS, CEILING, REAL_STEPS):
                if grid.name in done:
                    log_grid(mlf, logs[grid.name], paths.stage(grid.name), grid, cfg)
            if VOICES.name in done:
                log_voices(mlf, logs[VOICES.name], paths, VOICES.children(cfg))
            log_replication(mlf, paths, done)
    print("time per stage:", *time_summary(done, paths, since), sep="\n", flush=True)
    return paths.pdf


def train(name: str, cfg, *, overwrite: bool = False) -> dict:
    """The mapping of ``runs/<name>`` (and its keyframes, which ``animate --keyframes`` uses),
    logged as an MLflow run with the pyfunc model. Returns the mapping's done.json."""
    stages = ["mapping", "keyframes"]
    paths = open_run(name, cfg, stages, overwrite=overwrite)
    with mlflow_run(cfg, run_name=f"train:{name}", tags={"stage": "train"}) as mlf:
        done = run(stages, paths, cfg)
        if mlf is not None:
            log_train(mlf, done["mapping"], paths.mapping, cfg)
    return done["mapping"]


def track(name: str, cfg, *, overwrite: bool = False) -> dict:
    """The tracked corpus of ``runs/<name>`` (``cfg`` has ``mapping.visual_source: tracked``)."""
    return run(["tracked"], open_run(name, cfg, ["tracked"], overwrite=overwrite), cfg)["tracked"]


def front_end(name: str, cfg, *, overwrite: bool = False) -> dict:
    """The causal phone front end of ``runs/<name>`` (stage ``front_end``: its corpora made if
    missing, hama's teacher pass, the training)."""
    refuse_off("front_end", cfg)
    if not front_end_applies(cfg):
        raise ParameterError("talkingface front-end teaches the front end that the voices "
                             "grid's causal children read (mapping.recogniser: causal, no "
                             f"mapping.front_model); voices.grid {cfg.voices.grid} has none "
                             "(default: the project's configs/voices.yaml has two)")
    return run(["front_end"], open_run(name, cfg, ["front_end"], overwrite=overwrite),
               cfg)["front_end"]


def ablate(name: str, cfg, *, overwrite: bool = False) -> dict:
    """The ablation grid ``ablations.grid`` on ``runs/<name>``, one MLflow child run per
    setting under a parent run."""
    grid = ABLATIONS.grid_path(cfg)
    if grid is None:
        raise ParameterError("talkingface ablate needs a grid file (--grid FILE), not 'none'")
    paths = open_run(name, cfg, [ABLATIONS.name], overwrite=overwrite)
    with mlflow_run(cfg, run_name=f"ablate:{grid.stem}",
                    tags={"stage": ABLATIONS.tag, "grid": str(grid)}) as mlf:
        with grid_runs(mlf, cfg, [ABLATIONS], nested=False) as logs:
            done = run([ABLATIONS.name], paths, cfg)[ABLATIONS.name]
        if mlf is not None:
            log_grid(mlf, logs[ABLATIONS.name], paths.ablations, ABLATIONS, cfg, nested=False)
    return done


def stimuli(name: str, cfg, *, overwrite: bool = False) -> dict:
    """The study's stimuli of ``runs/<name>`` (its mapping trained first if needed)."""
    refuse_off("stimuli", cfg)
    return run(["stimuli"], open_run(name, cfg, ["stimuli"], overwrite=overwrite), cfg)["stimuli"]


def refuse_off(stage: str, cfg) -> None:
    """Refuse a command for ``stage`` when the run's corpus switches it off (a given corpus,
    one without smile and sad: :mod:`talkingface.stages.applies`), saying why."""
    why = off_for_corpus([stage], cfg).get(stage)
    if why:
        raise ParameterError(f"stage {stage} does not apply to this run's corpus"
                             + (f" (corpus.source {cfg.corpus.source})" if cfg.corpus.source
                                else "") + f": {why}")
