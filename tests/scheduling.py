"""The suite's order and its spread over the pytest-xdist workers: whole test files, the costliest
first, each to whichever worker is free, so that the workers finish together.

A file's tests stay together on one worker (xdist's load-scope scheduling, by module, or by class
for test methods): its module-scoped fixtures — a server, a browser, a trained run — are made once
per file, not once per test as they would be if its tests were dealt out one by one between
other files' tests. The order of the files (:func:`order_items`, the same in every worker, so the
collections agree):

1. the files of :data:`BUILD_FIRST`, the first reader of each folder shared by the whole session
   (``build_once`` in tests/conftest.py), that reader first in its file: the workers start on
   them at once, so the shared folders are made before the files that read them come up;
2. every other file, the costliest first;
3. the file of :data:`RUN_LAST`: the check that each shared folder was made once this session.

Within a file the tests keep their collection order. A file's cost is the sum of its tests' in a
measured run of the suite, ``tests/durations.json`` (setup, call and teardown; tests under
:data:`MIN_RECORDED_S` are left out and count 0). The file is written by ``make durations``
(``pytest --save-durations FILE``); a stale file costs balance, never a result.
:class:`FileScheduling` hands out the files in that order (xdist would otherwise reorder them by
their number of tests).
"""
from __future__ import annotations

import json
from pathlib import Path

from xdist.scheduler import LoadScopeScheduling

DURATIONS = Path(__file__).with_name("durations.json")
MIN_RECORDED_S = 1.0  # tests faster than this are not recorded (they count 0)

# the session fixtures that make a folder shared by every worker (tests/conftest.py build_once)
SHARED_FIXTURES = ("small_run_dir", "full_run_dir", "default_corpus_dir")
# the first reader of each shared folder, which makes it: the workers start on them at once
BUILD_FIRST = (
    "tests/talkingface/test_cli_pipeline.py::test_replicate_writes_runs_report_and_mlflow",
    "tests/study/test_stimuli.py::test_every_stimulus_of_the_design_in_sync_with_its_audio",
    "tests/data_synth/test_generate.py::test_default_corpus_size_and_phone_classes",
)
RUN_LAST = ("tests/test_shared_runs.py::test_each_shared_folder_was_made_once_this_session",)


def recorded_costs(path: Path = DURATIONS) -> dict:
    """``{nodeid: seconds}`` of the measured run (empty when the file is missing)."""
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        return {}


def _file(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def order_items(items: list, costs: dict) -> list:
    """``items`` in the order of the module docstring (stable: ties keep their order)."""
    first = {_file(n): i for i, n in enumerate(BUILD_FIRST)}
    last = {_file(n) for n in RUN_LAST}
    cost: dict = {}
    for it in items:
        f = _file(it.nodeid)
        cost[f] = cost.get(f, 0.0) + costs.get(it.nodeid, 0.0)

    def file_key(f: str) -> tuple:
        if f in first:
            return (0, first[f])
        return (2, 0.0) if f in last else (1, -cost[f])

    rank = {f: i for i, f in enumerate(sorted(cost, key=file_key))}
    builds = set(BUILD_FIRST)
    return sorted(items, key=lambda it: (rank[_file(it.nodeid)], it.nodeid not in builds))


class FileScheduling(LoadScopeScheduling):
    """xdist's load-scope scheduling in the collection's order of files (see the module
    docstring)."""

    def __init__(self, config, log=None):
        config.option.loadscopereorder = False  # keep order_items' order
        super().__init__(config, log)


class DurationRecorder:
    """Sums each test's setup, call and teardown time as reported (on the xdist controller, the
    workers' reports) and writes those of at least :data:`MIN_RECORDED_S` to ``path`` at the
    end of the session (``make durations`` runs the whole suite with it)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.seconds: dict = {}

    def pytest_runtest_logreport(self, report) -> None:
        self.seconds[report.nodeid] = self.seconds.get(report.nodeid, 0.0) + report.duration

    def pytest_sessionfinish(self, session, exitstatus) -> None:
        kept = {k: round(v, 1) for k, v in sorted(self.seconds.items(), key=lambda kv: -kv[1])
                if v >= MIN_RECORDED_S}
        self.path.write_text(json.dumps(kept, indent=0) + "\n")
