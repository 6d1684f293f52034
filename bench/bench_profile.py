"""Where a replication's time goes: each stage's wall and CPU seconds, each network type's
training time against its arithmetic floor.

Trains every method of the mapping stage (the paper's gated MLP and the baselines) on both
splits of the paper-size corpus in this process, on one torch thread, recording every training
(:func:`mapping.nets.record_fits`). Per network type it prints the trainings, members, epochs,
seconds, milliseconds per member-epoch, the arithmetic done (GFLOP: forward and backward over
the training frames, forward over the validation frames) and its floor — those GFLOP at this
core's single-thread GEMM rate, measured in the same run — and the ratio of the two. Per method
it prints the fit seconds (GMM regression, VQ and the ridge are no networks: seconds only).

``--run NAME`` also prints each stage's wall and CPU seconds from ``runs/NAME/*/done.json``
(what ``replicate`` prints when it ends) and the same per-network table for every training of
that run (the mapping stage and every grid task record theirs in their summaries).

    python bench/bench_profile.py [--run paper] [--json]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import torch  # noqa: E402

from data_synth.generate import synthesize_corpus  # noqa: E402
from face_model.corpus import load_corpus  # noqa: E402
from face_model.motion_units import fit_corpus_units  # noqa: E402
from groundwork.memory import keep_freed_memory  # noqa: E402
from groundwork.threads import limit_threads  # noqa: E402
from mapping import build_dataset  # noqa: E402
from mapping.experiment import run_experiment  # noqa: E402
from mapping.nets import record_fits  # noqa: E402
from talkingface.config import Config  # noqa: E402
from talkingface.paths import STAGE_FOLDERS  # noqa: E402


def gemm_rate(n: int = 1024, repeat: int = 5) -> float:
    """This core's single-thread float32 GEMM rate (FLOP/s), the best of ``repeat``."""
    a, b = torch.randn(n, n), torch.randn(n, n)
    a @ b
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        a @ b
        best = min(best, time.perf_counter() - t0)
    return 2.0 * n ** 3 / best


def stage_times(run: Path) -> dict:
    """``{stage: (wall s, CPU s)}`` from a run's done.json files."""
    out = {}
    for name in STAGE_FOLDERS:
        f = run / name / "done.json"
        if f.is_file():
            d = json.loads(f.read_text())
            out[name] = (float(d.get("seconds", float("nan"))),
                         float(d.get("cpu_seconds", float("nan"))))
    return out


def run_costs(run: Path) -> dict:
    """Per network type, the trainings of a whole run summed: the mapping stage's and every
    grid task's (the ``fits`` of their summaries, :func:`talkingface.stages.training.
    network_costs`)."""
    summaries = [json.loads(f.read_text()) for f in [run / "mapping" / "done.json",
                 *run.glob("ablations/**/summary.json"), *run.glob("ceiling/**/summary.json"),
                 *run.glob("voices/**/summary.json")] if f.is_file()]
    out: dict = defaultdict(lambda: defaultdict(float))
    for summary in summaries:
        for net, c in summary.get("fits", {}).items():
            for k, v in c.items():
                out[net][k] += v
    return out


def _table(nets: dict, rate: float) -> dict:
    """Per network type: the summed figures, seconds per member-epoch, GFLOP, the floor at
    ``rate`` FLOP/s and the ratio of the seconds to it."""
    networks = {}
    for name, n in sorted(nets.items()):
        floor = n["flops"] / rate
        networks[name] = {"trainings": int(n["trainings"]), "members": int(n["members"]),
                          "epochs": int(n["epochs"]), "seconds": n["seconds"],
                          "ms_per_member_epoch": 1e3 * n["seconds"] / max(n["epochs"], 1),
                          "gflop": n["flops"] / 1e9, "floor_seconds": floor,
                          "ratio_to_floor": n["seconds"] / floor if floor else float("nan")}
    return networks


def _print_table(networks: dict) -> None:
    print(f"{'network':<8} {'fits':>5} {'members':>8} {'epochs':>7} {'seconds':>8} "
          f"{'ms/ep':>7} {'GFLOP':>8} {'floor s':>8} {'ratio':>6}")
    for name, n in networks.items():
        print(f"{name:<8} {n['trainings']:>5} {n['members']:>8} {n['epochs']:>7} "
              f"{n['seconds']:>8.2f} {n['ms_per_member_epoch']:>7.2f} {n['gflop']:>8.2f} "
              f"{n['floor_seconds']:>8.2f} {n['ratio_to_floor']:>6.1f}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.add_argument("--run", help="also print the stage times of runs/RUN")
    p.add_argument("--runs-dir", type=Path, default=Path("runs"))
    p.add_argument("--plain-malloc", action="store_true", help="glibc's default malloc (every "
                   "freed large tensor given back to the system), for the comparison")
    args = p.parse_args()
    limit_threads(1)
    if not args.plain_malloc:
        keep_freed_memory()
    cfg = Config()
    rate = gemm_rate()
    with tempfile.TemporaryDirectory() as tmp:
        synthesize_corpus(Path(tmp) / "corpus", cfg.synth, cfg.seed, progress=False)
        corpus = load_corpus(Path(tmp) / "corpus")
        units, _ = fit_corpus_units(corpus)
        t0 = time.perf_counter()
        data = build_dataset(corpus, units, n_mfcc=cfg.mapping.n_mfcc,
                             mel_fmax_hz=cfg.mapping.mel_fmax_hz)
        feature_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    with record_fits() as fits:
        trained = run_experiment(data, cfg.mapping, n_utterance=units.n_utterance, seed=cfg.seed)
    train_s = time.perf_counter() - t0
    gemm = rate  # measured again after training: the better of the two is the floor's rate
    rate = max(rate, gemm_rate())
    nets = defaultdict(lambda: defaultdict(float))
    for f in fits:
        n = nets[f["network"]]
        for k in ("members", "epochs", "seconds", "flops"):
            n[k] += f[k]
        n["trainings"] += 1
    networks = _table(nets, rate)
    methods = defaultdict(float)
    for r in trained:
        methods[r.method] += r.fit_seconds
    figures = {"gemm_gflops_single_thread": rate / 1e9, "gemm_first_gflops": gemm / 1e9,
               "features_s": feature_s, "train_all_methods_s": train_s,
               "networks": networks, "method_fit_s": dict(methods)}
    if args.run:
        run = args.runs_dir / args.run
        figures["stages"] = {k: {"wall_s": w, "cpu_s": c}
                             for k, (w, c) in stage_times(run).items()}
        figures["run_networks"] = _table(run_costs(run), rate)
    if args.json:
        print(json.dumps(figures))
        return
    print(f"single-thread GEMM: {rate / 1e9:.1f} GFLOP/s; features {feature_s:.1f} s; every "
          f"method on both splits {train_s:.1f} s")
    _print_table(networks)
    print("fit seconds per method (both splits): "
          + ", ".join(f"{m} {s:.1f}" for m, s in methods.items()))
    if args.run:
        print(f"stages of {args.runs_dir / args.run}:")
        for k, v in figures["stages"].items():
            print(f"  {k:<12} {v['wall_s']:8.1f} s wall {v['cpu_s']:8.1f} s CPU")
        print(f"every training of {args.runs_dir / args.run} (the mapping stage and every grid "
              "task, in the workers that ran them) against the floor at this run's GEMM rate:")
        _print_table(figures["run_networks"])


if __name__ == "__main__":
    main()
