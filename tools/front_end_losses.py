"""Where the phone front ends lose on sentences against pocketsphinx: viseme accuracy per viseme
class (recall of the labelled frames), per speaker and per look-ahead, on the real-speech set's
independently labelled sentence recordings (a measured step; never used to choose anything).

    python tools/front_end_losses.py [RUN_DIR] [--part test|dev] [--kind sentences|digits|all]
                                     [--lookahead-frames 3] [--json]

RUN_DIR (optional): a run whose content-keyed cache holds what the recognisers heard (its
speech_eval stage: every recording at the native rate) and whose own causal front end
(``front_end/causal_front.npz``) is scored; without it, the shipped front end, heard now (a few
minutes on 2 cores). Frames at 30 fps (frame k at k / 30 s); a frame's truth is the viseme of
the labelled phone holding its instant (:func:`analysis.speech_scores.phone_frames`,
:func:`analysis.speech_scores.viseme_index`).

Printed, for pocketsphinx, hama and the causal front end:

1. per viseme class, the share of the frames labelled with it that the front end names with it
   (recall) at the look-ahead, and the frames labelled;
2. per speaker, viseme accuracy over every frame at the look-ahead;
3. per look-ahead (0–6 frames, 0–200 ms), viseme accuracy over every frame of the part.
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
from analysis.speech_scores import viseme_index  # noqa: E402
from analysis.speech_set import load_speech_set  # noqa: E402
from face_model.phones import VISEMES  # noqa: E402
from groundwork.cache import ArrayCache  # noqa: E402
from groundwork.errors import ParameterError  # noqa: E402
from mapping.recogniser import hearing_cache, recogniser_name  # noqa: E402
from talkingface.paths import RunPaths  # noqa: E402

FPS = 30
KINDS = ("sentences", "digits", "all")


def frames(items, recognisers, fps: int = FPS) -> dict:
    """``{recogniser: {"true": visemes, "speaker": ids, "said": {look-ahead: visemes}}}``, every
    frame of ``items`` concatenated in their order."""
    out = {}
    for rec in recognisers:
        true, spk, said = [], [], {k: [] for k in LOOKAHEAD_FRAMES}
        for it in items:
            n = label_frames(len(it.audio), it.sr, fps)
            true.append(viseme_index(phone_frames(it.phones, np.arange(n) / fps)))
            spk += [it.speaker] * n
            _, streams = recognised(rec, it.audio, it.sr, fps)
            for k in LOOKAHEAD_FRAMES:
                said[k].append(viseme_index(fit_frames(streams[k], n, what=it.id)))
        out[rec] = {"true": np.concatenate(true), "speaker": np.asarray(spk, dtype=object),
                    "said": {k: np.concatenate(v) for k, v in said.items()}}
    return out


def losses(heard: dict, lookahead: int) -> dict:
    """The three tables (module docstring) from :func:`frames`."""
    by_class, by_speaker, by_lookahead = {}, {}, {}
    for rec, f in heard.items():
        name = recogniser_name(rec)
        true, said = f["true"], f["said"][lookahead]
        by_class[name] = {v: {"frames": int((true == i).sum()),
                              "recall": float((said[true == i] == i).mean())
                              if (true == i).any() else None}
                          for i, v in enumerate(VISEMES)}
        by_speaker[name] = {s: float((said[f["speaker"] == s] == true[f["speaker"] == s]).mean())
                            for s in sorted(set(f["speaker"]))}
        by_lookahead[name] = {k: float((f["said"][k] == true).mean()) for k in LOOKAHEAD_FRAMES}
    return {"lookahead_frames": lookahead, "by_class": by_class, "by_speaker": by_speaker,
            "by_lookahead": by_lookahead}


def _table(title: str, rows: dict, cols: list, fmt) -> list[str]:
    width = max(len(r) for r in rows) + 2
    lines = [title, f"{'':<{width}}" + "".join(f"{str(c):>11}" for c in cols)]
    for name, vals in rows.items():
        lines.append(f"{name:<{width}}" + "".join(f"{fmt(vals.get(c)):>11}" for c in cols))
    return lines


def report(result: dict, n_items: int, what: str) -> str:
    f3 = (lambda v: "–" if v is None else f"{v:.3f}")
    la = result["lookahead_frames"]
    any_rec = next(iter(result["by_class"].values()))
    lines = [f"{n_items} {what} recordings; look-ahead {la} frames ({1000 * la / FPS:.0f} ms)"]
    lines += _table("1. recall per viseme class (frames labelled: "
                    + ", ".join(f"{v} {d['frames']}" for v, d in any_rec.items()) + ")",
                    {n: {v: d["recall"] for v, d in c.items()} for n, c in
                     result["by_class"].items()}, list(VISEMES), f3)
    speakers = sorted({s for v in result["by_speaker"].values() for s in v})
    lines += _table("2. viseme accuracy per speaker", result["by_speaker"], speakers, f3)
    lines += _table("3. viseme accuracy per look-ahead (frames)", result["by_lookahead"],
                    list(LOOKAHEAD_FRAMES), f3)
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", nargs="?", help="a run whose speech_eval stage has run")
    ap.add_argument("--part", choices=("test", "dev"), default="test")
    ap.add_argument("--kind", choices=KINDS, default="sentences")
    ap.add_argument("--lookahead-frames", type=int, default=3, choices=LOOKAHEAD_FRAMES)
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
        items = [it for it in load_speech_set() if it.part == args.part and it.independent
                 and args.kind in ("all", it.kind)]
        if not items:
            raise ParameterError(f"no independently labelled {args.kind} recordings in the "
                                 f"{args.part} part of the real-speech set")
        with hearing_cache(cache) if cache is not None else nullcontext():
            result = losses(frames(items, recs), args.lookahead_frames)
    except ParameterError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    what = f"independently labelled {args.kind} {args.part}-part"
    if args.json:
        print(json.dumps({"recordings": len(items), "what": what, **result}, indent=1))
        return 0
    print(report(result, len(items), what))
    return 0


if __name__ == "__main__":
    sys.exit(main())
