"""A stage's time on a quiet machine and beside a load (by default the test suite), in one run.

Times the ``mapping`` stage (every method × split of the paper-size corpus, ``talkingface train``)
of a checkout, first alone, then while another command loads the machine (``make test`` by
default, started here and stopped when the timing ends), and prints both and their ratio. Issue
24's target: beside the test suite a stage takes at most 2.5× its quiet time. The run is
prepared once (corpus, Motion Units, the cache), and each timing makes the mapping stage again.

    python bench/bench_load.py [--repo DIR] [--beside 'make test'] [--settle 60] [--json]

``--repo``: the checkout to time (its ``.venv`` and code; default: this one), so an older commit
can be measured the same way; ``--settle``: seconds the load runs before the timing starts.
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import signal
import subprocess
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
NAME = "bench-load"


def stage_seconds(repo: Path) -> float:
    """Wall seconds of the mapping stage of ``repo``'s run :data:`NAME`, made afresh."""
    shutil.rmtree(repo / "runs" / NAME / "mapping", ignore_errors=True)
    t0 = time.perf_counter()
    subprocess.run([str(repo / ".venv" / "bin" / "python"), "-m", "talkingface", "train",
                    "--name", NAME, "--set", "mlflow.enabled=false"], cwd=repo, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repo", type=Path, default=ROOT)
    p.add_argument("--beside", default="make test", help="the command that loads the machine")
    p.add_argument("--settle", type=float, default=60.0)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    repo = args.repo.resolve()
    stage_seconds(repo)  # prepares the run (corpus, units) and the caches; not counted
    quiet = stage_seconds(repo)
    load = subprocess.Popen(shlex.split(args.beside), cwd=repo, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        time.sleep(args.settle)
        if load.poll() is not None:
            raise SystemExit(f"bench_load: {args.beside!r} ended before the timing "
                             f"(exit {load.returncode})")
        loaded = stage_seconds(repo)
        still = load.poll() is None
    finally:
        if load.poll() is None:
            os.killpg(load.pid, signal.SIGTERM)
            load.wait()
    figures = {"repo": str(repo), "beside": args.beside, "quiet_s": quiet, "loaded_s": loaded,
               "slowdown": loaded / quiet, "target_slowdown": 2.5,
               "load_ran_throughout": still}
    if args.json:
        print(json.dumps(figures))
    else:
        for k, v in figures.items():
            print(f"{k:>20s}: {v:.2f}" if isinstance(v, float) else f"{k:>20s}: {v}")


if __name__ == "__main__":
    main()
