"""Hearing recordings once, on every core (issue 38): the time to hear N recordings of the
real-speech set (``analysis/real_speech``, resampled to the mapping's 22,050 Hz; windows of
3 past and 3 future frames, as the default voice model's front end) with each recogniser's
stream, one process after the other (``mapping.hearing.hear_all`` with ``workers=1``) against
a pool of every core (``workers=0``, pool start-up included), and a warm pass that reads every
entry from the cache — measured side by side in one run, each into its own fresh cache.

It also prints the time a pool takes to start (one 0.2-s job per worker: a spawned worker
imports the ``mapping`` package, torch included), the serial pass's CPU time over its wall
time (at most 1 for a recogniser on one thread, less when other jobs share the core: a process
per core is then what parallelises it), whether the parallel pass's arrays are byte-identical
to the serial pass's, and the load average before and after (other jobs on the machine take
the cores the pool would use).

    python bench/bench_hearing.py [--recordings 40] [--recogniser hama] [--workers 0] [--json]
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import soxr  # noqa: E402
from _common import report  # noqa: E402

from analysis.speech_set import load_speech_set  # noqa: E402
from groundwork.cache import ArrayCache  # noqa: E402
from groundwork.threads import cores  # noqa: E402
from mapping.hearing import Windows, hear_all  # noqa: E402
from mapping.recogniser import HEARD_KIND, RECOGNISERS  # noqa: E402

SR = 22050


def _pass(jobs, root: Path, workers: int) -> tuple[float, float, object]:
    """(wall s, this process's CPU s, passes) of one pass into the cache at ``root``."""
    cache = ArrayCache(root)
    c0, t0 = os.times(), time.perf_counter()
    passes = hear_all(jobs, cache, workers=workers, progress=False)
    t1, c1 = time.perf_counter(), os.times()
    return t1 - t0, (c1.user - c0.user) + (c1.system - c0.system), passes


def _same(a: Path, b: Path) -> bool:
    fa = sorted((a / HEARD_KIND).glob("*.npz"))
    fb = sorted((b / HEARD_KIND).glob("*.npz"))
    if [f.name for f in fa] != [f.name for f in fb]:
        return False
    for x, y in zip(fa, fb):
        with np.load(x) as zx, np.load(y) as zy:
            if zx["windows"].tobytes() != zy["windows"].tobytes():
                return False
    return True


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--recordings", type=int, default=40, help="recordings of the set, spread "
                   "evenly over it (default 40 of 354)")
    p.add_argument("--recogniser", choices=(*RECOGNISERS, "both"), default="both")
    p.add_argument("--workers", type=int, default=0, help="processes of the parallel pass "
                   "(0: all cores)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    args = p.parse_args()
    items = load_speech_set()
    pick = np.unique(np.linspace(0, len(items) - 1, min(args.recordings, len(items)))
                     .round().astype(int))
    audio = [soxr.resample(items[i].audio.astype(np.float32), items[i].sr, SR)
             .astype(np.float32) for i in pick]
    which = RECOGNISERS if args.recogniser == "both" else (args.recogniser,)
    figures = {"recordings": len(audio), "audio_s": round(sum(len(y) for y in audio) / SR, 1),
               "workers": args.workers or cores(), "load_before": os.getloadavg()[0]}
    for rec in which:
        jobs = [Windows(y, SR, 30, 3, 3, rec) for y in audio]
        with tempfile.TemporaryDirectory() as tmp:
            serial, parallel = Path(tmp) / "serial", Path(tmp) / "parallel"
            s_wall, s_cpu, _ = _pass(jobs, serial, 1)
            p_wall, _, p_passes = _pass(jobs, parallel, args.workers)
            w_wall, _, w_passes = _pass(jobs, parallel, args.workers)
            assert p_passes.heard == len(jobs) and w_passes.reused == len(jobs)
            figures.update({f"{rec}_serial_s": round(s_wall, 2),
                            f"{rec}_serial_cpu_per_wall": round(s_cpu / s_wall, 2),
                            f"{rec}_parallel_s": round(p_wall, 2),
                            f"{rec}_speedup": round(s_wall / p_wall, 2),
                            f"{rec}_warm_s": round(w_wall, 3),
                            f"{rec}_identical": _same(serial, parallel)})
    with tempfile.TemporaryDirectory() as tmp:  # the pool's start-up: one tiny job a worker
        n = args.workers or cores()
        tiny = [Windows(np.full(SR // 5, 1e-3 * (k + 1), np.float32), SR, 30, 3, 3,
                        "pocketsphinx") for k in range(n)]
        figures["pool_startup_s"] = round(_pass(tiny, Path(tmp), args.workers)[0], 2)
    figures["load_after"] = os.getloadavg()[0]
    report(figures, args.json)


if __name__ == "__main__":
    main()
