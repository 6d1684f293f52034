"""How well each phone recogniser names /p b m/ on real speech: recall and precision of the
bilabial frames, streaming at a look-ahead, on the real-speech set's independently labelled
test recordings (a measured step behind the models' closures; never used to choose anything).

    python tools/recogniser_bilabials.py [RUN_DIR] [--lookahead-frames 3] [--per-speaker N]
                                         [--json]

RUN_DIR (optional): a run whose content-keyed cache holds what the recognisers heard (its
speech_eval stage), and whose own causal front end (``front_end/causal_front.npz``) is scored;
without it, the shipped front end, heard now. A frame counts as /p b m/ when its label is p, b
or m; recall is the share of those frames the recogniser names p, b or m, precision the share of
the frames it names so that are labelled so.
"""
from __future__ import annotations

import argparse
import json
import sys
from contextlib import nullcontext
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from analysis.speech_recogniser import LOOKAHEAD_FRAMES, recognised  # noqa: E402
from analysis.speech_scores import fit_frames, label_frames, phone_frames  # noqa: E402
from analysis.speech_set import load_speech_set  # noqa: E402
from face_model.phones import BILABIALS, PHONE_INDEX  # noqa: E402
from groundwork.cache import ArrayCache  # noqa: E402
from groundwork.errors import ParameterError  # noqa: E402
from mapping.recogniser import hearing_cache, recogniser_name  # noqa: E402
from talkingface.paths import RunPaths  # noqa: E402

BILABIAL = sorted(PHONE_INDEX[p] for p in BILABIALS)


def bilabial_rows(items, recognisers, lookahead_frames: int = 3, fps: int = 30) -> list[dict]:
    """Per recogniser: the labelled /p b m/ frames of ``items``, recall and precision."""
    rows = []
    for rec in recognisers:
        hit = labelled = named = 0
        for it in items:
            n = label_frames(len(it.audio), it.sr, fps)
            true = np.isin(phone_frames(it.phones, np.arange(n) / fps), BILABIAL)
            _, streams = recognised(rec, it.audio, it.sr, fps)
            said = np.isin(fit_frames(streams[lookahead_frames], n, what=it.id), BILABIAL)
            hit += int((true & said).sum())
            labelled += int(true.sum())
            named += int(said.sum())
        rows.append({"recogniser": recogniser_name(rec), "bilabial_frames": labelled,
                     "named_bilabial": named, "recall": hit / labelled if labelled else None,
                     "precision": hit / named if named else None})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", nargs="?", help="a run whose speech_eval stage has run")
    ap.add_argument("--lookahead-frames", type=int, default=3, choices=LOOKAHEAD_FRAMES)
    ap.add_argument("--per-speaker", type=int, default=0,
                    help="the first N recordings of each speaker and part (0: all)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    try:
        recs = ["pocketsphinx", "hama", "causal"]
        cache = None
        if args.run_dir is not None:
            paths = RunPaths.at(Path(args.run_dir))
            if not paths.root.is_dir():
                raise ParameterError(f"{args.run_dir}: not a run folder")
            cache = ArrayCache(paths.cache)
            front = paths.stage("front_end") / "causal_front.npz"
            if front.is_file():
                recs[-1] = f"causal:{front.resolve()}"
        items = [it for it in load_speech_set(per_speaker=args.per_speaker)
                 if it.part == "test" and it.independent]
        with hearing_cache(cache) if cache is not None else nullcontext():
            rows = bilabial_rows(items, recs, args.lookahead_frames)
    except ParameterError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps({"recordings": len(items), "rows": rows}, indent=1))
        return 0
    print(f"/p b m/ frames of {len(items)} independently labelled test recordings, streaming "
          f"with {args.lookahead_frames} frames of look-ahead:")
    for r in rows:
        rec = "–" if r["recall"] is None else f"{r['recall']:.3f}"
        pre = "–" if r["precision"] is None else f"{r['precision']:.3f}"
        print(f"  {r['recogniser']:<40} "
              f"labelled {r['bilabial_frames']:>5}  named {r['named_bilabial']:>5}  "
              f"recall {rec}  precision {pre}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
