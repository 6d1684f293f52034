"""Throughput of an ablation grid on Dask: 1 worker against 2, and what a cluster would take.

Trains the same small grid (``--settings`` settings of the ablation grid x ``--seeds`` seeds, the
utterance split, on a corpus of ``--sentences`` sentences) on a Dask LocalCluster with 1 worker,
then with 2, in one run, and prints the wall time of each (cluster start-up included), the
1 -> 2 worker speed-up, the mean cost of one task, and the scheduler's own overhead per task
(``--overhead-tasks`` empty tasks on a 2-worker cluster). From these it projects the wall time
of a ``--project-settings`` x ``--project-seeds`` grid on ``--nodes`` nodes of
``--cores-per-node`` cores (one worker per core):

    waves = ceil(tasks / workers);   T = start-up + waves * task cost + tasks * overhead

which assumes tasks of equal cost, a shared file system and a scheduler that keeps up (the
overhead term counts its per-task time as if serial). The README's "Sweeps on a cluster"
quotes its figures.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from data_synth.generate import synthesize_corpus  # noqa: E402
from talkingface.config import load_config  # noqa: E402
from talkingface.executor import dask_client  # noqa: E402
from talkingface.stages.foundation import fit_units_folder  # noqa: E402
from talkingface.stages.grid import run_grid  # noqa: E402
from talkingface.stages.grid_files import load_grid  # noqa: E402

GRID = Path(__file__).resolve().parent.parent / "configs" / "ablations.yaml"


def _args() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.add_argument("--sentences", type=int, default=100, help="corpus size (default: the "
                   "paper's 100 sentences x 3 expressions)")
    p.add_argument("--settings", type=int, default=2, help="first settings of the grid")
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--overhead-tasks", type=int, default=400)
    p.add_argument("--project-settings", type=int, default=100)
    p.add_argument("--project-seeds", type=int, default=10)
    p.add_argument("--nodes", type=int, default=16)
    p.add_argument("--cores-per-node", type=int, default=os.cpu_count() or 1)
    return p.parse_args()


def _noop(i):
    return i


def scheduler_overhead(n: int) -> tuple[float, float]:
    """(seconds to start a 2-worker LocalCluster, seconds of scheduling per empty task)."""
    t0 = time.perf_counter()
    with dask_client("local", 2) as client:
        started = time.perf_counter() - t0
        client.gather(client.map(_noop, range(20), pure=False))  # warm
        t1 = time.perf_counter()
        client.gather(client.map(_noop, range(n), pure=False))
        per_task = (time.perf_counter() - t1) / n
    return started, per_task


def main() -> None:
    args = _args()
    cfg = load_config(None, [f"synth.n_sentences={args.sentences}"])
    figures = {"cores": os.cpu_count(), "sentences": args.sentences}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        synthesize_corpus(tmp / "corpus", cfg.synth, cfg.seed, progress=False)
        fit_units_folder(tmp / "corpus", tmp / "units", cfg)
        base = load_config(None, [f"synth.n_sentences={args.sentences}",
                                  "mapping.splits=[utterance]", "mapping.baselines=[]"])
        grid = dict(list(load_grid(GRID, base).items())[:args.settings])
        jobs = {n: (tmp / "corpus", tmp / "units" / "motion_units.npz", c)
                for n, c in grid.items()}
        walls, costs = {}, []
        for w in (1, 2):
            t0 = time.perf_counter()
            res = run_grid(jobs, tmp / f"w{w}", seeds=args.seeds, scheduler="local", workers=w,
                           desc=f"{w} worker(s)", progress=not args.json)
            walls[w] = time.perf_counter() - t0
            costs += [r["seconds"] for r in res.values()]
    tasks = args.settings * args.seeds
    start_s, overhead_s = scheduler_overhead(args.overhead_tasks)
    task_s = sum(costs) / len(costs)
    figures.update({
        "grid_tasks": tasks,
        "wall_1_worker_s": walls[1], "wall_2_workers_s": walls[2],
        "speedup_1_to_2": walls[1] / walls[2],
        "tasks_per_min_1_worker": 60 * tasks / walls[1],
        "tasks_per_min_2_workers": 60 * tasks / walls[2],
        "task_cost_s": task_s,
        "cluster_start_s": start_s, "scheduler_overhead_ms_per_task": 1000 * overhead_s})
    n = args.project_settings * args.project_seeds
    workers = args.nodes * args.cores_per_node
    projected = start_s + math.ceil(n / workers) * task_s + n * overhead_s
    figures.update({"project_tasks": n, "project_workers": workers,
                    "project_wall_min": projected / 60,
                    "project_one_machine_min": math.ceil(n / (os.cpu_count() or 1))
                    * task_s / 60})
    if args.json:
        print(json.dumps(figures))
    else:
        for k, v in figures.items():
            print(f"{k:>32s}: {v:.3f}" if isinstance(v, float) else f"{k:>32s}: {v}")


if __name__ == "__main__":
    main()
