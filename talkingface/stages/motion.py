"""The face in motion (paper §V, §VII-B, Figs. 6 and 7): three stages.

``tracking/``: rendered video of a corpus subset tracked at several image noise levels (raw
Lucas–Kanade vs the MU-constrained fit), the error curve. ``tracked/``: the whole corpus rendered
as marker video and tracked (``mapping.visual_source: tracked``; see :mod:`face_model.tracked_corpus`).
``render/``: a held-out sentence animated from its audio by the trained mapping (Fig. 6 style),
the same moment in neutral, smile and sad (Fig. 7 style), and that sentence's keyframe tracks
(the last two only when the mapping knows expressions and the run has a keyframe model:
``skipped`` in its record says what was left out).
"""
from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np

from analysis.figures import tracking_curve
from face_model.alignment import speaker_neutrals
from face_model.corpus import load_corpus
from face_model.keyframes import KeyframeModel, write_keyframe_tracks
from face_model.layout import mouth_opening
from face_model.marker_video import tracking_error_curve
from face_model.motion_units import MotionUnits
from face_model.phones import PHONES
from face_model.render import FaceRenderer, face_grid
from face_model.tracked_corpus import track_corpus
from talkingface.executor import map_tasks
from talkingface.paths import RunPaths
from talkingface.stages.base import read_done, write_csv
from talkingface.stages.models import load_animator

INIT_WORDS = {"markers": "true first-frame markers",
              "corners": "neutral face placed by the true mouth corners",
              "image": "markers found in the first image (mouth corners, then the dots)"}


def _tracking_subset(corpus, n: int) -> list:
    """``n`` utterances taken round robin over the expressions."""
    by_expr: dict = {}
    for u in corpus.utterances:
        by_expr.setdefault(u.expression, []).append(u)
    subset, i = [], 0
    while len(subset) < min(n, len(corpus.utterances)):
        for utts in by_expr.values():
            if i < len(utts) and len(subset) < n:
                subset.append(utts[i])
        i += 1
    return subset


def evaluate_tracker(paths: RunPaths, cfg) -> dict:
    """Track rendered video of a corpus subset at several noise levels and plot the error
    curve."""
    t = cfg.tracker
    corpus = load_corpus(paths.corpus)
    units = MotionUnits.load(paths.units_model)
    subset = _tracking_subset(corpus, t.n_utterances)
    neutrals = speaker_neutrals(corpus, model=units.metadata_.get("alignment", "similarity"))
    curve = tracking_error_curve(subset, units, neutrals=neutrals, noise_levels=t.noise_levels,
                                 seed=cfg.seed, init=t.init)
    rows = curve.rows()
    write_csv(paths.tracking / "error_curve.csv", rows)
    fig = tracking_curve(rows, paths.tracking / "error_curve.png")
    worst = rows[-1]
    summary = (f"Tracker (§V, Eq. 5 solved as in Appendix A): {len(subset)} utterances "
               f"({curve.n_frames} frames) rendered as marker video and tracked from the "
               f"{INIT_WORDS[t.init]}. Mean "
               f"marker error at image noise sd {worst['noise_sd']:.0f}: raw Lucas-Kanade "
               f"{worst['lk_px']:.2f} px, MU-constrained {worst['constrained_px']:.2f} px.")
    return {"rows": rows, "utterances": [u.utt_id for u in subset], "summary": summary,
            "figure": fig.name, "caption": "Mean marker error (pixels) against image noise: raw "
            "pyramidal Lucas-Kanade tracks, the measurements the fit uses, and the "
            "MU-constrained tracker."}


def uses_tracked_corpus(cfg) -> bool:
    return cfg.mapping.visual_source == "tracked"


def track_folder(corpus_dir: Path, units_path: Path, out_dir: Path, cfg) -> dict:
    """The corpus in ``corpus_dir`` rendered as marker video and tracked into ``out_dir`` with
    the Motion Units of ``units_path``, under ``cfg.tracker``'s settings and ``cfg.seed``."""
    t = cfg.tracker
    # on Dask like the grids (cluster.scheduler), or this machine's process pool (processes)
    map_fn = None if cfg.cluster.scheduler == "processes" else partial(
        map_tasks, scheduler=cfg.cluster.scheduler, workers=t.workers, desc="tracking corpus")
    return track_corpus(load_corpus(corpus_dir), MotionUnits.load(units_path), out_dir,
                        noise_sd=t.corpus_noise_sd, init=t.init, seed=cfg.seed,
                        workers=t.workers, progress=True, overwrite=True, map_fn=map_fn)


def make_tracked_corpus(paths: RunPaths, cfg) -> dict:
    """The whole corpus rendered as marker video and tracked."""
    return track_folder(paths.corpus, paths.units_model, paths.tracked, cfg)


def training_corpus(paths: RunPaths, cfg) -> Path:
    """The corpus the mapping learns from: the run's corpus or its tracked copy."""
    return paths.tracked if uses_tracked_corpus(cfg) else paths.corpus


def held_out_utterance(corpus, mapping_done: dict):
    """The first neutral utterance held out by the utterance split (any neutral one if none)."""
    held = set(mapping_done.get("test_utterances", []))
    neutral = [u for u in corpus.utterances if u.expression == "neutral"] or corpus.utterances
    return next((u for u in neutral if u.utt_id in held), neutral[0])


def render_held_out(paths: RunPaths, cfg) -> dict:
    """Fig. 6 / Fig. 7-style pictures and keyframe tracks of a held-out sentence."""
    animator, tfmap = load_animator(str(paths.root))
    corpus = load_corpus(paths.corpus)
    utt = held_out_utterance(corpus, read_done(paths.mapping))
    out_dir = paths.render
    renderer = FaceRenderer(mesh=False)
    mups, markers = animator.animate(utt.audio, utt.sample_rate, "neutral")
    picks = np.linspace(0, len(markers) - 1, 10).round().astype(int)
    phones = utt.phone_per_frame()
    fig6 = face_grid([renderer.render(markers[k]) for k in picks],
                     [f"{k / 30:.2f} s /{PHONES[phones[k]]}/" for k in picks],
                     out_dir / "fig6_sentence.png", ncols=5)
    k = int(np.argmax(mouth_opening(markers)))  # Fig. 7: the frame of widest mouth opening
    record = {"utterance": utt.utt_id, "text": utt.text, "fig6": fig6.name, "fig7": None,
              "fig7_frame": k, "tracks": None, "model": str(tfmap)}
    expressions = animator.mapping.expressions
    if any(e != "neutral" for e in expressions):
        faces, titles = [], []
        for expr in expressions:
            _, m = animator.animate(utt.audio, utt.sample_rate, expr)
            faces.append(renderer.render(m[k]))
            titles.append(expr)
        record["fig7"] = face_grid(faces, titles, out_dir / "fig7_expressions.png",
                                   ncols=len(faces)).name
        record["fig7_expressions"] = titles
    else:
        record["skipped"] = ["Fig. 7 (the same moment in each expression): the mapping knows "
                             "neutral speech only"]
    if paths.keyframes_model.is_file():
        kf = KeyframeModel.load(paths.keyframes_model)
        record["tracks"] = Path(write_keyframe_tracks(
            out_dir / "keyframe_tracks.json", kf.mups_to_keyframes(mups, "neutral"), 30,
            expression="neutral", source=utt.utt_id)).name
    else:
        record.setdefault("skipped", []).append(
            "the keyframe tracks: the run has no keyframe model (the paper's eight keyframes "
            "include smile and sad)")
    return record
