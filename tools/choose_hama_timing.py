"""Re-run the sweep behind hama's timing constants in ``mapping/hama_front.py`` (``SPIKE_LAG``,
``REACH``, ``BOUNDARY``, ``EDGE``, ``RESAMPLE_QUALITY``) on the development part of the
real-speech set, print the tables and the pick.

    python tools/choose_hama_timing.py [--set-dir DIR] [--no-stream] [--json] [--check]

Data: the recordings of the real-speech set (:func:`analysis.speech_set.load_speech_set`) whose
``part`` is ``dev`` in the manifest when the command runs (an error when there are none).
Score: viseme frame accuracy pooled over every frame of those recordings (frame k at k / 30 s;
its true phone the labelled segment holding that instant, :func:`analysis.speech_eval.
phone_frames`; visemes by :func:`analysis.speech_eval.viseme_index`).

1. Whole utterances. Each recording's log posteriors are decoded once
   (:func:`mapping.hama_front.whole_posteriors`) and read with every spike lag in
   :data:`LAGS`, reach in :data:`REACHES` and boundary in :data:`BOUNDARIES`
   (:func:`mapping.hama_front.whole_frames`, the edge rule on as in the whole-utterance
   reference). The pick is the most frames right; ties (equal counts) go to the smaller lag,
   then the smaller reach, then the boundary earlier in :data:`BOUNDARIES` (the midpoint first).
2. Streams. With the timing of step 1, each recording resampled to the mapping's
   :data:`STREAM_RATE` and streamed (:func:`mapping.hama_front.stream_decodes`, one stream per
   resampler quality; its decodes read with and without the edge rule) at the look-ahead of
   :data:`STREAM_DELAY` frames. The pick is the most frames right; ties go to the quality
   earlier in ``RESAMPLE_QUALITIES`` (the quickest first), then to the edge rule on.

``--check`` exits 1 with one line naming every constant that differs from the pick.
``--no-stream`` runs step 1 only (one decode per recording; the stream constants ``EDGE`` and
``RESAMPLE_QUALITY`` are then neither swept nor checked): step 2 streams every recording once per
resampler quality, several times the cost of step 1.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from analysis.speech_eval import frame_accuracy, phone_frames, viseme_index  # noqa: E402
from analysis.speech_set import SET_DIR, load_speech_set, read_manifest  # noqa: E402
from groundwork.audio import resample  # noqa: E402
from groundwork.errors import CorpusError, ParameterError  # noqa: E402
from mapping import hama_front  # noqa: E402
from mapping.hama_front import Timing  # noqa: E402

FPS = 30
LAGS = (0, 1, 2, 3, 4, 5)  # output frames (20 ms each); only integer lags exist in the code
REACHES = tuple(range(1, 13))  # output frames
BOUNDARIES = (0.5, 0.35, 0.65)  # fraction of the way between two spikes; the midpoint first
STREAM_RATE = 22050  # Hz, the rate the mapping's audio reaches the stream at
STREAM_DELAY = 3  # video frames of look-ahead (100 ms), HamaStream's default
EDGES = (True, False)


def dev_items(set_dir=SET_DIR) -> list:
    """The set's recordings whose ``part`` is ``dev`` now."""
    ids = [r["id"] for r in read_manifest(set_dir) if r["part"] == "dev"]
    if not ids:
        raise CorpusError(f"{Path(set_dir) / 'manifest.csv'}: no recordings with part 'dev'; "
                          f"the sweep needs the development part")
    return load_speech_set(set_dir, ids=ids)


def true_visemes(item, n_frames: int) -> np.ndarray:
    """The labelled viseme of each of ``n_frames`` video frames of ``item``."""
    return viseme_index(phone_frames(item.phones, np.arange(n_frames) / FPS))


def timing_grid():
    """Every timing of step 1, in tie-break order."""
    return [Timing(lag=lag, reach=reach, boundary=b, edge=True)
            for lag in LAGS for reach in REACHES for b in BOUNDARIES]


def pick(rows: list[dict], key: str = "hits") -> dict:
    """The first row (rows are in tie-break order) with the most ``key``."""
    best = max(r[key] for r in rows)
    return next(r for r in rows if r[key] == best)


def sweep_timing(posteriors: list, truths: list, grid=None) -> list[dict]:
    """One row per timing of ``grid`` (default :func:`timing_grid`): frames right pooled over
    the recordings. ``posteriors``: per recording ``(log posteriors, pad)`` of
    :func:`mapping.hama_front.whole_posteriors`; ``truths``: per recording its true visemes."""
    grid = timing_grid() if grid is None else list(grid)
    hits = np.zeros(len(grid), dtype=np.int64)
    frames = sum(len(t) for t in truths)
    for (lp, pad), true in zip(posteriors, truths):
        classes = {}  # output classes per (reach, boundary): computed once, read at every lag
        for i, t in enumerate(grid):
            key = (t.reach, t.boundary)
            if key not in classes:
                classes[key] = (hama_front.output_classes(lp, reach=t.reach, boundary=t.boundary)
                                [pad:] if lp is not None else np.zeros(0, np.int64))
            pred = [hama_front.read_frame((0, classes[key]), k, FPS, lag=t.lag, edge=t.edge)
                    for k in range(len(true))]
            hits[i] += int(np.sum(viseme_index(np.asarray(pred, np.int64)) == true))
    return [{"lag": t.lag, "reach": t.reach, "boundary": t.boundary, "hits": int(h),
             "frames": frames, "viseme_acc": h / frames if frames else float("nan")}
            for t, h in zip(grid, hits)]


def sweep_stream(items, timing: Timing, qualities=hama_front.RESAMPLE_QUALITIES) -> list[dict]:
    """One row per (resampler quality, edge rule): frames right streaming at
    :data:`STREAM_RATE` with ``timing``'s lag, reach and boundary."""
    audio = [resample(it.audio, sr_in=it.sr, sr_out=STREAM_RATE) for it in items]
    rows = []
    for q in qualities:
        decodes = [hama_front.stream_decodes(y, STREAM_RATE, FPS, timing=timing,
                                             resample_quality=q) for y in audio]
        for edge in EDGES:
            hits = frames = 0
            for it, sd in zip(items, decodes):
                labels = hama_front.labels_from_decodes(sd, FPS, [STREAM_DELAY],
                                                        lag=timing.lag, edge=edge)[STREAM_DELAY]
                true = true_visemes(it, len(labels))
                hits += int(np.sum(viseme_index(labels) == true))
                frames += len(true)
            rows.append({"quality": q, "edge": edge, "hits": hits, "frames": frames,
                         "viseme_acc": hits / frames if frames else float("nan")})
    return rows


def constants() -> dict:
    return {"SPIKE_LAG": hama_front.SPIKE_LAG, "REACH": hama_front.REACH,
            "BOUNDARY": hama_front.BOUNDARY, "EDGE": hama_front.EDGE,
            "RESAMPLE_QUALITY": hama_front.RESAMPLE_QUALITY}


def run(set_dir=SET_DIR, *, stream: bool = True) -> dict:
    items = dev_items(set_dir)
    posteriors = [hama_front.whole_posteriors(it.audio) for it in items]
    truths = [true_visemes(it, int(np.ceil(len(it.audio) * FPS / it.sr))) for it in items]
    whole = sweep_timing(posteriors, truths)
    w = pick(whole)
    timing = Timing(lag=w["lag"], reach=w["reach"], boundary=w["boundary"])
    chosen = {"SPIKE_LAG": w["lag"], "REACH": w["reach"], "BOUNDARY": w["boundary"]}
    rows = []
    if stream:
        rows = sweep_stream(items, timing)
        s = pick(rows)
        chosen.update({"EDGE": s["edge"], "RESAMPLE_QUALITY": s["quality"]})
    return {"recordings": [{"id": it.id, "speaker": it.speaker, "label_source": it.label_source,
                            "frames": len(t)} for it, t in zip(items, truths)],
            "whole": whole, "stream": rows, "pick": chosen, "constants": constants()}


def differences(result: dict) -> list[str]:
    """``NAME code → pick`` for every constant that differs from the pick."""
    return [f"{k} {result['constants'][k]!r} → {v!r}" for k, v in result["pick"].items()
            if result["constants"][k] != v]


def table(result: dict) -> str:
    recs = result["recordings"]
    speakers = sorted({r["speaker"] for r in recs})
    sources = sorted({r["label_source"] for r in recs})
    frames = sum(r["frames"] for r in recs)
    lines = [f"development part: {len(recs)} recordings, {len(speakers)} speakers "
             f"({', '.join(speakers)}), {frames} frames at {FPS} fps; labels: "
             f"{'; '.join(sources)}",
             "score: viseme frame accuracy pooled over the frames", "",
             "1. whole utterances (edge rule on): rows spike lag (output frames of 20 ms), "
             "columns reach (output frames)"]
    by = {(r["lag"], r["reach"], r["boundary"]): r["viseme_acc"] for r in result["whole"]}
    for b in BOUNDARIES:
        lines.append(f"boundary {b:g} of the way" + (" (midpoint)" if b == 0.5 else ""))
        lines.append("lag \\ reach " + "".join(f"{r:>7}" for r in REACHES))
        for lag in LAGS:
            lines.append(f"{lag:>11} " + "".join(f"{by[(lag, r, b)]:>7.3f}" for r in REACHES))
    lines += ["rule: the most frames right; ties to the smaller lag, then the smaller reach, "
              "then the boundary in the order " + ", ".join(f"{b:g}" for b in BOUNDARIES), ""]
    p = result["pick"]
    if not result["stream"]:
        lines += ["2. streams: not run (--no-stream)", ""]
    else:
        lines += _stream_lines(result)
    lines.append("pick: " + ", ".join(f"{k} = {v!r}" for k, v in p.items()))
    diff = differences(result)
    lines.append("mapping/hama_front.py: " + ("the same" if not diff else
                                               "differs: " + "; ".join(diff)))
    return "\n".join(lines)


def _stream_lines(result: dict) -> list[str]:
    p, lines = result["pick"], []
    lines.append(f"2. streams at {STREAM_RATE} Hz, look-ahead {STREAM_DELAY} frames, lag "
                 f"{p['SPIKE_LAG']}, reach {p['REACH']}, boundary {p['BOUNDARY']:g}")
    lines.append(f"{'quality':>8}  {'edge rule on':>12}  {'edge rule off':>13}")
    sby = {(r["quality"], r["edge"]): r["viseme_acc"] for r in result["stream"]}
    for q in dict.fromkeys(r["quality"] for r in result["stream"]):
        lines.append(f"{q:>8}  {sby[(q, True)]:>12.3f}  {sby[(q, False)]:>13.3f}")
    lines += ["rule: the most frames right; ties to the quality earlier in "
              + ", ".join(hama_front.RESAMPLE_QUALITIES) + ", then the edge rule on", ""]
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set-dir", type=Path, default=SET_DIR,
                    help="the real-speech set (default: analysis/real_speech)")
    ap.add_argument("--no-stream", action="store_true",
                    help="step 1 only: SPIKE_LAG, REACH and BOUNDARY from whole utterances")
    ap.add_argument("--json", action="store_true", help="print the result as JSON")
    ap.add_argument("--check", action="store_true",
                    help="exit 1 with one line if a constant differs from the pick")
    args = ap.parse_args(argv)
    try:
        result = run(args.set_dir, stream=not args.no_stream)
    except (CorpusError, ParameterError) as e:
        print(e, file=sys.stderr)
        return 2
    if args.check:
        diff = differences(result)
        if diff:
            print("mapping/hama_front.py differs from the development sweep's pick: "
                  + "; ".join(diff), file=sys.stderr)
            return 1
        print("mapping/hama_front.py: the constants are the development sweep's pick")
        return 0
    print(json.dumps(result, indent=1) if args.json else table(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
