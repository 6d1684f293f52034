"""The paper's pipeline on a real speaker (stage ``real_speaker``): the built-in GRID s1 corpus
(``face_model/real_faces/grid-s1``, made from video by ``talkingface corpus from-video``) or
``real_speaker.corpus``.

A nested run in ``runs/<name>/real/`` (the same stages, the same settings, the corpus given:
:mod:`talkingface.stages.given_corpus`) fits the Motion Units and the neutral face on the
training sentences of the utterance split (:func:`talkingface.stages.foundation.units_held_out`)
and trains the mapping with its baselines on the real corpus — Tables I–II on both splits and
the lip metrics. Then, on the nested run's held-out sentences, the inner lips are scored against
the real lips by the rules of :mod:`analysis.face_eval` (speech frames, silence apart, closures
on /p b m/, chance, no-face frames excluded; :mod:`talkingface.stages.face_scoring`): the mapping
trained on this speaker, the outer run's default model (trained on synthetic voices and faces
only: it has never seen this speaker), and every peer of :mod:`mapping.peers` (the loudness
envelope, ``openfacefx`` in transcript and loudness modes, ``pylipsync``). Every score is made
from the corpus's audio at its own rate and from the same audio resampled to each rate of
:data:`EXTRA_RATES` (the models and peers hear it at that rate).

``openfacefx-text`` gets the transcript only (the manifest's ``text``), spread over the speech
span (first to last non-silence phone): the corpus keeps phone times but no word times (its
phones come from forced alignment; the source's ``.align`` word times are read only when the
corpus is built), and splitting the phones into words would need the aligner's dictionary.

The stage folder holds ``summary.json``, per-clip CSVs ``per_clip_<name>_<rate>.csv``,
``strip.npz`` and ``units.npz`` for the report's section (:mod:`analysis.real_face_report`), and
for the first two held-out clips with a video in ``real_speaker.videos`` (by default two of GRID
s1's, shipped) ``side_by_side_<clip>.mp4`` — the video with its tracked markers | the markers
the speaker-trained model predicts from the audio | the default model's face, the audio muxed —
and ``video_strip.npz``, the report's stills from the first.
"""
from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import time
from pathlib import Path

import numpy as np

import face_model
from analysis.face_eval import ClipTrack, normalised, write_scores_csv
from face_model.alignment import align_markers
from face_model.corpus import Corpus, load_corpus
from face_model.motion_units import MotionUnits
from face_model.video_corpus import VIDEO_EXTENSIONS
from groundwork.atomic import atomic_file
from groundwork.errors import CorpusError
from mapping.animator import FaceAnimator
from mapping.checkpoint import AudioMapping
from mapping.dataset import training_sentences
from mapping.experiment import SPLIT_SEED_OFFSET
from mapping.peers import PEERS, peer_versions
from talkingface.paths import RunPaths
from talkingface.stages.base import read_done
from talkingface.stages.face_scoring import (RealClip, clips_from_corpus, model_neutrals,
                                             predicted_markers, score_model, score_peer)
from talkingface.stages.given_corpus import check_folder, combine_corpora
from talkingface.stages.models import find_model
from talkingface.stages.side_by_side import predict, strip_frames, write_side_by_side
from talkingface.stages.training import utterance_test_ids

BUILTIN = Path(face_model.__file__).resolve().parent / "real_faces" / "grid-s1"
BUILTIN_VIDEOS = BUILTIN.with_name("grid-s1-video")  # two held-out clips' video
N_SIDE_BY_SIDE = 2  # held-out clips drawn beside their predictions (those with a video)
SIDE_BY_SIDE_CAPTIONS = ("real + tracked", "predicted (speaker-trained)",
                         "default model's face")
PAPER_VARIANCE = 0.9756
NESTED = "real"  # runs/<name>/real: the nested run
SETTING = "real_speaker.corpus"  # the setting that names the corpus, in messages
ALSO = "made by `talkingface corpus from-video`, builtin (GRID s1) or empty (off)"
MODELS = ("speaker_model", "synthetic_model")
# 2: speech frames, closures on /p b m/, chance, peers, input rates, units on training sentences
SCORING_VERSION = 2
EXTRA_RATES = (16000, 8000)  # Hz: the same audio resampled, beside the corpus's own rate
WORD_TIMES = ("word times of the clips whose corpus keeps them (words/<utt_id>.csv, GRID's .align "
              "times), each word segmented on its own interval and shifted there, closed outside "
              "every word; the other clips' transcript over the speech span (first to last "
              "non-silence phone); which timing each clip got is the peer's word_times")


def real_corpus(cfg) -> Path | None:
    """The real speaker's corpus folder, or None when the stage is off."""
    value = cfg.real_speaker.corpus
    if not value:
        return None
    return BUILTIN if value == "builtin" else Path(value)


def real_videos(cfg) -> Path | None:
    """The folder of the real corpus's videos (``real_speaker.videos``), or None."""
    value = cfg.real_speaker.videos
    if not value:
        return None
    return BUILTIN_VIDEOS if value == "builtin" else Path(value)


def video_files(folder: Path | None) -> dict:
    """``{stem: path}`` of the videos in ``folder`` (:data:`face_model.video_corpus.
    VIDEO_EXTENSIONS`; none for None)."""
    if folder is None:
        return {}
    return {p.stem: p for p in sorted(folder.iterdir())
            if p.is_file() and p.suffix.lower() in VIDEO_EXTENSIONS}


def training_part(corpus: Corpus, seed: int, train_fraction: float) -> Corpus:
    """The corpus's utterances whose sentence is a training sentence of the utterance split of
    run seed ``seed``."""
    train = training_sentences([u.text for u in corpus.utterances],
                               train_fraction=train_fraction, seed=seed + SPLIT_SEED_OFFSET)
    return Corpus(corpus.root, corpus.info, [u for u in corpus.utterances if u.text in train])


def copy_training_part(src: Path, dst: Path, cfg) -> Path:
    """The training sentences of ``src`` (:func:`training_part`) as a corpus folder ``dst``
    (:func:`talkingface.stages.given_corpus.combine_corpora`: their rows and files, hard links
    where the file system allows; a finished folder is kept)."""
    if (dst / "manifest.csv").is_file():
        return dst
    keep = {u.utt_id for u in training_part(load_corpus(src), cfg.seed,
                                            cfg.mapping.train_fraction).utterances}
    return combine_corpora([(src, keep, "")], dst)


def real_speaker_applies(cfg) -> bool:
    """On when ``real_speaker.corpus`` names a corpus and the run's own corpus is synthetic
    (a run on a given corpus *is* the pipeline on that corpus)."""
    return real_corpus(cfg) is not None and not cfg.corpus.source


def real_inputs(paths, cfg) -> dict:
    """The real corpus's content (its manifest's hash) and the scoring rules' version
    (:data:`SCORING_VERSION`) join the stage's key. The corpus is validated here, by the one
    reader (:func:`talkingface.stages.given_corpus.check_folder`: about a second for GRID s1's
    196 clips, once per process), so that a bad ``real_speaker.corpus`` is refused, naming the
    setting, before a run starts rather than when the stage reaches it.

    Raises
    ------
    CorpusError
        ``real_speaker.corpus <folder>: ...``: not found, not a folder, or the reader's refusal;
        ``real_speaker.videos <folder>: not a folder``.
    """
    src = real_corpus(cfg)
    if src is None:
        return {}
    check_folder(src, SETTING, also=ALSO)
    videos = real_videos(cfg)
    if videos is not None and not videos.is_dir():
        raise CorpusError(f"real_speaker.videos {videos}: "
                          f"{'not a folder' if videos.exists() else 'not found'} (builtin, "
                          "empty for none, or the folder of the corpus's videos, "
                          "<utt_id>.mpg …)")
    return {"real_corpus": hashlib.sha256((src / "manifest.csv").read_bytes()).hexdigest(),
            "scoring": SCORING_VERSION,
            "videos": {k: p.stat().st_size for k, p in video_files(videos).items()}}


def _rows(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _variance(units_dir: Path) -> float | None:
    """The fraction of neutral-speech deformation variance the utterance MUs explain."""
    mu = units_dir / "motion_units.npz"
    return MotionUnits.load(mu).variance_explained()["neutral"] if mu.is_file() else None


def _animator(tfmap: Path, units: Path) -> FaceAnimator:
    return FaceAnimator(AudioMapping.load(tfmap), MotionUnits.load(units))


def _strip(path: Path, clip: RealClip, models: dict, neutrals: dict) -> None:
    """The data of the report's frame strip: one held-out sentence, real and predicted, the
    openings z-scored on its speech frames (:func:`analysis.face_eval.normalised`)."""
    real = align_markers(clip.markers)
    arrays = {"clip": np.str_(clip.clip), "real": real, "fps": np.float64(clip.fps),
              "neutral": neutrals["speaker_model"]}
    for name, animator in models.items():
        key = name.replace("_model", "")
        pred = predicted_markers(animator, clip, neutrals[name])
        track = ClipTrack.from_markers(
            clip.clip, clip.speaker, real, pred, clip.fps, phones=clip.phones,
            valid=clip.valid, lve=False)
        z_real, z_pred = normalised(track)
        arrays[key], arrays[f"{key}_opening"], arrays["real_opening"] = pred, z_pred, z_real
    with atomic_file(path) as tmp:
        np.savez(tmp, **arrays)


def _side_by_side(out: Path, clips: list, videos: dict, speaker, synthetic, neutral) -> dict:
    """The first :data:`N_SIDE_BY_SIDE` held-out clips that have a video: one MP4 each
    (``side_by_side_<clip>.mp4``: the video with its tracked markers | the speaker-trained
    model's markers | the default model's face, the audio muxed;
    :func:`talkingface.stages.side_by_side.write_side_by_side`) and, from the first, the
    report's stills (``video_strip.npz``: real | predicted at /p b m/ and open vowels)."""
    shown = [c for c in clips if c.clip in videos][:N_SIDE_BY_SIDE]
    written = []
    for i, c in enumerate(shown):
        pred = predict(speaker, c, neutral, face_animator=synthetic)
        path = out / f"side_by_side_{c.clip}.mp4"
        write_side_by_side(path, videos[c.clip], c, speaker, neutral, prediction=pred,
                           face_animator=synthetic, captions=SIDE_BY_SIDE_CAPTIONS,
                           progress=False)
        written.append(path.name)
        if i == 0:
            stills = strip_frames(videos[c.clip], c, speaker, neutral, prediction=pred)
            with atomic_file(out / "video_strip.npz") as tmp:
                np.savez(tmp, clip=np.str_(c.clip), fps=np.float64(c.fps),
                         frames=np.array([s.frame for s in stills], int),
                         reasons=np.array([s.reason for s in stills]),
                         images=np.stack([s.image for s in stills]) if stills else
                         np.zeros((0, 1, 1, 3), np.uint8))
    return {"videos": written, "clips": [c.clip for c in shown],
            "without_video": sum(c.clip not in videos for c in clips)}


def _score_all(clips, speaker, synthetic, corpus, rate, out: Path) -> dict:
    """Every model and peer on ``clips`` with the audio at ``rate`` (None: the corpus's)."""
    label = rate or clips[0].sample_rate
    scores = {"speaker_model": score_model(speaker, clips, training_corpus=corpus,
                                           input_rate=rate),
              "synthetic_model": score_model(synthetic, clips, input_rate=rate)}
    scores.update({p: score_peer(p, clips, input_rate=rate) for p in PEERS})
    out_dict = {}
    for name, s in scores.items():
        write_scores_csv(s, out / f"per_clip_{name}_{label}.csv", extra={"input_rate": label})
        d = s.to_dict()
        d["pooled"]["input_rate"] = label
        out_dict[name] = d
    return out_dict


def evaluate_real_speaker(paths: RunPaths, cfg, runner) -> dict:
    """The stage (``runner``: :func:`talkingface.stages.run`, for the nested run)."""
    src = real_corpus(cfg)
    check_folder(src, SETTING, also=ALSO)  # as the key found it (cached): refused under this setting's name
    out = paths.stage("real_speaker")
    nested = RunPaths.at(paths.root / NESTED, cache_dir=paths.cache)
    sub_cfg = dataclasses.replace(cfg, corpus=dataclasses.replace(cfg.corpus,
                                                                  source=str(src.resolve())))
    runner(["units", "mapping"], nested, sub_cfg)
    t0 = time.perf_counter()
    mapping_done = read_done(nested.mapping) or {}
    test_ids = mapping_done.get("test_utterances") or []
    if isinstance(test_ids, str):
        test_ids = json.loads(test_ids.replace("'", '"'))
    corpus = load_corpus(nested.corpus)
    expected = utterance_test_ids(corpus, sub_cfg)
    if list(test_ids) != expected:
        raise CorpusError(f"{nested.mapping}: the mapping held out {len(test_ids)} utterances, "
                          f"the split of the units stage {len(expected)}; they must be the same")
    units_path = nested.units / "motion_units.npz"
    held = set(MotionUnits.load(units_path).metadata_.get("held_out_utterances") or [])
    leaked = sorted(set(test_ids) - held)
    clips = clips_from_corpus(nested.corpus, test_ids)
    speaker_tfmap = nested.mapping / mapping_done["models"]["utterance"]
    speaker = _animator(speaker_tfmap, units_path)
    synth_tfmap, synth_units = find_model(str(paths.root), paths.root.parent)
    synthetic = _animator(synth_tfmap, synth_units)
    native = clips[0].sample_rate
    rates = {native: _score_all(clips, speaker, synthetic, corpus, None, out)}
    for r in EXTRA_RATES:
        rates[r] = _score_all(clips, speaker, synthetic, corpus, r, out)
    aligned = {c.clip: align_markers(c.markers) for c in clips}
    neutrals = {"speaker_model": model_neutrals(speaker, clips, aligned, corpus)[0],
                "synthetic_model": model_neutrals(synthetic, clips, aligned)[0]}
    spk = clips[0].speaker
    by_r = sorted(rates[native]["speaker_model"]["clips"],
                  key=lambda row: (row["r_speech"] is None, row["r_speech"] or 0.0))
    median_clip = by_r[len(by_r) // 2]["clip"]
    strip_clip = next(c for c in clips if c.clip == median_clip)
    _strip(out / "strip.npz", strip_clip, {"speaker_model": speaker,
                                            "synthetic_model": synthetic},
           {k: v[spk] for k, v in neutrals.items()})
    side = _side_by_side(out, clips, video_files(real_videos(cfg)), speaker, synthetic,
                         neutrals["speaker_model"][spk])
    units = speaker.units
    with atomic_file(out / "units.npz") as tmp:
        np.savez(tmp, components=units.components_,
                 scale=2 * np.sqrt(units.variance_[:units.n_utterance]),
                 neutral=neutrals["speaker_model"][spk])
    info = corpus.info
    units_done = read_done(nested.units) or {}
    summary = {
        "corpus": {"source": info.get("source", str(src)), "speaker": spk,
                   "utterances": len(corpus), "frames": corpus.n_frames, "fps": clips[0].fps,
                   "sample_rate": native, "refused": info.get("refused", 0),
                   "licence": info.get("licence", "")},
        "units": {"n_utterance": units.n_utterance, "variance_explained":
                  _variance(nested.units), "synthetic": _variance(paths.units),
                  "paper": PAPER_VARIANCE,
                  "fitted_utterances": units_done.get("fitted_utterances"),
                  "held_out": len(held), "test_sentences_in_fit": len(leaked)},
        "tables": {"real": _rows(nested.mapping / "tables.csv"),
                   "synthetic": _rows(paths.mapping / "tables.csv")},
        "test_utterances": test_ids,
        "input_rate": native,
        "face_scores": rates[native],
        "rates": {str(r): {k: v["pooled"] for k, v in d.items()} for r, d in rates.items()},
        "peers": {"names": list(PEERS), "versions": peer_versions(),
                  "openfacefx_text_words": WORD_TIMES},
        "models": {"speaker_model": str(speaker_tfmap), "synthetic_model": str(synth_tfmap)},
        "side_by_side": side,
        "scoring_seconds": time.perf_counter() - t0,
        "note": str(mapping_done.get("note", "")),
    }
    with atomic_file(out / "summary.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=1, default=float) + "\n")
    p = {k: v["pooled"] for k, v in rates[native].items()}
    nan = float("nan")
    return {"speaker_r": p["speaker_model"]["r_speech"],
            "synthetic_r": p["synthetic_model"]["r_speech"],
            "synthetic_closures": p["synthetic_model"]["closure_rate"],
            "loudness_r": p["loudness"]["r_speech"] if "loudness" in p else nan,
            "test_clips": len(clips), "scoring_seconds": summary["scoring_seconds"]}
