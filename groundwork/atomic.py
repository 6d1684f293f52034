"""Outputs that are never half-written under their final name.

A file is written to a temporary name beside it and renamed into place (``os.replace`` is atomic
on one file system); a folder is built beside its target and swapped in only when complete, the
previous folder removed only after the new one is in place. A killed process leaves the previous
output intact and at most a dot-named leftover, which the next build clears.
"""
from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

from groundwork.errors import ParameterError


def partial_path(path) -> Path:
    """The temporary name of ``path`` while it is being written (same folder, same suffix, so
    tools that choose the format by extension still do)."""
    path = Path(path)
    return path.with_name(f".{path.stem}.partial{path.suffix}")


@contextmanager
def atomic_file(path, *, fsync: bool = False, unique: bool = False):
    """Yield a temporary path to write; on success it becomes ``path``, on failure it is
    removed and ``path`` is untouched.

    Parameters
    ----------
    path : path-like
        The final name; its folder must exist.
    fsync : bool
        Flush the written file to disk (``os.fsync``) before it is renamed into place, so that
        after a power cut ``path`` holds the previous or the new contents, never a short file.
    unique : bool
        Write under a temporary name of its own (``tempfile.mkstemp`` beside ``path``:
        ``.<name>.<random>``, created readable by its owner only) instead of
        :func:`partial_path`, for a file that several processes may write at the same time.

    Yields
    ------
    pathlib.Path
        The temporary file to write (and close) inside the ``with`` block.
    """
    path = Path(path)
    if unique:
        fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
        os.close(fd)
        tmp = Path(name)
    else:
        tmp = partial_path(path)
    try:
        yield tmp
        if fsync:
            _fsync(tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _fsync(path: Path) -> None:
    """Flush a closed file's data to disk."""
    fd = os.open(path, os.O_RDWR)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fresh_partial_folder(folder, *, keep=None) -> Path:
    """An empty folder beside ``folder`` to build it in (what an interrupted build left there
    is removed: it was never used), or, when ``keep(partial)`` says so, the interrupted build's
    folder as it is, for a build that goes on from its finished parts."""
    folder = Path(folder)
    partial = folder.parent / f".{folder.name}.partial"
    if partial.exists():
        if keep is not None and keep(partial):
            return partial
        shutil.rmtree(partial)
    partial.mkdir(parents=True)
    return partial


def swap_in(partial, folder) -> Path:
    """Rename the finished ``partial`` folder to ``folder``; the previous ``folder`` is removed
    only after the new one is in place."""
    partial, folder = Path(partial), Path(folder)
    old = folder.parent / f".{folder.name}.replaced"
    if old.exists():
        shutil.rmtree(old)
    if folder.exists():
        os.replace(folder, old)
    os.replace(partial, folder)
    if old.exists():
        shutil.rmtree(old)
    return folder


def check_output_file(path, what: str = "output file", *, overwrite: bool = False) -> Path:
    """Refuse an output path that is a folder, that exists (unless ``overwrite``) or whose folder
    cannot be written, before any work is done (its folder is created when missing)."""
    path = Path(path)
    if path.is_dir():
        raise ParameterError(f"{what} {path} is a folder; give a file name")
    if path.exists() and not overwrite:
        raise ParameterError(f"{what} {path} already exists; pass --overwrite to replace it")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ParameterError(f"{what} {path}: cannot create its folder ({exc.strerror})") from None
    if not os.access(path.parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise ParameterError(f"{what} {path}: not writable")
    return path
