"""One owner at a time (groundwork.owner): a second process is refused naming the first; the
lock of a process that died is taken over; a process may hold a folder twice."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from groundwork.owner import BusyError, acquire, hold, lock_path, owner_path, release_all

REPO = Path(__file__).resolve().parents[2]
HOLDER = """
import sys, time
sys.path.insert(0, {repo!r})
from groundwork.owner import hold
with hold({folder!r}, "run"):
    print("held", flush=True)
    time.sleep(600)
"""


def _holder(folder: Path) -> subprocess.Popen:
    """A process that holds ``folder`` until killed (returns once it holds it)."""
    proc = subprocess.Popen([sys.executable, "-c", HOLDER.format(repo=str(REPO),
                                                                 folder=str(folder))],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_second_process_is_refused_naming_the_first_and_a_dead_ones_lock_is_taken(tmp_path):
    folder = tmp_path / "runs" / "R"
    proc = _holder(folder)
    try:
        with pytest.raises(BusyError) as err:
            with hold(folder, "run"):
                pass
        msg = str(err.value)
        assert msg.startswith(f"run {folder} is in use by process {proc.pid} (")
        assert "wait for it to end" in msg
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    # the dead process's owner file is still there, its lock is not: taken over
    assert owner_path(folder).is_file()
    with hold(folder, "run"):
        assert f'"pid": {os.getpid()}' in owner_path(folder).read_text()
    assert not owner_path(folder).exists() and lock_path(folder).is_file()
    assert not folder.exists()  # the folder's own files are its command's: nothing in it


def test_one_process_may_hold_a_folder_twice_and_releases_it_at_the_end(tmp_path):
    folder = tmp_path / "R"
    acquire(folder, "run")
    with hold(folder, "run"):  # the same command reaching the run again
        pass
    assert owner_path(folder).is_file()  # still held: the outer hold goes on
    release_all()
    assert not owner_path(folder).exists()
    # another process can take it now
    proc = _holder(folder)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
