"""Throughput of ``talkingface corpus from-video`` (target: at least 50 video frames/s on 2 cores).

Imports the shipped GRID clips (tests/data/grid/video: 4 clips, 300 frames at 25 fps; one is
refused for missed frames, as it should be) with 1 and with 2 workers, side by side in one run,
and prints the best of --repeat runs in source video frames per second, for the whole import
(landmarks, audio, forced alignment, writing) and for the landmark pass alone.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

from _common import parse_args, report

from face_model.landmarks import extract_landmarks
from face_model.video_corpus import FromVideoSettings, find_videos
from face_model.video_import import corpus_from_video

VIDEOS = Path(__file__).resolve().parents[1] / "tests" / "data" / "grid" / "video"
FRAMES = 4 * 75


def _import(workers: int) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        corpus_from_video(VIDEOS, Path(tmp) / "c", settings=FromVideoSettings(speaker="s1"),
                          workers=workers, progress=False)
        return time.perf_counter() - t0


def _landmarks(workers: int) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        jobs = [(v, Path(tmp) / f"{v.stem}.npz") for v in find_videos(VIDEOS)]
        t0 = time.perf_counter()
        extract_landmarks(jobs, workers=workers)
        return time.perf_counter() - t0


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    figures = {}
    for workers in (1, 2):
        best_import = min(_import(workers) for _ in range(args.repeat))
        best_lm = min(_landmarks(workers) for _ in range(args.repeat))
        figures[f"import_fps_{workers}_workers"] = FRAMES / best_import
        figures[f"landmarks_fps_{workers}_workers"] = FRAMES / best_lm
    figures["speedup_2_over_1"] = figures["import_fps_2_workers"] / figures["import_fps_1_workers"]
    report(figures, args.json)


if __name__ == "__main__":
    main()
