"""MLflow child runs of a grid stage, logged by the task that trained them, once each.

A grid stage's tasks may run on other machines (:mod:`talkingface.executor`), so each task logs
its own child run to the tracking server, under the stage's parent run. :class:`ChildLog` is all
a task needs for that (the tracking URI, the experiment, the parent run), and it is picklable.

A child run is keyed by its setting and seed (the tag ``grid.key``; children logged before it was
named so carry ``ablation.key``, which is still read). Logging is idempotent:
a finished child run with the key is kept and not logged again (a task run twice, or a stage
reused and logged from its files); attempts that log at once keep one finished run between
them; an unfinished run — left by a worker killed while it was logging — is deleted by
:meth:`ChildLog.prune` once the grid has ended. So a grid ends with exactly one child run per
setting and seed, whatever died on the way.

The stages learn their parent run from the entry point (:mod:`talkingface.cli.runs`) through
:func:`logging_to`; without one (MLflow disabled, or a stage run alone) :func:`log_for` gives
``None`` and nothing is logged. This module imports MLflow only inside its functions.
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path

KEY_TAG = "grid.key"
OLD_KEY_TAG = "ablation.key"  # the key of children logged before the tag was grid.key
_BATCH = 100  # MLflow takes at most 100 params or tags and 1000 metrics per batch
_LOGS: ContextVar[dict] = ContextVar("child_logs", default={})


def child_key(name: str, seed: int) -> str:
    """The key of a grid child: its setting and its seed."""
    return f"{name}/seed-{seed}"


@dataclass(frozen=True)
class ChildLog:
    """Where a grid stage's tasks log their child runs: ``uri`` (the tracking URI every worker
    reaches), ``experiment_id`` and ``parent_run_id``."""

    uri: str
    experiment_id: str
    parent_run_id: str

    def _client(self):
        from mlflow.tracking import MlflowClient

        return MlflowClient(self.uri)

    def children(self) -> list:
        """The parent's child runs that are not deleted (MLflow ``Run`` objects)."""
        return self._client().search_runs(
            [self.experiment_id], f"tags.mlflow.parentRunId = '{self.parent_run_id}'",
            max_results=50000)

    def _with_key(self, client, key: str) -> list:
        """The parent's child runs (not deleted) that carry ``key``, under either tag name."""
        return [run for tag in (KEY_TAG, OLD_KEY_TAG) for run in client.search_runs(
            [self.experiment_id], f"tags.mlflow.parentRunId = '{self.parent_run_id}' and "
            f"tags.`{tag}` = '{key}'")]

    def log(self, name: str, seed: int, *, tags: dict, params: dict, metrics: dict,
            files=(), config: dict | None = None, run_name: str | None = None) -> str:
        """Log one child (setting ``name``, ``seed``; named ``run_name``, by default its key)
        unless a finished child run with its key is already there; returns the id of the child
        run that stays.

        Two attempts of one task may log at once (a scheduler that lost a worker's heartbeat
        runs its task again while the first attempt still lives): each finishes its own run,
        then keeps the earliest finished run with the key (by start time, then run id) and
        deletes the others, so one run stays (the id returned by an attempt that looked before
        the other had finished may be the one deleted). Unfinished runs are left to their
        attempts; :meth:`prune` removes those a dead worker left, once the grid is done."""
        from mlflow.entities import Metric, Param

        client, key = self._client(), child_key(name, seed)
        done = _finished(self._with_key(client, key))
        if done:
            return done[0].info.run_id
        run = client.create_run(self.experiment_id, run_name=run_name or key, tags={
            "mlflow.parentRunId": self.parent_run_id, KEY_TAG: key,
            **{k: str(v) for k, v in tags.items()}})
        rid, now = run.info.run_id, int(time.time() * 1000)
        ps = [Param(k, str(v)[:500]) for k, v in params.items()]
        ms = [Metric(k, float(v), now, 0) for k, v in metrics.items()]
        for i in range(0, len(ps), _BATCH):
            client.log_batch(rid, params=ps[i:i + _BATCH])
        for i in range(0, len(ms), 10 * _BATCH):
            client.log_batch(rid, metrics=ms[i:i + 10 * _BATCH])
        for f in files:
            client.log_artifact(rid, str(f))
        if config is not None:
            client.log_dict(rid, config, "config.json")
        client.set_terminated(rid, "FINISHED")  # last: a run without it is half-logged
        keep, *twins = _finished(self._with_key(client, key))
        for r in twins:
            client.delete_run(r.info.run_id)
        return keep.info.run_id

    def prune(self) -> int:
        """Delete the parent's unfinished child runs (half-logged by a worker that died); call
        it once every task of the grid has ended. Returns how many were deleted."""
        client = self._client()
        gone = [r.info.run_id for r in self.children() if r.info.status != "FINISHED"]
        for rid in gone:
            client.delete_run(rid)
        return len(gone)


def _finished(runs: list) -> list:
    """The FINISHED runs of ``runs``, earliest first (start time, then run id): the first is
    the one every attempt keeps."""
    return sorted((r for r in runs if r.info.status == "FINISHED"),
                  key=lambda r: (r.info.start_time or 0, r.info.run_id))


@contextmanager
def logging_to(logs: dict):
    """Within the block, :func:`log_for` gives the stage's :class:`ChildLog` of ``logs``
    (stage name → ChildLog)."""
    token = _LOGS.set(dict(logs))
    try:
        yield
    finally:
        _LOGS.reset(token)


def log_for(stage: str) -> ChildLog | None:
    """The :class:`ChildLog` of ``stage`` set by the entry point, or None (nothing logged)."""
    return _LOGS.get().get(stage)


def artifact_files(folder: Path, names=("tables.csv",)) -> list[Path]:
    """The files of a child's folder that its child run keeps as artifacts."""
    return [folder / n for n in names if (folder / n).is_file()]
