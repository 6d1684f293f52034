"""The face-in-motion stages (paper §IV-B, §VII-B, Figs. 4, 6 and 7).

``keyframes/``: the Eq. 3–4 keyframe model fitted on the run's corpus, its MUP → keyframe → MUP
round trip per expression (``roundtrip.csv``) and the keyframe shapes drawn on the face.
``render/``: a held-out sentence animated from its audio by the trained mapping (Fig. 6 style),
the same moment in neutral, smile and sad (Fig. 7 style), and that sentence's keyframe tracks.
"""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from talkingface.config import dump_config, to_dict


def stage_keyframes(corpus_dir: Path, units_path: Path, out_dir: Path, cfg) -> dict:
    from analysis.figures import face_grid
    from face_model.alignment import corpus_deformations, unflatten
    from face_model.corpus import load_corpus
    from face_model.keyframes import KEYFRAMES, KeyframeModel
    from face_model.layout import default_layout
    from face_model.motion_units import MotionUnits
    from face_model.render import FaceRenderer

    corpus = load_corpus(corpus_dir)
    units = MotionUnits.load(units_path)
    defs = corpus_deformations(corpus, model=units.metadata_.get("alignment", "similarity"))
    model = KeyframeModel().fit(corpus, units, deformations=defs)
    out_dir.mkdir(parents=True, exist_ok=True)
    model.save(out_dir / "keyframes.npz")
    rows = []
    for expr in dict.fromkeys(u.expression for u in corpus.utterances):
        mups = np.concatenate([units.transform(defs[u.utt_id], expr)
                               for u in corpus.utterances if u.expression == expr])
        e = model.round_trip_error(mups, expr)
        rows.append({"expression": expr, "frames": e.n_frames, "mup_relative": e.mup_relative,
                     "pixel_rmse": e.pixel_rmse, "pixel_max": e.pixel_max,
                     "shape_relative": e.shape_relative})
    with open(out_dir / "roundtrip.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    neutral = default_layout().neutral
    renderer = FaceRenderer(mesh=False)
    images = [renderer.render(neutral + unflatten(s[None])[0]) for s in model.shapes_]
    face_grid(images, list(KEYFRAMES), out_dir / "keyframes.png", ncols=4)
    summary = {"roundtrip": rows, "condition": float(model.condition_),
               "samples": {k: len(v) for k, v in model.selection_.items()}}
    dump_config(cfg, out_dir / "config.yaml")
    (out_dir / "done.json").write_text(json.dumps(summary, indent=1))
    return summary


def stage_render(run_root: Path, out_dir: Path, cfg) -> dict:
    """Fig. 6 / Fig. 7-style pictures and keyframe tracks of a held-out sentence."""
    from analysis.figures import face_grid
    from face_model.corpus import load_corpus
    from face_model.keyframes import KeyframeModel, write_keyframe_tracks
    from face_model.render import FaceRenderer
    from talkingface.animate import load_animator

    animator, tfmap = load_animator(str(run_root))
    corpus = load_corpus(run_root / "corpus")
    done = json.loads((run_root / "mapping" / "done.json").read_text())
    utt = _held_out(corpus, done)
    out_dir.mkdir(parents=True, exist_ok=True)
    renderer = FaceRenderer(mesh=False)
    mups, markers = animator.animate(utt.audio, utt.sample_rate, "neutral")
    picks = np.linspace(0, len(markers) - 1, 10).round().astype(int)
    phones = utt.phone_per_frame()
    from face_model.phones import PHONES
    fig6 = face_grid([renderer.render(markers[k]) for k in picks],
                     [f"{k / 30:.2f} s /{PHONES[phones[k]]}/" for k in picks],
                     out_dir / "fig6_sentence.png", ncols=5)
    # Fig. 7: the frame of widest mouth opening, animated neutral, smiling and sad
    gap = markers[:, 71:76, 1].mean(1) - markers[:, 65:70, 1].mean(1)
    k = int(np.argmax(gap))
    faces, titles = [], []
    for expr in animator.mapping.expressions:
        _, m = animator.animate(utt.audio, utt.sample_rate, expr)
        faces.append(renderer.render(m[k]))
        titles.append(expr)
    fig7 = face_grid(faces, titles, out_dir / "fig7_expressions.png", ncols=len(faces))
    kf = KeyframeModel.load(run_root / "keyframes" / "keyframes.npz")
    tracks = write_keyframe_tracks(out_dir / "keyframe_tracks.json",
                                   kf.mups_to_keyframes(mups, "neutral"), 30,
                                   expression="neutral", source=utt.utt_id)
    summary = {"utterance": utt.utt_id, "text": utt.text, "fig6": fig6.name, "fig7": fig7.name,
               "fig7_frame": k, "tracks": Path(tracks).name, "model": str(tfmap)}
    (out_dir / "done.json").write_text(json.dumps(summary, indent=1))
    return summary


def tracked_by(c: dict) -> tuple:
    """What determines a tracked corpus (a config as a dict; workers only set the speed)."""
    return (c["seed"], {k: v for k, v in c["synth"].items() if k != "workers"}, c["units"],
            c["tracker"]["init"], c["tracker"]["corpus_noise_sd"])


def stage_track_corpus(corpus_dir: Path, units_path: Path, out_dir: Path, cfg, *,
                       progress: bool = True) -> dict:
    """The whole corpus rendered as marker video and tracked (``mapping.visual_source:
    tracked``); reused when done for this config. See :mod:`data_synth.tracked`."""
    from data_synth.tracked import track_corpus
    from face_model.corpus import load_corpus
    from face_model.motion_units import MotionUnits

    done_path = out_dir / "done.json"
    if done_path.is_file():
        done = json.loads(done_path.read_text())
        if tracked_by(done["config"]) == tracked_by(to_dict(cfg)):
            return done
    t = cfg.tracker
    summary = track_corpus(load_corpus(corpus_dir), MotionUnits.load(units_path), out_dir,
                           noise_sd=t.corpus_noise_sd, init=t.init, seed=cfg.seed,
                           workers=t.workers, progress=progress, overwrite=True)
    done = {"config": to_dict(cfg), **summary}
    dump_config(cfg, out_dir / "config.yaml")
    done_path.write_text(json.dumps(done, indent=1))
    return done


def stage_tracking(corpus_dir: Path, units_path: Path, out_dir: Path, cfg) -> dict:
    """Track rendered video of a corpus subset at several noise levels (raw Lucas–Kanade vs
    the MU-constrained fit) and plot the error curve."""
    from analysis.figures import tracking_curve
    from data_synth.video import tracking_error_curve
    from face_model.alignment import speaker_neutrals
    from face_model.corpus import load_corpus
    from face_model.motion_units import MotionUnits

    t = cfg.tracker
    corpus = load_corpus(corpus_dir)
    units = MotionUnits.load(units_path)
    by_expr: dict = {}
    for u in corpus.utterances:
        by_expr.setdefault(u.expression, []).append(u)
    subset, i = [], 0
    while len(subset) < min(t.n_utterances, len(corpus.utterances)):
        for utts in by_expr.values():  # round robin over the expressions
            if i < len(utts) and len(subset) < t.n_utterances:
                subset.append(utts[i])
        i += 1
    neutrals = speaker_neutrals(corpus, model=units.metadata_.get("alignment", "similarity"))
    curve = tracking_error_curve(subset, units, neutrals=neutrals, noise_levels=t.noise_levels,
                                 seed=cfg.seed, init=t.init)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = curve.rows()
    with open(out_dir / "error_curve.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    fig = tracking_curve(rows, out_dir / "error_curve.png")
    worst = rows[-1]
    summary = (f"Tracker (§V, Eq. 5 solved as in Appendix A): {len(subset)} utterances "
               f"({curve.n_frames} frames) rendered as marker video and tracked from the "
               f"{INIT_WORDS[t.init]}. Mean "
               f"marker error at image noise sd {worst['noise_sd']:.0f}: raw Lucas-Kanade "
               f"{worst['lk_px']:.2f} px, MU-constrained {worst['constrained_px']:.2f} px.")
    done = {"rows": rows, "utterances": [u.utt_id for u in subset], "summary": summary,
            "figure": fig.name, "caption": "Mean marker error (pixels) against image noise: raw "
            "pyramidal Lucas-Kanade tracks, the measurements the fit uses, and the "
            "MU-constrained tracker."}
    dump_config(cfg, out_dir / "config.yaml")
    (out_dir / "done.json").write_text(json.dumps(done, indent=1))
    return done


INIT_WORDS = {"markers": "true first-frame markers",
              "corners": "neutral face placed by the true mouth corners",
              "image": "markers found in the first image (mouth corners, then the dots)"}


def _held_out(corpus, done: dict):
    """The first neutral utterance held out by the utterance split (any neutral one if none)."""
    held = set(done.get("test_utterances", []))
    neutral = [u for u in corpus.utterances if u.expression == "neutral"] or corpus.utterances
    return next((u for u in neutral if u.utt_id in held), neutral[0])
