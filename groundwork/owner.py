"""One owner at a time: a folder that a command builds (a run, a participant's sessions) is held
by one process, and a second process is refused in one line naming the first.

The lock is ``fcntl.flock`` on ``.<folder>.lock`` beside the folder (the folder's own files stay
the command's), an empty file that is never removed (removing a lock file lets two processes
lock two different files of one name). The operating system drops the lock when its process
ends, however it ends, so the lock of a dead process is free: the next command takes it over.
Who holds it is written beside it, in ``.<folder>.owner`` (process id, command, start time), for
the refusal's message only, and removed when the lock is released.

A process may take the lock of a folder it already holds (the same command reaching the folder
twice): :func:`hold` counts, and the lock is released when the outermost hold ends.
"""
from __future__ import annotations

import fcntl
import json
import os
import sys
import time
from contextlib import ExitStack, contextmanager
from pathlib import Path

from groundwork.errors import TalkingFaceError



def lock_path(folder) -> Path:
    """The lock file of ``folder``: ``.<name>.lock`` beside it."""
    folder = Path(folder)
    return folder.parent / f".{folder.name}.lock"


def owner_path(folder) -> Path:
    """Who holds ``folder``: ``.<name>.owner`` beside it."""
    folder = Path(folder)
    return folder.parent / f".{folder.name}.owner"

_HELD: dict = {}  # resolved folder → [open lock file, depth]
_COMMAND = ExitStack()  # the holds taken for the rest of a command (:func:`acquire`)


class BusyError(TalkingFaceError):
    """Another process holds the folder."""


def owner_of(folder) -> str:
    """Who holds ``folder``, in words (from its owner file): ``"process N (command, started
    YYYY-MM-DD HH:MM:SS)"``, or ``"another process"`` when the file is missing or unreadable."""
    try:
        info = json.loads(owner_path(folder).read_text(encoding="utf-8"))
        started = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(info["started"]))
        return f"process {info['pid']} ({info['command']}, started {started})"
    except (OSError, ValueError, KeyError, TypeError):
        return "another process"


@contextmanager
def hold(folder, what: str = "folder"):
    """Hold ``folder`` for the block (a context manager; see the module text).

    Parameters
    ----------
    folder : path-like
        The folder to own; it need not exist (its parent folder is created when missing).
    what : str
        What the folder is, for the refusal (``"run"``, ``"study folder"``).

    Yields
    ------
    pathlib.Path
        ``folder``. A hold this process already has is counted, not taken again.

    Raises
    ------
    BusyError
        Another process holds it: ``<what> <folder> is in use by process N (command,
        started ...)``.
    """
    folder = Path(folder)
    key = folder.resolve()
    if key in _HELD:
        _HELD[key][1] += 1
        try:
            yield folder
        finally:
            _HELD[key][1] -= 1
        return
    folder.parent.mkdir(parents=True, exist_ok=True)
    f = open(lock_path(folder), "a+b")
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        f.close()
        raise BusyError(f"{what} {folder} is in use by {owner_of(folder)}; wait for it to end "
                        "or stop it, then run the command again") from None
    owner = owner_path(folder)
    tmp = owner.with_name(f"{owner.name}.{os.getpid()}")
    tmp.write_text(json.dumps({"pid": os.getpid(), "started": time.time(),
                               "command": _command()}))
    os.replace(tmp, owner)
    _HELD[key] = [f, 1]
    try:
        yield folder
    finally:
        _HELD[key][1] -= 1
        if _HELD[key][1] == 0:
            del _HELD[key]
            owner.unlink(missing_ok=True)
            fcntl.flock(f, fcntl.LOCK_UN)
            f.close()


def acquire(folder, what: str = "folder") -> Path:
    """Hold ``folder`` until :func:`release_all` (the end of the command that asked).

    Parameters and errors as :func:`hold`; returns ``folder`` as a ``Path``.
    """
    return _COMMAND.enter_context(hold(folder, what))


def release_all() -> None:
    """Release every hold taken by :func:`acquire`."""
    _COMMAND.close()


def _command() -> str:
    """This process's command line, as the user typed it (as near as can be told)."""
    argv = list(sys.argv) or ["?"]
    head = "talkingface" if "talkingface" in argv[0] else Path(argv[0]).name
    return " ".join([head, *argv[1:]])[:200]
