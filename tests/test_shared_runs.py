"""The suite's own machinery: the folders it shares (tests/conftest.py ``build_once``), made once
per test session however many workers ask; the order that starts them first and the costliest
tests before the rest (tests/scheduling.py); the times `make test` ends with."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from types import SimpleNamespace

from tests.conftest import REPO_ROOT, _shared_root, builds_log
from tests.scheduling import BUILD_FIRST, RUN_LAST, SHARED_FIXTURES, order_items

SHARED = {"small_run_dir": "small_run", "full_run_dir": "full_run",
          "default_corpus_dir": "default_corpus"}

# two processes ask for one folder at once, as two pytest-xdist workers do
_RACE = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    sys.path.insert(0, {repo!r})
    from tests.conftest import build_once

    class Factory:  # what build_once reads of pytest's tmp_path_factory
        def getbasetemp(self):
            return Path({base!r}) / sys.argv[1]

    def build(folder):
        time.sleep(1.0)  # long enough for the other process to ask meanwhile
        (folder / "made").write_text(sys.argv[1])

    out = build_once(Factory(), "thing", build)
    print((out / "made").read_text())
""")


def test_two_workers_asking_at_once_get_one_build(tmp_path):
    base = tmp_path / "pytest-0"
    for w in ("gw0", "gw1"):
        (base / w).mkdir(parents=True)
    script = _RACE.format(repo=str(REPO_ROOT), base=str(base))
    env = {**os.environ, "PYTEST_XDIST_WORKER": "gw"}
    procs = [subprocess.Popen([sys.executable, "-c", script, w], env=env, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
             for w in ("gw0", "gw1")]
    outs = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], [o[1] for o in outs]
    made = {o[0].strip() for o in outs}
    assert len(made) == 1 and made <= {"gw0", "gw1"}  # both read the one folder
    assert len(builds_log(base, "thing").read_text().splitlines()) == 1


def _item(nodeid):
    return SimpleNamespace(nodeid=nodeid)


def test_the_order_starts_the_builds_then_the_costliest_files_each_whole():
    build_full, build_small = BUILD_FIRST[0], BUILD_FIRST[1]
    full_file, small_file = build_full.split("::")[0], build_small.split("::")[0]
    items = [_item("a.py::short"), _item(RUN_LAST[0]), _item("b.py::one"),
             _item(f"{small_file}::other"), _item("c.py::long"), _item(build_small),
             _item("b.py::two"), _item(f"{full_file}::reader"), _item(build_full),
             _item("c.py::short"), _item("d.py::free")]
    costs = {"c.py::long": 50.0, "c.py::short": 1.0, "a.py::short": 2.0, "b.py::one": 30.0,
             "b.py::two": 30.0}
    assert [it.nodeid for it in order_items(items, costs)] == [
        build_full, f"{full_file}::reader",  # the builders' files, each builder first
        build_small, f"{small_file}::other",
        "b.py::one", "b.py::two",  # 60 s: the costliest file, whole
        "c.py::long", "c.py::short",  # 51 s
        "a.py::short", "d.py::free",  # 2 s, 0 s
        RUN_LAST[0]]
    assert set(SHARED) == set(SHARED_FIXTURES)


def test_each_shared_folder_was_made_once_this_session(request, tmp_path_factory):
    """Run last (tests/scheduling.py RUN_LAST): every shared folder, asked for again here, was
    made by exactly one worker in this session."""
    shared = _shared_root(tmp_path_factory)
    for fixture, name in SHARED.items():
        assert (request.getfixturevalue(fixture)).is_dir()
        assert len(builds_log(shared, name).read_text().splitlines()) == 1, name


_TIMED = textwrap.dedent("""
    import time

    def test_sleeps():
        time.sleep(1.2)

    def test_quick():
        pass
""")


def _make_times() -> list:
    """The pytest options `make test` ends with (the Makefile's PYTEST_TIMES)."""
    line = next(ln for ln in (REPO_ROOT / "Makefile").read_text().splitlines()
                if ln.startswith("PYTEST_TIMES :="))
    return line.split(":=", 1)[1].split()


def test_make_test_ends_with_its_slowest_tests_and_can_keep_their_times(tmp_path):
    (tmp_path / "test_timed.py").write_text(_TIMED)
    (tmp_path / "conftest.py").write_text(textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(REPO_ROOT)!r})
        from tests.scheduling import DurationRecorder

        def pytest_configure(config):
            config.pluginmanager.register(DurationRecorder({str(tmp_path / 'd.json')!r}))
    """))
    make = (REPO_ROOT / "Makefile").read_text().split("\ntest:\n", 1)[1].split("\n\n", 1)[0]
    assert "-m pytest" in make and "$(PYTEST_TIMES)" in make  # the test target uses them
    res = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          *_make_times(), str(tmp_path)], cwd=tmp_path, text=True,
                         capture_output=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "slowest 15 durations" in res.stdout
    assert "test_timed.py::test_sleeps" in res.stdout.split("slowest 15 durations")[1]
    recorded = json.loads((tmp_path / "d.json").read_text())
    assert recorded["test_timed.py::test_sleeps"] >= 1.2
