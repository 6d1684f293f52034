"""The one stage contract and the one helper that runs a stage.

A stage is a function ``(paths, cfg) -> dict`` that writes the folder ``runs/<name>/<stage>/``
and returns a summary of its results. :func:`run_stage` owns everything around it: the
folder's ``config.yaml`` and its ``done.json`` (written last, atomically), and reuse. A stage is
reused exactly when its *key* is unchanged; the key is

* the config sections or keys the stage declares it depends on (minus the ones that only set
  the speed, such as worker counts),
* the fingerprints of the upstream stages whose results it reads (``None`` for an upstream
  stage the config switches off), and
* the SHA-256 of the files outside the run it reads (a user's sentence file, a grid file), by
  content, so moving a file or the checkout changes nothing, and
* what else outside the run it reads, as the stage sums it up (a given corpus: its
  ``corpus_hash``).

So a changed mapping setting re-runs training and everything downstream of it, and a changed
study setting re-runs the study stages and nothing upstream. A stale or interrupted stage
folder is removed and made again, never mixed with new results; except that a *resumable*
stage (a grid: hours of independent tasks, each written complete or not at all) interrupted
under the same key goes on from the tasks it had finished.
"""
from __future__ import annotations

import csv
import hashlib
import json
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path


from groundwork.atomic import atomic_file, fresh_partial_folder, swap_in
from groundwork.errors import ParameterError
from groundwork.owner import acquire
from talkingface.config import dump_config, read_yaml, select, to_dict
from talkingface.paths import RunPaths

DONE = "done.json"
BUILDING = "building.json"  # in a resumable stage's partial folder: the key it is built under


def _always(cfg) -> bool:
    return True


def _no_files(paths, cfg) -> list:
    return []


def _no_inputs(paths, cfg) -> dict:
    return {}


@dataclass(frozen=True)
class Stage:
    """One stage and its reuse rule (see the module docstring).

    ``config``: dotted config keys the results depend on (``"synth"``, ``"tracker.init"``), or
    a function of the config giving them (the corpus: ``synth`` only when it is synthesised);
    ``speed_only``: keys inside those that do not change the results; ``upstream``: stages whose
    results it reads; ``enabled``: whether the config asks for the stage at all (and whether it
    applies to the run's corpus: :mod:`talkingface.stages.applies`); ``files``: files outside
    the run it reads; ``inputs``: ``(paths, cfg) -> dict``, a summary of anything else outside
    the run it reads (a given corpus's hash; an empty dict adds nothing to the key);
    ``always``: never reused (the report); ``guard``: called with
    an existing folder before it would be replaced, raises to refuse; ``resumable``: an
    interrupted build under the same key is kept and goes on (the stage must keep only complete
    parts in its folder and check each against its own settings before reusing it).
    """

    name: str
    run: Callable
    config: tuple | Callable = ()
    upstream: tuple = ()
    speed_only: tuple = ()
    enabled: Callable = _always
    files: Callable = _no_files
    inputs: Callable = _no_inputs
    always: bool = False
    guard: Callable | None = None
    resumable: bool = False


def _building(partial: Path) -> str | None:
    """The fingerprint an interrupted build of a resumable stage was made under (None: none)."""
    try:
        return json.loads((partial / BUILDING).read_text(encoding="utf-8")).get("fingerprint")
    except (OSError, ValueError, AttributeError):
        return None


def read_done(folder: Path) -> dict | None:
    """A stage folder's ``done.json`` (None when the stage has not finished there)."""
    p = Path(folder) / DONE
    if not p.is_file():
        return None
    try:
        done = json.loads(p.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise ParameterError(f"{p}: not valid JSON ({exc}); it is written last and only by the "
                             f"pipeline: remove {p.parent} to make that stage again") from None
    if not isinstance(done, dict) or "fingerprint" not in done:
        return None  # a record of an older version: the stage is made again
    return done


def write_csv(path: Path, rows: list[dict]) -> Path:
    """``rows`` (dicts) as a CSV file with a header (written atomically): the columns are every
    key of any row, in order of appearance; a row without a key leaves its cell empty."""
    with atomic_file(path) as tmp, open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for r in rows for k in r)),
                           restval="")
        w.writeheader()
        w.writerows(rows)
    return path


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _cpu_seconds() -> float:
    """CPU seconds (user + system) of this process and of its finished child processes (a
    stage's pool and Dask workers count once they have ended, as they do with the stage)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def time_summary(done: dict, paths: RunPaths, since: float) -> list[str]:
    """One line per stage of ``{stage: done.json}`` of ``paths``: its wall and CPU seconds, or
    that it was reused (its done.json is older than ``since``, a ``time.time()``); and the
    total of the stages that ran."""
    lines, wall, cpu = [], 0.0, 0.0
    for name, d in done.items():
        if (paths.stage(name) / DONE).stat().st_mtime < since:
            lines.append(f"  {name:<12} reused")
            continue
        w, c = float(d.get("seconds", 0.0)), float(d.get("cpu_seconds", float("nan")))
        wall, cpu = wall + w, cpu + c
        lines.append(f"  {name:<12} {w:8.1f} s wall {c:8.1f} s CPU")
    lines.append(f"  {'total':<12} {wall:8.1f} s wall {cpu:8.1f} s CPU")
    return lines


def stage_key(stage: Stage, stages: dict, paths: RunPaths, cfg) -> dict:
    """What a stage's results depend on, as plain data (see the module docstring)."""
    tree = to_dict(cfg)
    keys = stage.config(cfg) if callable(stage.config) else stage.config
    conf = {k: select(tree, k) for k in keys}
    for key in stage.speed_only:
        section, _, leaf = key.rpartition(".")
        if section in conf and isinstance(conf[section], dict):
            conf[section] = {k: v for k, v in conf[section].items() if k != leaf}
    upstream = {}
    for name in stage.upstream:
        up = stages[name]
        done = read_done(paths.stage(name)) if up.enabled(cfg) else None
        upstream[name] = done["fingerprint"] if done else None
    files = [_sha256(Path(p)) for p in stage.files(paths, cfg)]  # contents, wherever they are
    key = {"config": conf, "upstream": upstream, "files": files}
    inputs = stage.inputs(paths, cfg)
    if inputs:  # only then: the keys of the stages without inputs stay as they were
        key["inputs"] = inputs
    return key


def fingerprint(key: dict) -> str:
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()


def run_stage(stage: Stage, stages: dict, paths: RunPaths, cfg) -> dict:
    """Run ``stage`` unless its folder holds a finished run with the same key; returns the
    stage's ``done.json`` (its results plus ``stage``, ``fingerprint``, ``key``, ``seconds``)."""
    out = paths.stage(stage.name)
    key = stage_key(stage, stages, paths, cfg)
    fp = fingerprint(key)
    done = read_done(out)
    if done is not None and done.get("fingerprint") == fp and not stage.always:
        return done
    if stage.guard is not None and out.exists():
        stage.guard(out)
    partial = fresh_partial_folder(out, keep=lambda p: stage.resumable and _building(p) == fp)
    if stage.resumable:
        (partial / BUILDING).write_text(json.dumps({"fingerprint": fp}))
    t0, c0 = time.perf_counter(), _cpu_seconds()
    try:
        results = stage.run(paths.building_in(stage.name, partial), cfg)
    except BaseException:
        # a full disk or a bug: the unfinished folder goes, unless the stage goes on from its
        # finished parts when the same command runs again (a grid's finished tasks)
        if not stage.resumable:
            shutil.rmtree(partial, ignore_errors=True)
        raise
    record = {"stage": stage.name, "fingerprint": fp, "key": key,
              "seconds": time.perf_counter() - t0, "cpu_seconds": _cpu_seconds() - c0,
              **results}
    (partial / BUILDING).unlink(missing_ok=True)
    dump_config(cfg, partial / "config.yaml")
    (partial / DONE).write_text(json.dumps(record, indent=1, default=float))
    swap_in(partial, out)
    return record


def run_stages(names, stages: dict, paths: RunPaths, cfg) -> dict:
    """Run the named stages, each after the upstream stages it needs (in order, once each);
    stages the config switches off are skipped. Returns ``{stage: done.json}``."""
    return {n: run_stage(stages[n], stages, paths, cfg) for n in run_order(names, stages)
            if stages[n].enabled(cfg)}


def run_order(names, stages: dict) -> list[str]:
    """``names`` with their upstream stages, each after what it reads."""
    order: list[str] = []

    def visit(name: str) -> None:
        if name not in stages:
            raise ParameterError(f"unknown stage {name!r}; allowed: {', '.join(stages)}")
        if name in order:
            return
        for up in stages[name].upstream:
            visit(up)
        order.append(name)

    for n in names:
        visit(n)
    return order


def stale_stages(names, stages: dict, paths: RunPaths, cfg) -> list[str]:
    """The stages among ``names`` and their upstream stages that :func:`run_stages` would run
    (not reuse) for ``cfg``, in run order: those without a finished run of the same key, those
    downstream of one, and those never reused."""
    order = run_order(names, stages)
    stale: list[str] = []
    for name in order:
        stage = stages[name]
        if not stage.enabled(cfg):
            continue
        fp = fingerprint(stage_key(stage, stages, paths, cfg))  # checks its input files too
        done = read_done(paths.stage(name))
        if (stage.always or done is None or any(u in stale for u in stage.upstream)
                or done.get("fingerprint") != fp):
            stale.append(name)
    return stale


# Settings that change neither results nor outputs: a run made with other values is the same run
# (every section's ``workers``: how many processes; ``cluster``: where the grids' tasks run;
# ``mlflow``: where runs are logged). The stages key what they read (``Stage.config``).
RUN_INDEPENDENT = ("cluster", "mlflow", "ablations")
SPEED_ONLY_LEAF = "workers"


def _result_settings(tree: dict) -> dict:
    tree = json.loads(json.dumps(tree))
    for key in RUN_INDEPENDENT:
        tree.pop(key, None)
    for node in tree.values():
        if isinstance(node, dict):
            node.pop(SPEED_ONLY_LEAF, None)
    return tree


def prepare_run(paths: RunPaths, cfg, *, overwrite: bool, check=None) -> None:
    """Create ``runs/<name>`` and record the config. A run made with other settings is refused
    unless ``overwrite``; with it, the stages whose keys changed are made again when they run
    and the others are reused (nothing is deleted here). ``check`` (optional) runs after the
    refusal test and before anything is written, to refuse bad inputs first."""
    if paths.config.is_file():
        old = read_yaml(paths.config, "run config") or {}
        if _result_settings(old) != _result_settings(to_dict(cfg)) and not overwrite:
            raise ParameterError(
                f"{paths.root} was made with a different config; choose another --name, or "
                f"pass --overwrite to re-run the stages it changes (compare {paths.config})")
    if check is not None:
        check()
    acquire(paths.root, "run")  # one command builds a run at a time, until it ends
    paths.root.mkdir(parents=True, exist_ok=True)
    with atomic_file(paths.config) as tmp:
        dump_config(cfg, tmp)
