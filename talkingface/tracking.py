"""MLflow at the entry points only: where the store is, and one helper to log a stage run.

Default store: ``sqlite:///<cwd>/mlflow.db`` with artifacts in ``<cwd>/mlartifacts``;
``MLFLOW_TRACKING_URI`` (or ``tracking.uri`` in the config) overrides it.
"""
from __future__ import annotations

import os
import subprocess
from contextlib import contextmanager
from pathlib import Path

from talkingface.config import flatten


def tracking_uri(cfg) -> str:
    if cfg.tracking.uri:
        return cfg.tracking.uri
    env = os.environ.get("MLFLOW_TRACKING_URI")
    if env:
        return env
    return f"sqlite:///{Path.cwd() / 'mlflow.db'}"


def artifact_root() -> str:
    return (Path.cwd() / "mlartifacts").as_uri()


def git_commit() -> str:
    """The source tree's commit (``+dirty`` with uncommitted changes), or ``unknown``."""
    here = Path(__file__).resolve().parent.parent
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True,
                             text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return sha + ("+dirty" if dirty else "")


@contextmanager
def mlflow_run(cfg, *, run_name: str, tags: dict | None = None, nested: bool = False):
    """Start an MLflow run with the resolved config as params and the git commit as a tag.

    Yields the ``mlflow`` module (or ``None`` when tracking is disabled in the config).
    ``nested`` makes the run a child of the active run (an ablation setting of its parent).
    """
    if not cfg.tracking.enabled:
        yield None
        return
    import logging

    import mlflow

    # Alembic prints every schema migration of a fresh SQLite store at INFO.
    logging.getLogger("alembic").setLevel(logging.WARNING)
    mlflow.set_tracking_uri(tracking_uri(cfg))
    client = mlflow.tracking.MlflowClient()
    exp = client.get_experiment_by_name(cfg.tracking.experiment)
    if exp is None:
        loc = artifact_root() if tracking_uri(cfg).startswith("sqlite:") else None
        exp_id = client.create_experiment(cfg.tracking.experiment, artifact_location=loc)
    else:
        exp_id = exp.experiment_id
    mlflow.set_experiment(experiment_id=exp_id)  # nested (child) runs go to the same experiment
    with mlflow.start_run(experiment_id=exp_id, run_name=run_name, nested=nested) as run:
        mlflow.set_tags({"git_commit": git_commit(), **(tags or {})})
        mlflow.log_params({k: str(v)[:500] for k, v in flatten(cfg).items()})
        yield mlflow
        del run
