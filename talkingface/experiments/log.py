"""MLflow at the entry points only: where the store is, the run helper, and what each stage
logs (the library packages never import MLflow).

Default store: ``sqlite:///<cwd>/mlflow.db`` with artifacts in ``<cwd>/mlartifacts``;
``MLFLOW_TRACKING_URI`` (or ``mlflow.uri`` in the config) overrides it.
"""
from __future__ import annotations

import csv
import json
import logging
import os
import sqlite3
import tempfile
import time
import urllib.error
import urllib.request
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

from analysis.evaluation import row_metrics
from analysis.grid_summary import (best, forest_figure, grid_summary, read_replicates,
                                   summary_markdown, voices_markdown, voices_summary,
                                   write_summary)
from groundwork.errors import TalkingFaceError
from talkingface.config import flatten
from talkingface.paths import RunPaths
from talkingface.provenance import git_commit
from talkingface.stages import STAGES
from talkingface.stages.child_runs import ChildLog, logging_to
from talkingface.stages.grid import VOICES, GridStage, log_child, replicate_folder, replicate_seed
from talkingface.stages.voices import read_results


# The UI opens an experiment on its GenAI pages (traces, tokens) unless it is tagged as model
# training; this MLflow reads this tag.
EXPERIMENT_TAGS = {"mlflow.experimentKind": "custom_model_development"}


def tracking_uri(cfg) -> str:
    if cfg.mlflow.uri:
        return cfg.mlflow.uri
    env = os.environ.get("MLFLOW_TRACKING_URI")
    if env:
        return env
    return f"sqlite:///{Path.cwd() / 'mlflow.db'}"


_CREDENTIALS = ("MLFLOW_TRACKING_USERNAME", "MLFLOW_TRACKING_PASSWORD", "MLFLOW_TRACKING_TOKEN")


# The stores a run may log to: a local SQLite file, a tracking server, a database server.
TRACKING_SCHEMES = ("sqlite", "http", "https", "postgresql", "mysql", "mssql")
# MLflow's own waits on a tracking server (its defaults retry for minutes); a user's
# MLFLOW_HTTP_REQUEST_* variables are kept.
HTTP_WAIT = {"MLFLOW_HTTP_REQUEST_TIMEOUT": "30", "MLFLOW_HTTP_REQUEST_MAX_RETRIES": "2"}


def check_tracking(cfg) -> None:
    """Refuse a tracking store that cannot be used, before a command writes anything: a URI of
    another kind, an SQLite file that is not a database, a tracking server (``http(s)://``)
    that does not answer — one line, not minutes of MLflow's retries and a traceback."""
    if not cfg.mlflow.enabled:
        return
    uri = tracking_uri(cfg)
    scheme = uri.split("://", 1)[0].split("+", 1)[0].lower() if "://" in uri else ""
    if scheme not in TRACKING_SCHEMES:
        raise TalkingFaceError(f"mlflow.uri {uri}: not a tracking store this project logs to; "
                               f"allowed: {', '.join(s + '://' for s in TRACKING_SCHEMES)} "
                               "(empty: ./mlflow.db)")
    if scheme == "sqlite":
        _check_sqlite(uri)
        return
    if scheme not in ("http", "https"):
        return
    try:
        with urllib.request.urlopen(uri.rstrip("/") + "/health", timeout=10) as r:
            r.read()
    except urllib.error.HTTPError as exc:
        if exc.code >= 500:
            raise TalkingFaceError(f"mlflow.uri {uri}: the tracking server answers with HTTP "
                                   f"{exc.code}; see its log") from None
        if exc.code == 404:
            raise TalkingFaceError(f"mlflow.uri {uri}: a web server answers there but not "
                                   "MLflow's (HTTP 404 at /health); check the address and "
                                   "port") from None
        if exc.code in (401, 403) and not any(os.environ.get(k) for k in _CREDENTIALS):
            raise TalkingFaceError(f"mlflow.uri {uri}: the tracking server asks for a log-in "
                                   f"(HTTP {exc.code}); set {' or '.join(_CREDENTIALS[::2])} "
                                   "(MLflow's own variables)") from None
    except (OSError, ValueError) as exc:
        why = getattr(exc, "reason", None) or exc
        raise TalkingFaceError(f"mlflow.uri {uri}: no tracking server answers there ({why}); "
                               "start one (`talkingface server`), or leave mlflow.uri empty "
                               "for ./mlflow.db") from None


def _check_sqlite(uri: str) -> None:
    """Refuse an SQLite store whose file exists but is not a readable SQLite database
    (``sqlite:///relative.db``, ``sqlite:////absolute.db``: SQLAlchemy's forms)."""
    path = Path(uri.split(":///", 1)[1]) if ":///" in uri else None
    if path is None or not path.is_file():
        return
    try:
        db = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, timeout=10)
        try:
            db.execute("SELECT name FROM sqlite_master LIMIT 1").fetchall()
        finally:
            db.close()
    except sqlite3.DatabaseError as exc:
        raise TalkingFaceError(f"mlflow.uri {uri}: {path} is not a usable SQLite database "
                               f"({exc}); move it away, or set mlflow.uri to another "
                               "store") from None


def artifact_root() -> str:
    return (Path.cwd() / "mlartifacts").as_uri()


@contextmanager
def mlflow_run(cfg, *, run_name: str, tags: dict | None = None, nested: bool = False):
    """Start an MLflow run with the resolved config as params and the git commit as a tag.

    Yields the ``mlflow`` module (or ``None`` when tracking is disabled in the config).
    ``nested`` makes the run a child of the active run (an ablation setting of its parent).
    """
    if not cfg.mlflow.enabled:
        yield None
        return
    import mlflow

    # Alembic prints every schema migration of a fresh SQLite store at INFO.
    logging.getLogger("alembic").setLevel(logging.WARNING)
    for key, value in HTTP_WAIT.items():
        os.environ.setdefault(key, value)
    mlflow.set_tracking_uri(tracking_uri(cfg))
    client = mlflow.tracking.MlflowClient()
    exp = client.get_experiment_by_name(cfg.mlflow.experiment)
    if exp is None:
        loc = artifact_root() if tracking_uri(cfg).startswith("sqlite:") else None
        exp_id = client.create_experiment(cfg.mlflow.experiment, artifact_location=loc,
                                          tags=EXPERIMENT_TAGS)
    else:
        exp_id = exp.experiment_id
        for k, v in EXPERIMENT_TAGS.items():
            if exp.tags.get(k) != v:
                client.set_experiment_tag(exp_id, k, v)
    mlflow.set_experiment(experiment_id=exp_id)  # nested (child) runs go to the same experiment
    with mlflow.start_run(experiment_id=exp_id, run_name=run_name, nested=nested) as run:
        mlflow.set_tags({"git_commit": git_commit(), **(tags or {})})
        mlflow.log_params({k: str(v)[:500] for k, v in flatten(cfg).items()})
        yield mlflow
        del run


def train_metrics(summary: dict, primary: str) -> dict:
    """MLflow metrics: the primary method as ``<split>.<expression>.<part>.<metric>``, every
    other method under ``baseline.<method>.``, gate accuracy and training times."""
    out = {}
    for r in summary["rows"]:
        prefix = "" if r["method"] == primary else f"baseline.{r['method']}."
        out.update(row_metrics(r, prefix))
    for key, g in summary["gate"].items():
        split = key.split("/")[1]
        out.update({f"gate.{split}.{k}": v for k, v in g.items() if isinstance(v, float)})
    for key, sec in summary["fit_seconds"].items():
        method, split = key.split("/")
        out[f"fit_seconds.{method}.{split}"] = sec
    for split, rk in summary["ranking"].items():
        for x in rk:
            out[f"rank.{split}.{x['method']}"] = x["rank"]
    out["feature_seconds"] = summary["feature_seconds"]
    return out


def log_train(mlf, summary: dict, out_dir: Path, cfg) -> None:
    """Log the mapping stage to the active MLflow run: metrics, tables, plots, models, pyfunc."""
    from talkingface.experiments.pyfunc import log_mapping_model  # imports mlflow

    mlf.log_metrics(train_metrics(summary, cfg.mapping.method))
    for p in sorted(out_dir.iterdir()):
        if p.suffix in (".csv", ".json", ".png", ".yaml", ".tfmap"):
            mlf.log_artifact(str(p), "mapping")
    models = summary["models"]
    if models:
        split = "utterance" if "utterance" in models else next(iter(models))
        log_mapping_model(mlf, out_dir / models[split], name="mapping")


def _grid_parent(mlf, cfg, grid: GridStage, path: Path, nested: bool) -> ChildLog:
    """The parent run of a grid stage (its grid file ``path``): a new child of the active run
    named after the stage (``nested``) or the active run itself, as a :class:`ChildLog` the
    stage's tasks log their child runs under. Its tags: ``stage`` (:attr:`GridStage.tag`),
    ``grid`` (the kind: ablations, ceiling, voices) and ``grid_file``."""
    active = mlf.active_run()
    exp = active.info.experiment_id
    tags = {"stage": grid.tag, "grid": grid.name, "grid_file": str(path)}
    if nested:
        client = mlf.tracking.MlflowClient()
        pid = client.create_run(exp, run_name=grid.name, tags={
            "mlflow.parentRunId": active.info.run_id, **tags}).info.run_id
    else:
        mlf.set_tags(tags)
        pid = active.info.run_id
    return ChildLog(tracking_uri(cfg), exp, pid)


@contextmanager
def grid_runs(mlf, cfg, grids, *, nested: bool = True):
    """Within the block the grid stages of ``grids`` (:class:`GridStage` s) that ``cfg`` asks
    for (and the run's corpus allows: the stage's ``enabled``) log their child runs under a parent run each (:mod:`talkingface.stages.child_runs`);
    yields ``{stage name: ChildLog}`` (empty without MLflow). A nested parent of a stage that
    failed is marked FAILED."""
    if mlf is None:
        yield {}
        return
    logs = {grid.name: _grid_parent(mlf, cfg, grid, grid.grid_path(cfg), nested)
            for grid in grids if STAGES[grid.name].enabled(cfg)}
    try:
        with logging_to(logs):
            yield logs
    except BaseException:
        if nested:
            client = mlf.tracking.MlflowClient()
            for log in logs.values():
                client.set_terminated(log.parent_run_id, "FAILED")
        raise


def log_grid(mlf, log: ChildLog, out_dir: Path, grid: GridStage, cfg, *,
             nested: bool = True) -> None:
    """A replicated grid stage (the ablations, the ceiling steps) under its parent run.

    Every child and seed of the grid ``cfg`` names that its task did not log yet (a reused
    stage, a task without MLflow) is logged from its folder, exactly once; the stage's tables
    and its summary go on the parent (:func:`log_grid_summary`, against the grid's reference
    child: :meth:`GridStage.reference_child`), which is then finished.

    Parameters
    ----------
    mlf : module
        ``mlflow``, with the run of the command active.
    log : ChildLog
        The stage's parent run (:func:`grid_runs`).
    out_dir : Path
        The stage's folder (its children's folders, ``results.csv``, ``replicates.csv``).
    grid : GridStage
        The grid stage (:data:`talkingface.stages.grid.ABLATIONS` or ``CEILING``).
    cfg : Config
        The run's resolved config (its grid file and seeds).
    nested : bool
        The parent is a run of its own, finished here (False: the command's own run).
    """
    children = grid.children(cfg)
    for name, child in children.items():
        for k in range(grid.seeds(cfg)):
            ck = replace(child, seed=replicate_seed(child.seed, k))
            where = replicate_folder(out_dir, name, ck.seed, k)
            summary = json.loads((where / "summary.json").read_text())
            log_child(log, grid.tag, name, k, where, ck, summary)
    log.prune()  # what a worker killed while logging left unfinished
    client = mlf.tracking.MlflowClient()
    for table in ("results.csv", "replicates.csv"):
        if (out_dir / table).is_file():
            client.log_artifact(log.parent_run_id, str(out_dir / table), grid.name)
    for figure in ("lookahead.png", "ceiling.png"):  # the stage's own figure, beside the forest
        if (out_dir / figure).is_file():
            client.log_artifact(log.parent_run_id, str(out_dir / figure))
    log_grid_summary(client, log.parent_run_id, out_dir, title=grid.title,
                     reference=grid.reference_child(children), key=grid.row_key)
    if nested:
        client.set_terminated(log.parent_run_id, "FINISHED")


def log_grid_summary(client, run_id: str, out_dir: Path, *, title: str, reference: str,
                     key: str = "setting") -> list[dict]:
    """The answer of a grid on its parent run, where the run's page shows it: per setting the
    mean test R with its 95 % interval, Δ against ``reference`` with its interval, the Holm-
    corrected p and a verdict (:func:`analysis.grid_summary.grid_summary`, from the stage's
    ``replicates.csv``) as ``summary.csv`` and the forest plot ``forest.png`` at the top of its
    artifacts, in words and as a table in the run's description, and the reference's figures
    as its metrics (``reference.test.<split>.R`` and ``…R_ci95``). ``title``: the grid stage's
    (:attr:`GridStage.title`); ``key``: the column naming a child. Returns the summary."""
    from mlflow.entities import Metric, Param

    reps = read_replicates(out_dir / "replicates.csv")
    summary = grid_summary(reps, reference=reference, key=key)
    with tempfile.TemporaryDirectory(prefix="talkingface-summary-") as tmp:
        client.log_artifact(run_id, str(write_summary(summary, Path(tmp) / "summary.csv")))
        client.log_artifact(run_id, str(forest_figure(
            summary, Path(tmp) / "forest.png", reference=reference,
            title=f"{title}: each {key} against {reference}", what=key)))
    text = summary_markdown(summary, title=title, reference=reference, what=key)
    client.set_tag(run_id, "mlflow.note.content",
                   text + "\nArtifacts: `summary.csv` (this table), `forest.png` (the "
                   "differences with their intervals), `results.csv` (every figure).")
    metrics, params = {}, {"reference": reference, "settings": len(
        {r["setting"] for r in summary}), "seeds": max(r["seeds"] for r in summary)}
    for r in summary:
        if r["verdict"] == "reference":
            metrics[f"reference.test.{r['split']}.R"] = r["R"]
            if r["R_ci95"] == r["R_ci95"]:
                metrics[f"reference.test.{r['split']}.R_ci95"] = r["R_ci95"]
    for split in dict.fromkeys(r["split"] for r in summary):
        part = [r for r in summary if r["split"] == split]
        metrics[f"differ.{split}.better"] = sum(r["verdict"] == "better" for r in part)
        metrics[f"differ.{split}.worse"] = sum(r["verdict"] == "worse" for r in part)
        top = best(summary, split)
        params[f"best.{split}"] = top["setting"]
    now = int(time.time() * 1000)
    client.log_batch(run_id, metrics=[Metric(k, float(v), now, 0) for k, v in metrics.items()],
                     params=[Param(k, str(v)) for k, v in params.items()])
    return summary


def log_voices(mlf, log: ChildLog, paths: RunPaths, children: dict) -> None:
    """The voices grid under its parent run ``log``: each model a child run (logged from its
    folder if its task did not), and on the parent the models side by side — in-domain R and
    the real-speech figures of :mod:`analysis.speech_report` — with the default model and the
    development rule that picks it, as ``summary.csv`` and the run's description."""
    out = paths.stage(VOICES.name)
    for name, cfg in children.items():
        summary = json.loads((out / name / "summary.json").read_text())
        log_child(log, VOICES.tag, name, 0, out / name, cfg, summary)
    log.prune()
    client = mlf.tracking.MlflowClient()
    rows = voices_summary(read_results(paths), _csv_rows(paths.stage("speech_eval") /
                                                          "results.csv"))
    with tempfile.TemporaryDirectory(prefix="talkingface-summary-") as tmp:
        client.log_artifact(log.parent_run_id, str(_write_rows(rows, Path(tmp) /
                                                               "summary.csv")))
    if (out / "results.csv").is_file():
        client.log_artifact(log.parent_run_id, str(out / "results.csv"), "voices")
    client.set_tag(log.parent_run_id, "mlflow.note.content", voices_markdown(rows))
    default = next((r for r in rows if r["default"]), None)
    if default is not None:
        from mlflow.entities import Metric, Param

        now = int(time.time() * 1000)
        client.log_batch(log.parent_run_id, params=[Param("default", default["model"])],
                         metrics=[Metric(f"default.{k}", v, now, 0) for k, v in default.items()
                                  if isinstance(v, float) and v == v])
    client.set_terminated(log.parent_run_id, "FINISHED")


def _csv_rows(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8-sig") as f:
        return list(csv.DictReader(f))


def _write_rows(rows: list[dict], path: Path) -> Path:
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else ["model"])
        w.writeheader()
        w.writerows(rows)
    return path


def log_replication(mlf, paths: RunPaths, done: dict) -> None:
    """What ``replicate`` logs besides the mapping and the ablations: the corpus, the Motion
    Units, the config, the report and the PDF."""
    corpus, units = done["corpus"], done["units"]
    mlf.set_tag("corpus_hash", corpus["corpus_hash"])
    # the report's counts (a given corpus's corpus.json need not hold them)
    info = json.loads((paths.report_dir / "summary.json").read_text())["corpus"]
    if "source" in corpus:
        mlf.set_tag("corpus_source", corpus["source"])
    mlf.log_metrics({"corpus.n_frames": info["n_frames"],
                     "corpus.n_utterances": info["n_utterances"],
                     "corpus.seconds": corpus["seconds"],
                     "units.fit_seconds": units["fit_seconds"],
                     **{f"units.explained.{k}": v
                        for k, v in units["summary"]["explained"].items()}})
    mlf.log_artifact(str(paths.config))
    mlf.log_artifact(str(paths.units / "variance.csv"), "units")
    mlf.log_artifact(str(paths.units_model), "units")
    mlf.log_artifacts(str(paths.report_dir), "report")
    mlf.log_artifact(str(paths.pdf))
    if "speech_eval" in done:
        log_speech_eval(mlf, done["speech_eval"], paths.speech_eval)


def speech_eval_metrics(summary: list, model: str) -> dict:
    """MLflow metrics of one model on the real-speech set: ``<split>.<figure>`` for every
    pooled figure (NaN and empty splits left out), and the recogniser's bar as ``bar.``."""
    out = {}
    for row in summary:
        prefix = ("" if row["model"] == model else
                  "bar." if row["model"].startswith("pocketsphinx") else None)
        if prefix is None:
            continue
        for k, v in row.items():
            if k not in ("model", "split") and isinstance(v, (int, float)) and v == v:
                out[f"{prefix}{row['split']}.{k}"] = float(v)
    return out


def speech_eval_tags(results: dict, model: str) -> dict:
    return {"stage": "speech_eval", "speech_eval.model": model,
            "speech_eval.model_file": results["models"][model],
            "speech_eval.seen_speakers": ",".join(results["seen_speakers"].get(model, []))
            or "none",
            "speech_eval.training_speakers": ",".join(
                (results.get("training_speakers") or {}).get(model, [])) or "none"}


def log_speech_eval_model(mlf, results: dict, out_dir: Path, model: str) -> None:
    """One evaluated model into the active MLflow run: its tags, metrics and the files."""
    mlf.set_tags(speech_eval_tags(results, model))
    mlf.log_metrics(speech_eval_metrics(results["summary"], model))
    for name in ("results.csv", "per_file.csv", "per_speaker.csv", "comparisons.csv",
                 "rates.csv", "results.json", f"opening_{model}.png"):
        if (Path(out_dir) / name).is_file():
            mlf.log_artifact(str(Path(out_dir) / name), "speech_eval")


def log_speech_eval(mlf, results: dict, out_dir: Path) -> None:
    """The ``speech_eval`` stage inside a replication: one child run per evaluated model,
    tagged ``stage=speech_eval`` and ``speech_eval.model`` so the models compare in the UI."""
    for model in results["models"]:
        with mlf.start_run(run_name=f"speech_eval:{model}", nested=True):
            log_speech_eval_model(mlf, results, out_dir, model)
