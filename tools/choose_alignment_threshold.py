"""Re-run the measurement behind ``MAX_SCORE_GAP`` of ``face_model/forced_align.py``: the gap
threshold at which a transcript is refused as not matching its recording.

    python tools/choose_alignment_threshold.py --grid-dir DIR [--workers N] [--every K]
                                               [--json] [--check]

``DIR`` is a GRID speaker folder (``video/<id>.mpg`` with the audio track, ``align/<id>.align``
word alignments), e.g. ``../shared/grid-s1`` (speaker s1, 400 clips). The clips are the ids
holding both files, in sorted order; the **development** half is the ids sorting into the first
half, the **check** half the rest. Every clip's audio is decoded by FFmpeg to 16 kHz mono
(:func:`face_model.video_corpus.decode_audio`) and aligned
(:func:`face_model.forced_align.force_align`) with three transcripts (the ``.align`` words without
``sil``/``sp``):

* its own;
* the transcript of the clip 7 places further in sorted order within its half (wrapping round);
* its own first 3 words.

Each gives the gap of :attr:`~face_model.forced_align.ForcedAlignment.gap`, or none when no
alignment is found (refused whatever the threshold). A threshold ``t`` refuses a transcript
when ``gap < -t``. The sweep tries ``t`` = 0.5, 1.0, …, 15.0 on the development half; its score
is the total error (own transcripts refused / own transcripts + wrong ones accepted / wrong
ones); the pick is the threshold with the least total error, **ties going to the smallest
threshold** (the strictest check among equals). The check half is printed at the pick only, not
used to choose. ``--every K`` measures every K-th clip of each half only (a quick look; the
pairs of transcripts are those of the full halves); the committed choice comes from the full
run. ``--check`` exits 1 with one line when ``MAX_SCORE_GAP`` is not the pick.
"""
from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import sys
import tempfile
from pathlib import Path

import numpy as np
from tqdm import tqdm

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from face_model import forced_align  # noqa: E402
from face_model.transcripts import read_align  # noqa: E402
from face_model.video_corpus import decode_audio  # noqa: E402
from groundwork.errors import CorpusError, ParameterError  # noqa: E402

SAMPLE_RATE = forced_align.SAMPLE_RATE
OFFSET = 7  # the wrong transcript: the clip this many places further in its half
FIRST_WORDS = 3  # the truncated transcript: its own first words
CANDIDATES = tuple(np.round(np.arange(1, 31) * 0.5, 1))  # thresholds tried, 0.5 … 15.0
KINDS = ("own", "other", "first3")


def clip_ids(grid_dir) -> list[str]:
    """The ids holding both ``video/<id>.mpg`` and ``align/<id>.align``, sorted."""
    grid_dir = Path(grid_dir)
    videos = {p.stem for p in (grid_dir / "video").glob("*.mpg")}
    aligns = {p.stem for p in (grid_dir / "align").glob("*.align")}
    ids = sorted(videos & aligns)
    if len(ids) < 2 * (OFFSET + 1):
        raise ParameterError(f"--grid-dir {grid_dir}: {len(ids)} clips with both video/<id>.mpg "
                             f"and align/<id>.align; need at least {2 * (OFFSET + 1)}")
    return ids


def halves(ids: list[str]) -> dict[str, list[str]]:
    """``{"dev": first half of the sorted ids, "check": the rest}``."""
    ids = sorted(ids)
    return {"dev": ids[: len(ids) // 2], "check": ids[len(ids) // 2:]}


def jobs(grid_dir, every: int = 1) -> list[dict]:
    """One job per clip measured: ``{id, part, video, transcripts: {kind: text}}``."""
    grid_dir = Path(grid_dir)
    text = {}
    out = []
    for part, ids in halves(clip_ids(grid_dir)).items():
        for i, clip in enumerate(ids):
            if i % every:
                continue
            for c in (clip, ids[(i + OFFSET) % len(ids)]):
                if c not in text:
                    text[c] = read_align(grid_dir / "align" / f"{c}.align").text
            own = text[clip]
            out.append({"id": clip, "part": part, "video": str(grid_dir / "video" / f"{clip}.mpg"),
                        "transcripts": {"own": own, "other": text[ids[(i + OFFSET) % len(ids)]],
                                        "first3": " ".join(own.split()[:FIRST_WORDS])}})
    return out


def measure(job: dict) -> dict:
    """The job's gaps ``{kind: gap or None}`` (None: no alignment found)."""
    with tempfile.TemporaryDirectory() as tmp:
        y = decode_audio(Path(job["video"]), SAMPLE_RATE, Path(tmp))
    gaps = {}
    for kind, text in job["transcripts"].items():
        try:
            gaps[kind] = forced_align.force_align(y, SAMPLE_RATE, text, source=job["video"]).gap
        except CorpusError as e:
            if "no alignment" not in str(e):
                raise
            gaps[kind] = None
    return {"id": job["id"], "part": job["part"], **gaps}


def _gaps(rows: list[dict], kind: str) -> np.ndarray:
    return np.array([np.nan if r[kind] is None else r[kind] for r in rows], dtype=np.float64)


def error_counts(own: np.ndarray, wrong: np.ndarray, threshold: float) -> tuple[int, int]:
    """``(own refused, wrong accepted)`` at ``threshold``; a NaN gap (no alignment) is refused."""
    own, wrong = np.asarray(own, np.float64), np.asarray(wrong, np.float64)
    refused = int(np.sum(~np.isfinite(own) | (own < -threshold)))
    accepted = int(np.sum(np.isfinite(wrong) & (wrong >= -threshold)))
    return refused, accepted


def choose_threshold(own, wrong, candidates=CANDIDATES) -> tuple[float, list[dict]]:
    """``(pick, sweep rows)``: the candidate threshold with the least total error
    (own refused / n own + wrong accepted / n wrong), ties to the smallest threshold.

    Parameters
    ----------
    own : array (n_own,)
        Gaps of the own transcripts (NaN: no alignment found).
    wrong : array (n_wrong,)
        Gaps of the wrong transcripts (NaN: no alignment found).
    candidates : sequence of float
        Thresholds tried (refuse when gap < −threshold).
    """
    own, wrong = np.asarray(own, np.float64), np.asarray(wrong, np.float64)
    if not len(own) or not len(wrong):
        raise ParameterError(f"need own and wrong transcripts to choose a threshold, got "
                             f"{len(own)} and {len(wrong)}")
    rows = []
    for t in sorted(float(c) for c in candidates):
        refused, accepted = error_counts(own, wrong, t)
        rows.append({"threshold": t, "own_refused": refused, "n_own": len(own),
                     "wrong_accepted": accepted, "n_wrong": len(wrong),
                     "total_error": refused / len(own) + accepted / len(wrong)})
    best = min(rows, key=lambda r: (round(r["total_error"], 12), r["threshold"]))
    return best["threshold"], rows


def summary(rows: list[dict], threshold: float) -> dict:
    """The figures of one half at ``threshold``."""
    own, other, first3 = (_gaps(rows, k) for k in KINDS)
    wrong = np.r_[other, first3]
    refused, accepted = error_counts(own, wrong, threshold)
    finite = own[np.isfinite(own)]
    return {"clips": len(rows), "own_refused": refused, "n_own": len(own),
            "wrong_accepted": accepted, "n_wrong": len(wrong),
            "other_accepted": error_counts(own, other, threshold)[1],
            "first3_accepted": error_counts(own, first3, threshold)[1],
            "wrong_no_alignment": int(np.sum(~np.isfinite(wrong))),
            "own_no_alignment": int(np.sum(~np.isfinite(own))),
            "own_gap_min": float(finite.min()) if len(finite) else math.nan,
            "own_gap_median": float(np.median(finite)) if len(finite) else math.nan,
            "own_gap_max": float(finite.max()) if len(finite) else math.nan}


def run(grid_dir, *, workers: int = 2, every: int = 1, progress: bool = True) -> dict:
    """Measure every clip and choose on the development half; the result's ``pick``,
    ``sweep`` (development) and ``halves`` (both halves at the pick)."""
    todo = jobs(grid_dir, every)
    bar = tqdm(total=len(todo), desc="aligning", unit="clip", disable=not progress)
    if workers > 1:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            rows = []
            for r in pool.imap(measure, todo, chunksize=2):
                rows.append(r)
                bar.update()
    else:
        rows = []
        for j in todo:
            rows.append(measure(j))
            bar.update()
    bar.close()
    dev = [r for r in rows if r["part"] == "dev"]
    pick, sweep = choose_threshold(_gaps(dev, "own"),
                                   np.r_[_gaps(dev, "other"), _gaps(dev, "first3")])
    return {"grid_dir": str(grid_dir), "every": every, "pick": pick, "sweep": sweep,
            "halves": {p: summary([r for r in rows if r["part"] == p], pick)
                       for p in ("dev", "check")},
            "constant": forced_align.MAX_SCORE_GAP, "clips": rows}


def _pct(n: int, d: int) -> str:
    return f"{n} / {d} ({100 * n / d:.2f} %)" if d else "0 / 0"


def table(result: dict) -> str:
    lines = [f"GRID clips of {result['grid_dir']}"
             + (f", every {result['every']}th of each half" if result["every"] > 1 else "")
             + "; refuse a transcript when gap < -threshold",
             "", "development half: the sweep",
             f"{'threshold':>9}  {'own refused':>16}  {'wrong accepted':>16}  {'total error':>11}"]
    for r in result["sweep"]:
        lines.append(f"{r['threshold']:>9.1f}  {r['own_refused']:>7} / {r['n_own']:<6}  "
                     f"{r['wrong_accepted']:>7} / {r['n_wrong']:<6}  {r['total_error']:>11.4f}")
    pick = result["pick"]
    lines += ["", f"at the pick, threshold {pick:g}",
              f"{'':28}{'development':>22}  {'check':>22}"]
    h = result["halves"]
    for label, n, d in (("own transcript refused", "own_refused", "n_own"),
                        ("wrong transcript accepted", "wrong_accepted", "n_wrong")):
        lines.append(f"{label:28}{_pct(h['dev'][n], h['dev'][d]):>22}  "
                     f"{_pct(h['check'][n], h['check'][d]):>22}")
    for label, key in (("- another clip's", "other_accepted"),
                       ("- its first 3 words", "first3_accepted")):
        lines.append(f"{label:28}{h['dev'][key]:>14} / {h['dev']['n_own']:<6}  "
                     f"{h['check'][key]:>14} / {h['check']['n_own']:<6}")
    lines.append(f"{'no alignment found (wrong)':28}{h['dev']['wrong_no_alignment']:>14} / "
                 f"{h['dev']['n_wrong']:<6}  {h['check']['wrong_no_alignment']:>14} / "
                 f"{h['check']['n_wrong']:<6}")
    lines.append(f"{'no alignment found (own)':28}{h['dev']['own_no_alignment']:>14} / "
                 f"{h['dev']['n_own']:<6}  {h['check']['own_no_alignment']:>14} / "
                 f"{h['check']['n_own']:<6}")
    for p in ("dev", "check"):
        lines.append(f"own gaps ({p}): min {h[p]['own_gap_min']:+.1f}, median "
                     f"{h[p]['own_gap_median']:+.1f}, max {h[p]['own_gap_max']:+.1f} per speech "
                     f"frame")
    lines += ["", "rule: the least total error on the development half (own refused rate + wrong "
              "accepted rate), ties to the smallest threshold",
              f"pick: MAX_SCORE_GAP = {pick:g} (face_model/forced_align.py has "
              f"{result['constant']:g})"]
    return "\n".join(lines)


def check_line(result: dict) -> str | None:
    """One line when the code's constant differs from the pick, else None."""
    if abs(result["constant"] - result["pick"]) > 1e-9:
        return (f"face_model/forced_align.py: MAX_SCORE_GAP is {result['constant']:g} but the "
                f"development sweep picks {result['pick']:g}")
    return None


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--grid-dir", type=Path, required=True,
                   help="a GRID speaker folder: video/<id>.mpg and align/<id>.align")
    p.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    p.add_argument("--every", type=int, default=1,
                   help="measure every K-th clip of each half only (a quick look)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--check", action="store_true",
                   help="exit 1 with one line if MAX_SCORE_GAP is not the pick")
    args = p.parse_args(argv)
    if args.workers < 1 or args.every < 1:
        p.error(f"--workers and --every must be at least 1, got {args.workers} and {args.every}")
    try:
        result = run(args.grid_dir, workers=args.workers, every=args.every)
    except (ParameterError, CorpusError) as e:
        print(e, file=sys.stderr)
        return 2
    if args.check:
        line = check_line(result)
        print(line or f"MAX_SCORE_GAP = {result['constant']:g} is the development sweep's pick",
              file=sys.stderr if line else sys.stdout)
        return 1 if line else 0
    print(json.dumps(result, indent=1) if args.json else table(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
