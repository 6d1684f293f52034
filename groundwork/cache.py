"""A content-keyed store of arrays shared by every task, stage and run (``cache/`` beside
``runs/``).

What many grid tasks need in common — the MFCC of a corpus, the phones a recogniser hears in it —
is computed once per *content key* (the SHA-256 of what it is made from: the corpus's own hash,
the settings, the code's version of the computation) and read back by every later task, stage
and run that asks for the same key. An entry is one ``.npz`` file of named arrays (no pickled
objects) at ``<root>/<kind>/<key>.npz``:

* written to a temporary name and renamed into place, so a reader never sees half an entry;
* built under a per-key lock file (``fcntl.flock``), so when two processes race for one key the
  second waits and reads the first's entry: one build, one valid entry;
* an unreadable entry (a truncated file from a full disk, say) is built again, never used;
* removed by ``talkingface cache clean`` (all, or those not used for some days); nothing in a
  run refers to the cache, so removing it only costs the time to build the entries again.
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
import time
import uuid
import zipfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from groundwork.errors import ParameterError

SUFFIX = ".npz"


def content_key(*parts) -> str:
    """The key of an entry: the SHA-256 of what it is made from.

    Parameters
    ----------
    *parts : JSON-able values
        E.g. a corpus hash, a settings dict and a version string of the computation; dicts
        are serialised with sorted keys, anything else JSON cannot hold by ``str``.

    Returns
    -------
    str
        64 hexadecimal characters.
    """
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


class ArrayCache:
    """Entries of named arrays under ``root``, keyed by content (see the module docstring).

    ``get_or_make(kind, key, make)`` returns the arrays of an entry, calling ``make()`` (which
    returns ``{name: ndarray}``) only when the entry is missing or unreadable.

    Parameters
    ----------
    root : path-like
        The cache folder (``cache/`` beside ``runs/``); created when the first entry is written.

    Attributes
    ----------
    hits, misses : int
        This object's lookups answered from an entry, and those that built one.
    """

    def __init__(self, root):
        self.root = Path(root)
        self.hits = 0
        self.misses = 0

    def path(self, kind: str, key: str) -> Path:
        """The entry's file, ``<root>/<kind>/<key>.npz``; ``kind`` (``mfcc``, ``phones``)
        must be a Python identifier (else :class:`~groundwork.errors.ParameterError`)."""
        if not kind.isidentifier():
            raise ParameterError(f"cache kind {kind!r} must be an identifier")
        return self.root / kind / f"{key}{SUFFIX}"

    def get(self, kind: str, key: str) -> dict | None:
        """The arrays of an entry, or None when it is missing or unreadable."""
        path = self.path(kind, key)
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {name: z[name] for name in z.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile):
            return None
        try:
            os.utime(path)  # last use, for `cache clean --unused-days`
        except OSError:
            pass
        return arrays

    @contextmanager
    def _lock(self, kind: str, key: str):
        path = self.path(kind, key)
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path.with_suffix(".lock"), "a") as f:
            fcntl.flock(f, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(f, fcntl.LOCK_UN)

    def put(self, kind: str, key: str, arrays: dict) -> Path:
        """Write an entry atomically (a temporary file renamed into place)."""
        path = self.path(kind, key)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{key}.{uuid.uuid4().hex[:8]}.partial{SUFFIX}")
        try:
            np.savez(tmp, **arrays)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
        return path

    def get_or_make(self, kind: str, key: str, make) -> dict:
        """The arrays of an entry, built by ``make`` when it is missing or unreadable.

        Parameters
        ----------
        kind : str
            The family of entries (a folder of the cache; an identifier).
        key : str
            The entry's :func:`content_key`.
        make : callable
            ``make() -> {name: ndarray}``, called at most once, under the key's lock: a
            process racing for the same key waits and reads this one's entry.

        Returns
        -------
        dict of str to ndarray
            The entry's arrays (``make``'s own when it was called; a failure to store them,
            e.g. a full disk, costs the reuse only).
        """
        arrays = self.get(kind, key)
        if arrays is not None:
            self.hits += 1
            return arrays
        with self._lock(kind, key):
            arrays = self.get(kind, key)  # another process may have made it while we waited
            if arrays is not None:
                self.hits += 1
                return arrays
            self.misses += 1
            arrays = make()
            try:
                self.put(kind, key, arrays)
            except OSError:  # a full or read-only disk costs the reuse, not the result
                pass
            return arrays


def cache_size(root) -> tuple[int, int]:
    """``(entries, bytes)`` of the cache at ``root`` (interrupted writes not counted)."""
    files = [p for p in Path(root).glob(f"*/*{SUFFIX}") if not p.name.startswith(".")]
    return len(files), sum(p.stat().st_size for p in files)


def clean_cache(root, *, unused_days: float | None = None) -> tuple[int, int]:
    """Remove the cache's entries and what interrupted writes left (``talkingface cache clean``).

    Parameters
    ----------
    root : path-like
        The cache folder; a missing one is nothing to clean.
    unused_days : float, optional
        Remove only the entries not used (read or written) for this many days; None: remove
        the whole folder.

    Returns
    -------
    tuple of int
        ``(entries, bytes)`` removed (interrupted writes count in bytes only).

    Raises
    ------
    ParameterError
        ``unused_days`` negative or not a number.
    """
    root = Path(root)
    if unused_days is not None and not unused_days >= 0:
        raise ParameterError(f"--unused-days must be a number of days >= 0, got {unused_days}")
    if not root.is_dir():
        return 0, 0
    if unused_days is None:
        n, size = cache_size(root)
        shutil.rmtree(root)
        return n, size
    cutoff = time.time() - unused_days * 86400
    n = size = 0
    for p in root.glob(f"*/*{SUFFIX}"):  # entries and interrupted writes, by last use
        st = p.stat()
        if st.st_mtime < cutoff:
            n += not p.name.startswith(".")
            size += st.st_size
            p.unlink(missing_ok=True)
    return n, size
