"""The one line a command prints for a user's mistake: ``error: ...``, never longer than a
terminal can show at a glance.

A message that names many things (every incomplete session of a study of hundreds, every file
of a folder) would otherwise fill the screen with one line. Messages should name the first few
and a count themselves; :func:`error_line` is the bound for those that do not: it keeps the
line's start (what is wrong, and where) and its end (what to do about it), and says how many
characters it left out between them.
"""
from __future__ import annotations

import errno
import os
from pathlib import Path

MAX_CHARS = 600  # the longest error line printed, "error: " included (about 8 lines of 80)
TAIL_CHARS = 200  # of which the message's end (its advice: a flag, a command to run)


def error_line(message: str, *, limit: int = MAX_CHARS, tail: int = TAIL_CHARS) -> str:
    """``error: <message>`` as one line of at most ``limit`` characters.

    Parameters
    ----------
    message : str
        The message (any length; each line break becomes a space).
    limit : int
        The longest line returned.
    tail : int
        How many characters of the message's end are kept when it is cut.

    Returns
    -------
    str
        The line: the message whole when it fits, else its start, ``… (N more characters) …``
        and its last ``tail`` characters.
    """
    line = "error: " + " ".join(str(message).splitlines())
    if len(line) <= limit:
        return line
    widest = len(_marker(len(line)))  # the marker's room, with the most digits it can need
    head = max(0, limit - tail - widest)
    return line[:head] + _marker(len(line) - head - tail) + line[len(line) - tail:]


def _marker(left_out: int) -> str:
    return f" … ({left_out} more characters) … "


# A write that failed for want of room (a full disk, a quota): one line, whatever the file.
OUT_OF_ROOM = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def os_error_line(exc: OSError) -> str | None:
    """The error line of an ``OSError`` about a path the user named (missing, a folder,
    unreadable, not writable), or of a write that ran out of room; None when it names no path
    (a bug: its traceback is kept)."""
    if exc.errno in OUT_OF_ROOM:  # whatever file it was: what ran out is the news
        where = f" writing {exc.filename}" if exc.filename else ""
        return error_line(f"{os.strerror(exc.errno)}{where}; nothing finished was replaced: "
                          "free some space and run the command again")
    if exc.filename is None:
        return None
    return error_line(f"{exc.filename}: {_os_problem(exc)}")


def _os_problem(exc: OSError) -> str:
    """What went wrong with the path of ``exc``, in words (a file where a folder is needed is
    "File exists" or "Not a directory" to the operating system)."""
    if isinstance(exc, FileExistsError) and Path(exc.filename).is_file():
        return "is a file; a folder is needed here"
    if isinstance(exc, NotADirectoryError):
        return "a part of this path is a file; a folder is needed there"
    return exc.strerror or str(exc)
