"""Measure the face counts and roll angles the landmark worker reports on real clips, and what
the import's bounds on them refuse.

    python tools/face_checks_sweep.py VIDEO_DIR [--clips 60] [--pairs 6] [--workers 2]

``VIDEO_DIR`` is a folder of single-speaker clips (e.g. ``../shared/grid-s1/video``, GRID s1).
``--clips`` of them, evenly spaced in name order, are run through the landmark worker
(:mod:`face_model.landmark_worker`) as they are; from the first ``--pairs`` of those the script
also makes, with FFmpeg, 2-second clips of two of them side by side (``hstack``, the next clip
on the right) and of one upside down (``vflip``). For each group it prints, per clip, the share
of frames in which the detector counted more than one face and the median |roll| (degrees), their
distribution over the group, and how many clips :func:`face_model.video_corpus.check_face`'s
bounds (:data:`~face_model.video_corpus.FromVideoSettings`'s ``max_multi_face_fraction`` and
``max_roll_deg``) refuse. The bounds were chosen from this output on GRID s1: no clip as recorded
may be refused, and every changed one must be.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import imageio_ffmpeg
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from face_model.landmarks import Landmarks, extract_landmarks  # noqa: E402
from face_model.video_corpus import FromVideoSettings, face_orientation  # noqa: E402


def _variants(clips: list, n_pairs: int, folder: Path) -> dict:
    ffmpeg = imageio_ffmpeg.get_ffmpeg_exe()
    made = {"hstack": [], "vflip": []}
    for i in range(min(n_pairs, len(clips) - 1)):
        a, b = clips[i], clips[i + 1]
        two = folder / f"two-{a.stem}-{b.stem}.mpg"
        subprocess.run([ffmpeg, "-v", "error", "-i", str(a), "-i", str(b), "-filter_complex",
                        "[0:v][1:v]hstack=inputs=2[v]", "-map", "[v]", "-map", "0:a", "-t", "2",
                        "-c:v", "mpeg1video", "-q:v", "4", "-c:a", "mp2", str(two)], check=True)
        flip = folder / f"flip-{a.stem}.mpg"
        subprocess.run([ffmpeg, "-v", "error", "-i", str(a), "-vf", "vflip", "-t", "2",
                        "-c:v", "mpeg1video", "-q:v", "4", "-c:a", "mp2", str(flip)], check=True)
        made["hstack"].append(two)
        made["vflip"].append(flip)
    return made


def _summary(name: str, rows: list, settings: FromVideoSettings) -> None:
    multi = np.array([r[1] for r in rows])
    roll = np.array([r[2] for r in rows])
    frame_roll = np.concatenate([r[3] for r in rows])
    refused = sum(m > settings.max_multi_face_fraction or r > settings.max_roll_deg
                  for m, r in zip(multi, roll))
    print(f"\n{name}: {len(rows)} clips, {len(frame_roll)} frames with a detection")
    print(f"  share of frames with more than one face: max {multi.max():.3f}, "
          f"min {multi.min():.3f}, clips with any {int((multi > 0).sum())}")
    print(f"  median |roll| per clip, degrees: min {roll.min():.1f}, median {np.median(roll):.1f}, "
          f"max {roll.max():.1f}")
    print(f"  |roll| per frame, degrees: 99th percentile {np.percentile(frame_roll, 99):.1f}, "
          f"max {frame_roll.max():.1f}")
    print(f"  refused by the bounds (more than one face in > "
          f"{100 * settings.max_multi_face_fraction:.0f} % of frames, or median |roll| > "
          f"{settings.max_roll_deg:g}°): {refused} of {len(rows)}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("video_dir", type=Path)
    ap.add_argument("--clips", type=int, default=60)
    ap.add_argument("--pairs", type=int, default=6)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)
    videos = sorted(args.video_dir.glob("*.mpg"))
    step = max(1, len(videos) // args.clips)
    clips = videos[::step][:args.clips]
    settings = FromVideoSettings()
    with tempfile.TemporaryDirectory(prefix="face-checks-") as tmp:
        tmp = Path(tmp)
        groups = {"as recorded": clips, **_variants(clips, args.pairs, tmp)}
        for name, group in groups.items():
            jobs = [(v, tmp / f"{name[:2]}-{v.stem}.npz") for v in group]
            extract_landmarks(jobs, workers=args.workers)
            rows = []
            for v, out in jobs:
                lm = Landmarks.load(out)
                multi, roll = face_orientation(lm)
                rows.append((v.name, multi, roll, np.abs(lm.roll_deg[~np.isnan(lm.roll_deg)])))
                if name != "as recorded":
                    print(f"  {name} {v.name}: more than one face in {multi:.2f} of frames, "
                          f"median |roll| {roll:.1f}°")
            _summary(name, rows, settings)
    return 0


if __name__ == "__main__":
    sys.exit(main())
