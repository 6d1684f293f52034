"""Speed of the MU-constrained tracker (§V) on a rendered sentence, and of the video renderer.

Fits the MUs on a 10-sentence corpus, renders its first smile sentence at 30 fps with sensor
noise (sd 10 grey levels), and times: rendering, finding the first-frame markers in the image
(mouth corners, then the dots), raw Lucas–Kanade, and the tracker with the linear (Appendix A)
and the nonlinear solver. Prints the best of --repeat runs, in frames per second (real time is
30), with the marker errors of the tracks; then tracks the whole 10-sentence corpus as
``--visual-source tracked`` does (all cores) and prints its throughput.
"""
from __future__ import annotations

import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import parse_args, report

from data_synth.generate import synthesize_corpus
from face_model.alignment import speaker_neutrals
from face_model.corpus import load_corpus
from face_model.detect import initial_markers_from_image
from face_model.marker_video import VideoDifficulty, render_marker_video
from face_model.motion_units import fit_corpus_units
from face_model.tracked_corpus import track_corpus
from face_model.tracker import MUTracker, track_points_lk
from talkingface.config import Config


def _best(fn, repeat: int):
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    cfg = Config()
    synth = dataclasses.replace(cfg.synth, n_sentences=10)
    with tempfile.TemporaryDirectory() as tmp:
        synthesize_corpus(Path(tmp) / "corpus", synth, cfg.seed, progress=False)
        corpus = load_corpus(Path(tmp) / "corpus")
        figures = _measure(args, cfg, corpus, Path(tmp))
    report(figures, args.json)


def _measure(args, cfg, corpus, tmp: Path) -> dict:
    units, _ = fit_corpus_units(corpus)
    utt = corpus.by_expression("smile")[0]
    neutral = speaker_neutrals(corpus)[utt.speaker]
    difficulty = VideoDifficulty(noise_sd=10.0)
    t_render, (frames, mapping) = _best(
        lambda: render_marker_video(utt.markers, difficulty=difficulty, seed=cfg.seed),
        args.repeat)
    truth = mapping.to_image(utt.markers)
    n = len(frames)
    t_lk, (lk, _) = _best(lambda: track_points_lk(frames, truth[0]), args.repeat)
    figures = {"frames": n, "image": f"{frames.shape[2]}x{frames.shape[1]}",
               "render_fps": n / t_render, "raw_lk_fps": n / t_lk,
               "raw_lk_error_px": float(np.linalg.norm(lk - truth, axis=-1).mean())}
    for solver in ("linear", "nonlinear"):
        tracker = MUTracker(solver=solver)
        t, res = _best(lambda: tracker.track(frames, units, utt.expression, neutral=neutral,
                                             init_markers=truth[0]), args.repeat)
        figures[f"tracker_{solver}_fps"] = n / t
        figures[f"tracker_{solver}_error_px"] = float(
            np.linalg.norm(res.markers - truth, axis=-1).mean())
    t_init, p0 = _best(lambda: initial_markers_from_image(frames[0], units, utt.expression,
                                                          neutral=neutral), args.repeat)
    figures["init_from_image_ms"] = 1000 * t_init
    figures["init_from_image_error_px"] = float(np.linalg.norm(p0 - truth[0], axis=-1).mean())
    figures["target_fps"] = 30.0
    done = track_corpus(corpus, units, tmp / "tracked", noise_sd=10.0, seed=cfg.seed,
                        progress=False)
    figures["track_corpus_frames"] = done["frames"]
    figures["track_corpus_fps"] = done["frames"] / done["seconds"]
    figures["track_corpus_error_px"] = done["error_px_mean"]
    return figures


if __name__ == "__main__":
    main()
