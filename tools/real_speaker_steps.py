"""Where the real speaker's Table II R goes (issue 39): the steps that need no trained mapping,
measured on the real speaker's *training* sentences only, printed; with ``--trained DIR``, also
the trained steps of ``configs/real_steps.yaml`` (3 seeds each), trained into ``DIR``.

    python tools/real_speaker_steps.py [--corpus DIR] [--seed N] [--json] [--trained DIR]

The rows and how they are measured: :mod:`talkingface.stages.real_steps` (the ``real_steps``
stage of ``make replicate`` writes the same to ``runs/<name>/real_steps/steps.json``). Data: the
built-in real speaker (``face_model/real_faces/grid-s1``) or ``--corpus``, the default config
with ``--seed`` as the run seed; the held-out sentences are never read.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from groundwork.errors import TalkingFaceError  # noqa: E402
from talkingface.config import Config  # noqa: E402
from talkingface.stages.real_speaker import BUILTIN  # noqa: E402
from talkingface.stages.real_steps import measure_steps, train_steps  # noqa: E402


def measure(corpus_dir: Path, seed: int) -> dict:
    """The stage's rows for ``corpus_dir`` under the default config with run seed ``seed``."""
    return measure_steps(corpus_dir, dataclasses.replace(Config(), seed=seed))


def show(res: dict) -> None:
    print(f"{res['corpus']}: {res['training_sentences']} training sentences, "
          f"{res['frames']} frames (held-out sentences not read)")
    print(f"measurement floor: markers vs their MU reconstruction R {res['reconstruction_r']:.3f};"
          " truth vs its moving average R " + ", ".join(
              f"{v:.3f} ({w} frames)" for w, v in res["smoothing_floor"].items()))
    d = res["definition"]
    print(f"the probe (±3 frames) by Eq. 6 as the paper R {d['paper']:.3f}; against the markers "
          f"{d['markers']:.3f}; in pixels, undivided {d['pixels']:.3f}")
    print("audio-video offset (lag: R): " + ", ".join(
        f"{k:+d}: {v:.3f}" for k, v in res["offset"]["r"].items())
        + f"; best {res['offset']['best']:+d}")
    print("audio context (frames either side: R): " + ", ".join(
        f"{k}: {v:.3f}" for k, v in res["context"].items()))
    print("oracle, true phones (context: R): " + ", ".join(
        f"{k}: {v:.3f}" for k, v in res["oracle"].items())
        + f"; phones and audio: {res['oracle_and_audio']:.3f}")
    proj = res.get("learning_projection")
    print("more data (sentences the probe is fitted on: R): " + ", ".join(
        f"{k}: {v:.3f}" for k, v in res["learning_curve"].items())
        + (f"; {proj['per_doubling']:+.3f} per doubling, {proj['sentences']} sentences: "
           f"{proj['r']:.3f}" if proj else ""))
    print("by region (share of what Eq. 6 weighs, the probe's R on it alone): " + ", ".join(
        f"{k} {100 * v['weight']:.0f} % R {v['r']:.3f}" for k, v in res["regions"].items()))
    print(f"{'unit':>4s} {'var':>6s} {'lips':>6s} {'cheeks':>6s} {'brows':>6s} {'x':>6s} "
          f"{'R audio':>7s}")
    for u in res["units"]:
        print(f"{u['unit']:4d} {u['variance_share']:6.3f} {u['lips']:6.2f} {u['cheeks']:6.2f} "
              f"{u['forehead']:6.2f} {u['x']:6.2f} {u['r_audio']:7.3f}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--corpus", type=Path, default=BUILTIN)
    p.add_argument("--seed", type=int, default=Config().seed, help="the run seed")
    p.add_argument("--json", action="store_true")
    p.add_argument("--trained", type=Path, metavar="DIR",
                   help="also train the grid's steps into DIR (an empty or new folder; a "
                        "folder of the same steps is reused) and print their R")
    args = p.parse_args(argv)
    try:
        if args.trained is not None and args.trained.exists() and (
                not args.trained.is_dir()
                or any(args.trained.iterdir()) and not (args.trained / "corpora").is_dir()):
            raise TalkingFaceError(f"--trained {args.trained}: not an empty folder nor one "
                                   "this command trained into; give a new folder")
        res = measure(args.corpus, args.seed)
        if args.trained is not None:
            cfg = dataclasses.replace(Config(), seed=args.seed)
            res["trained"] = train_steps(args.corpus, args.trained, cfg,
                                         cache=args.trained / "corpora" / "cache")
    except TalkingFaceError as exc:  # a folder that is not a corpus: one line, exit 2
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(res, indent=1, default=float))
    else:
        show(res)
        for r in res.get("trained", []):
            print(f"trained {r['step']}: R {float(r['utterance_R']):.3f} ± "
                  f"{float(r['utterance_R_ci95']):.3f} (utterance split), "
                  f"{float(r['random_frames_R']):.3f} ± {float(r['random_frames_R_ci95']):.3f} "
                  "(frame split)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
