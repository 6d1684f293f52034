"""The suite's order and its spread over the pytest-xdist workers: the costliest tests first, one
at a time to whichever worker is free, so that the workers finish together.

Order (:func:`order_items`, the same in every worker, so the collections agree):

1. :data:`BUILD_FIRST`: the first reader of each folder shared by the whole session
   (``build_once`` in tests/conftest.py), which makes it: the workers start on them at once;
2. every test that reads no shared folder, costliest first;
3. the tests that read a shared folder (:data:`SHARED_FIXTURES` among their fixtures),
   costliest first: by the time a worker reaches them the folders are made, so no worker waits
   on another's build (and their recorded costs are their own work, not a wait);
4. :data:`RUN_LAST`: the check that each shared folder was made once in the session.

A test's cost is what it took in a measured run of the suite, ``tests/durations.json`` (setup,
call and teardown; tests under :data:`MIN_RECORDED_S` are left out and count 0, keeping their
collection order, which keeps a module's tests together). The file is written by
``make durations`` (``pytest --save-durations FILE``); a stale file costs balance, never a
result. :class:`CostFirstScheduling` hands the tests out in that order, one at a time (each
worker holds two: the one it runs and the next), instead of xdist's default first blocks of a
quarter of the suite per worker, which would give one worker all the costly tests at the head of
the order.
"""
from __future__ import annotations

import json
from pathlib import Path

from xdist.scheduler import LoadScheduling

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


def order_items(items: list, costs: dict) -> list:
    """``items`` in the order of the module docstring (a stable sort: ties keep their order)."""
    first = {nodeid: i for i, nodeid in enumerate(BUILD_FIRST)}
    last = {nodeid: i for i, nodeid in enumerate(RUN_LAST)}

    def group(item) -> int:
        if item.nodeid in first:
            return 0
        if item.nodeid in last:
            return 3
        return 2 if set(SHARED_FIXTURES) & set(getattr(item, "fixturenames", ())) else 1

    def key(item):
        g = group(item)
        if g == 0:
            return (g, first[item.nodeid])
        if g == 3:
            return (g, last[item.nodeid])
        return (g, -costs.get(item.nodeid, 0.0))

    return sorted(items, key=key)


class CostFirstScheduling(LoadScheduling):
    """xdist's load scheduling, handing out the tests in the collection's order one at a time
    (see the module docstring)."""

    def __init__(self, config, log=None):
        super().__init__(config, log)
        self.maxschedchunk = 1  # refills of one test; a worker keeps two (LoadScheduling)

    def schedule(self) -> None:
        assert self.collection_is_completed
        if self.collection is not None:  # a node added later: fill it as any other
            for node in self.nodes:
                self.check_schedule(node)
            return
        if not self._check_nodes_have_same_collection():
            self.log("**Different tests collected, aborting run**")
            return
        self.collection = next(iter(self.node2collection.values()))
        self.pending[:] = range(len(self.collection))
        # two tests each, dealt in turn: the costliest to different workers
        for _ in range(2):
            for node in self.nodes:
                if self.pending:
                    self._send_tests(node, 1)
        if not self.pending:
            for node in self.nodes:
                node.shutdown()


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
