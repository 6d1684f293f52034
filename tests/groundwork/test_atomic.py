"""Atomic files: the final name holds the old or the complete new contents, never a part; the
temporary file is gone afterwards, whether the write succeeded or not."""
import os
import stat

import pytest

from groundwork import atomic
from groundwork.atomic import atomic_file, partial_path


def _write(tmp, text):
    with open(tmp, "w", newline="") as f:
        f.write(text)


def test_a_file_appears_complete_and_no_temporary_file_is_left(tmp_path):
    path = tmp_path / "a.csv"
    with atomic_file(path) as tmp:
        assert tmp == partial_path(path) == tmp_path / ".a.partial.csv"
        _write(tmp, "x,y\n1,2\n")
        assert not path.exists()
    assert path.read_text() == "x,y\n1,2\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv"]


@pytest.mark.parametrize("unique", [False, True])
def test_a_failed_write_leaves_the_previous_file(tmp_path, unique):
    path = tmp_path / "a.json"
    path.write_text("old")
    with pytest.raises(RuntimeError), atomic_file(path, unique=unique, fsync=True) as tmp:
        _write(tmp, "half")
        raise RuntimeError("killed")
    assert path.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]


def test_unique_temporary_names_let_two_writers_overlap(tmp_path):
    """Two processes writing the same file (e.g. two lab sessions starting at once) each get a
    temporary file of their own (``.<name>.<random>``, readable by the owner only)."""
    path = tmp_path / "dataset_description.json"
    with atomic_file(path, unique=True) as a, atomic_file(path, unique=True) as b:
        assert a != b and a.parent == b.parent == tmp_path
        assert a.name.startswith(".dataset_description.json.")
        assert stat.S_IMODE(a.stat().st_mode) == 0o600
        _write(a, "from a")
        _write(b, "from b")
    assert path.read_text() == "from a"  # the last to finish wins, whole
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]


def test_fsync_flushes_the_file_before_it_is_renamed(tmp_path, monkeypatch):
    path = tmp_path / "a.txt"
    synced = []
    real = os.fsync

    def spy(fd):
        synced.append((os.readlink(f"/proc/self/fd/{fd}") if os.path.isdir("/proc/self/fd")
                       else None, path.exists()))
        real(fd)

    monkeypatch.setattr(atomic.os, "fsync", spy)
    with atomic_file(path, fsync=True, unique=True) as tmp:
        _write(tmp, "text")
    assert len(synced) == 1 and synced[0][1] is False  # before the rename
    assert synced[0][0] in (None, str(tmp))
    assert path.read_text() == "text"
    synced.clear()
    with atomic_file(path) as tmp:  # without fsync, none
        _write(tmp, "more")
    assert synced == []
