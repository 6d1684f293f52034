"""``talkingface cache``: what the content-keyed cache beside ``runs/`` holds, and cleaning it.

    talkingface cache info  [--runs-dir runs]
    talkingface cache clean [--runs-dir runs] [--unused-days N]

The cache (:mod:`groundwork.cache`) keeps what grid tasks, stages and runs share (a corpus's
features, the phones a recogniser hears in it); removing it costs only the time to make them
again.
"""
from __future__ import annotations

from pathlib import Path

from groundwork.cache import cache_size, clean_cache
from talkingface.paths import RunPaths


def _folder(args) -> Path:
    return RunPaths.create("x", runs_dir=args.runs_dir).cache


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


def cmd_cache(args) -> int:
    folder = _folder(args)
    if args.action == "info":
        n, size = cache_size(folder) if folder.is_dir() else (0, 0)
        print(f"{folder}: {n} entries, {_mb(size)}")
        return 0
    n, size = clean_cache(folder, unused_days=args.unused_days)
    what = (f"not used for {args.unused_days:g} days" if args.unused_days is not None
            else "all")
    print(f"{folder}: removed {n} entries ({what}), {_mb(size)}")
    return 0


def add_parser(sub) -> None:
    s = sub.add_parser("cache", help="what the cache of shared intermediate results holds "
                       "(info), or remove it (clean)")
    s.add_argument("action", choices=("info", "clean"))
    s.add_argument("--runs-dir", type=Path, default=Path("runs"),
                   help="the runs folder the cache is beside (default: runs)")
    s.add_argument("--unused-days", type=float, help="clean: only the entries not used for "
                   "this many days")
    s.set_defaults(func=cmd_cache)
