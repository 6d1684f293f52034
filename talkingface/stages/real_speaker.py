"""The paper's pipeline on a real speaker (stage ``real_speaker``): the built-in GRID s1 corpus
(``face_model/real_faces/grid-s1``, made from video by ``talkingface corpus from-video``) or
``real_speaker.corpus``.

A nested run in ``runs/<name>/real/`` (the same stages, the same settings, the corpus given:
:mod:`talkingface.stages.given_corpus`) fits the Motion Units and trains the mapping with its
baselines on the real corpus — Tables I–II on both splits and the lip metrics. Then, on the
nested run's held-out sentences (the utterance split's test part), three predictions of the inner
lips are scored against the real lips (:mod:`talkingface.stages.face_scoring`,
:mod:`analysis.face_eval`): the mapping trained on this speaker, the outer run's default model
(trained on synthetic voices and faces only: it has never seen this speaker), and the loudness
envelope (dB in 40 ms windows) as the floor any audio-driven mouth should beat. The stage folder
holds ``summary.json``, per-clip CSVs, ``strip.npz`` and ``units.npz`` for the report's section
(:mod:`analysis.real_face_report`).
"""
from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np

import face_model
from analysis.face_eval import ClipTrack, score_clips, write_scores_csv
from face_model.alignment import align_markers, speaker_neutrals, unflatten
from face_model.corpus import load_corpus
from face_model.layout import mouth_opening
from face_model.motion_units import MotionUnits
from groundwork.atomic import atomic_file
from groundwork.errors import ParameterError
from mapping.animator import FaceAnimator
from mapping.checkpoint import AudioMapping
from talkingface.paths import RunPaths
from talkingface.stages.base import read_done
from talkingface.stages.face_scoring import RealClip, clips_from_corpus, score_model
from talkingface.stages.models import find_model

BUILTIN = Path(face_model.__file__).resolve().parent / "real_faces" / "grid-s1"
PAPER_VARIANCE = 0.9756
TARGETS = {"speaker_r": 0.85, "synthetic_r": 0.7, "synthetic_closures": 0.8}
NESTED = "real"  # runs/<name>/real: the nested run


def real_corpus(cfg) -> Path | None:
    """The real speaker's corpus folder, or None when the stage is off."""
    value = cfg.real_speaker.corpus
    if not value:
        return None
    return BUILTIN if value == "builtin" else Path(value)


def real_speaker_applies(cfg) -> bool:
    """On when ``real_speaker.corpus`` names a corpus and the run's own corpus is synthetic
    (a run on a given corpus *is* the pipeline on that corpus)."""
    return real_corpus(cfg) is not None and not cfg.corpus.source


def real_inputs(paths, cfg) -> dict:
    """The real corpus's content joins the stage's key (its manifest's hash)."""
    src = real_corpus(cfg)
    if src is None:
        return {}
    manifest = src / "manifest.csv"
    if not manifest.is_file():
        raise ParameterError(f"real_speaker.corpus {src}: no manifest.csv (a corpus folder is "
                             "needed, e.g. one made by `talkingface corpus from-video`)")
    return {"real_corpus": hashlib.sha256(manifest.read_bytes()).hexdigest()}


def _rows(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _variance(units_dir: Path) -> float | None:
    """The fraction of neutral-speech deformation variance the utterance MUs explain."""
    mu = units_dir / "motion_units.npz"
    return MotionUnits.load(mu).variance_explained()["neutral"] if mu.is_file() else None


def loudness_opening(y: np.ndarray, sr: int, n: int, window_s: float = 0.04) -> np.ndarray:
    """The loudness envelope (dB of the RMS in ``window_s`` windows centred on each 30 fps
    frame) as a stand-in opening: the floor an audio-driven mouth should beat."""
    half = int(round(window_s * sr / 2))
    centres = (np.arange(n) * sr / 30).astype(int)
    out = np.empty(n)
    for k, c in enumerate(centres):
        seg = y[max(0, c - half):c + half]
        out[k] = 10 * np.log10(np.mean(seg.astype(np.float64) ** 2) + 1e-10) if len(seg) else -100
    return out


def _loudness_scores(clips: list):
    tracks = []
    for c in clips:
        real = mouth_opening(align_markers(c.markers))
        tracks.append(ClipTrack(c.clip, c.speaker, real, loudness_opening(c.audio,
                                                                          c.sample_rate,
                                                                          len(real))))
    return score_clips(tracks)


def _animator(tfmap: Path, units: Path) -> FaceAnimator:
    return FaceAnimator(AudioMapping.load(tfmap), MotionUnits.load(units))


def _strip(path: Path, clip: RealClip, models: dict, neutral: np.ndarray, scores: dict) -> None:
    """The data of the report's frame strip: one held-out sentence, real and predicted."""
    real = align_markers(clip.markers)
    arrays = {"clip": np.str_(clip.clip), "real": real, "neutral": neutral}
    n = len(real)
    for name, animator in models.items():
        mups = animator.mups(clip.audio, clip.sample_rate)
        pred = neutral[None] + unflatten(animator.units.inverse_transform(mups, "neutral"))
        n = min(n, len(pred))
        arrays[name] = pred
    for k in ("real", *models):
        arrays[k] = arrays[k][:n]
        track = next((t for t in scores.get(k, scores["speaker"]).tracks if t.clip == clip.clip),
                     None)
        z = mouth_opening(arrays[k])
        arrays[f"{k}_opening"] = (z - z.mean()) / (z.std() + 1e-12) if track is None else (
            track.real[:n] if k == "real" else track.predicted[:n])
    with atomic_file(path) as tmp:
        np.savez(tmp, **arrays)


def evaluate_real_speaker(paths: RunPaths, cfg, runner) -> dict:
    """The stage (``runner``: :func:`talkingface.stages.run`, for the nested run)."""
    src = real_corpus(cfg)
    out = paths.stage("real_speaker")
    nested = RunPaths.at(paths.root / NESTED, cache_dir=paths.cache)
    sub_cfg = dataclasses.replace(cfg, corpus=dataclasses.replace(cfg.corpus,
                                                                  source=str(src.resolve())))
    runner(["units", "mapping"], nested, sub_cfg)
    mapping_done = read_done(nested.mapping) or {}
    test_ids = mapping_done.get("test_utterances") or []
    if isinstance(test_ids, str):
        test_ids = json.loads(test_ids.replace("'", '"'))
    corpus = load_corpus(nested.corpus)
    clips = clips_from_corpus(nested.corpus, test_ids)
    speaker_tfmap = nested.mapping / mapping_done["models"]["utterance"]
    speaker = _animator(speaker_tfmap, nested.units / "motion_units.npz")
    synth_tfmap, synth_units = find_model(str(paths.root), paths.root.parent)
    synthetic = _animator(synth_tfmap, synth_units)
    scores = {"speaker": score_model(speaker, clips, training_corpus=corpus),
              "synthetic": score_model(synthetic, clips),
              "loudness": _loudness_scores(clips)}
    for name, s in scores.items():
        write_scores_csv(s, out / f"per_clip_{name}.csv")
    neutral = speaker_neutrals(corpus)[clips[0].speaker]
    median_clip = sorted(scores["speaker"].clips, key=lambda r: r.r)[len(clips) // 2].clip
    strip_clip = next(c for c in clips if c.clip == median_clip)
    _strip(out / "strip.npz", strip_clip, {"speaker": speaker, "synthetic": synthetic}, neutral,
           scores)
    units = speaker.units
    with atomic_file(out / "units.npz") as tmp:
        np.savez(tmp, components=units.components_,
                 scale=2 * np.sqrt(units.variance_[:units.n_utterance]), neutral=neutral)
    info = corpus.info
    summary = {
        "corpus": {"source": info.get("source", str(src)), "speaker": clips[0].speaker,
                   "utterances": len(corpus), "frames": corpus.n_frames,
                   "refused": info.get("refused", 0), "licence": info.get("licence", "")},
        "units": {"n_utterance": units.n_utterance, "variance_explained":
                  _variance(nested.units), "synthetic": _variance(paths.units),
                  "paper": PAPER_VARIANCE},
        "tables": {"real": _rows(nested.mapping / "tables.csv"),
                   "synthetic": _rows(paths.mapping / "tables.csv")},
        "test_utterances": test_ids,
        "face_scores": {"speaker_model": scores["speaker"].to_dict(),
                        "synthetic_model": scores["synthetic"].to_dict(),
                        "loudness": scores["loudness"].to_dict()},
        "models": {"speaker_model": str(speaker_tfmap), "synthetic_model": str(synth_tfmap)},
        "targets": TARGETS,
        "note": (mapping_done.get("note") or read_done(nested.units) or {}).get("note", "")
        if isinstance(mapping_done.get("note"), dict) else str(mapping_done.get("note", "")),
    }
    with atomic_file(out / "summary.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=1, default=float) + "\n")
    p = {k: v.pooled for k, v in scores.items()}
    return {"speaker_r": p["speaker"]["r_pooled"], "synthetic_r": p["synthetic"]["r_pooled"],
            "synthetic_closures": p["synthetic"]["closure_agreed_frac"],
            "loudness_r": p["loudness"]["r_pooled"], "test_clips": len(clips)}
