"""A model scored against real faces (``talkingface evaluate-face`` and the report's real-speaker
section): real clips from videos or from a corpus, the model's lips predicted from their audio,
and the comparison of :mod:`analysis.face_eval`.

Both sides are compared in the aligned frame (:func:`face_model.alignment.align_markers`: the
glasses markers on the layout's): the real markers aligned, minus the speaker's neutral face;
the prediction is the model's deformation (Eq. 2) from the audio. The speaker's neutral face is
the training corpus's (:func:`face_model.alignment.speaker_neutrals`) when the model was trained
on that speaker — then LVE is reported — else the median of the aligned first frames of the
speaker's clips here.
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from analysis.face_eval import ClipTrack, FaceScores, score_clips
from face_model.alignment import align_markers, speaker_neutrals, unflatten
from face_model.corpus import load_corpus
from face_model.landmarks import extract_landmarks
from face_model.video_corpus import ClipRefused, FromVideoSettings, clip_data, find_videos
from groundwork.errors import CorpusError


@dataclass(frozen=True)
class RealClip:
    """One real clip: mono audio and the 79 markers (image pixels) at 30 fps."""

    clip: str
    speaker: str
    audio: np.ndarray
    sample_rate: int
    markers: np.ndarray


def clips_from_corpus(corpus_dir, utt_ids=None) -> list[RealClip]:
    """The utterances of a corpus folder (all, or ``utt_ids`` in corpus order)."""
    corpus = load_corpus(corpus_dir)
    keep = None if utt_ids is None else set(utt_ids)
    return [RealClip(u.utt_id, u.speaker, u.audio, u.sample_rate, u.markers)
            for u in corpus.utterances if keep is None or u.utt_id in keep]


def clips_from_videos(src, *, speaker: str, workers: int = 2, progress: bool = True,
                      settings: FromVideoSettings | None = None) -> tuple[list, list]:
    """``(clips, refused)``: the videos of ``src`` through the landmark worker (clips whose
    face is missed too often are refused with the reason, as the import does)."""
    settings = (settings or FromVideoSettings()).check()
    videos = find_videos(src)
    clips, refused = [], []
    with tempfile.TemporaryDirectory(prefix="talkingface-face-") as tmp:
        tmp = Path(tmp)
        jobs = [(v, tmp / f"{i:05d}-{v.stem}.npz") for i, v in enumerate(videos)]
        with tqdm(total=len(jobs), desc="landmarks", unit="clip", disable=not progress,
                  leave=False) as bar:
            replies = extract_landmarks(jobs, workers=workers, progress=bar.update)
        for v, lm_file in jobs:
            reply = replies[str(v)]
            if "error" in reply:
                refused.append((v.stem, reply["error"]))  # the worker names the file
                continue
            try:
                c = clip_data(v, lm_file, settings, tmp)
            except ClipRefused as exc:
                refused.append((v.stem, str(exc)))
                continue
            clips.append(RealClip(v.stem, speaker, c.audio, c.sample_rate, c.markers))
    if not clips:
        first = refused[0][1] if refused else f"{src}: no clip could be read"
        raise CorpusError(first + (f" (and {len(refused) - 1} more clips refused)"
                                   if len(refused) > 1 else ""))
    return clips, refused


def _neutrals(clips: list, aligned: dict) -> dict:
    firsts: dict = {}
    for c in clips:
        firsts.setdefault(c.speaker, []).append(aligned[c.clip][0])
    return {spk: np.median(np.stack(f), axis=0) for spk, f in firsts.items()}


def score_model(animator, clips: list, *, training_corpus=None, progress: bool = False
                ) -> FaceScores:
    """Score ``animator`` (:class:`mapping.animator.FaceAnimator`) on real ``clips``.

    ``training_corpus`` (a loaded corpus or its folder), when given, names the speakers the
    model was trained on: their neutral face is the training corpus's and their LVE is scored.
    """
    if training_corpus is not None and not hasattr(training_corpus, "utterances"):
        training_corpus = load_corpus(training_corpus)
    alignment = animator.units.metadata_.get("alignment", "similarity")
    aligned = {c.clip: align_markers(c.markers, model=alignment) for c in clips}
    neutrals = _neutrals(clips, aligned)
    trained = set()
    if training_corpus is not None:
        seen = {u.speaker for u in training_corpus.utterances}
        trained = {c.speaker for c in clips} & seen
        if trained:
            neutrals.update({k: v for k, v in
                             speaker_neutrals(training_corpus, model=alignment).items()
                             if k in trained})
    tracks = []
    for c in tqdm(clips, desc="scoring", unit="clip", disable=not progress, leave=False):
        mups = animator.mups(c.audio, c.sample_rate)
        d_pred = unflatten(animator.units.inverse_transform(mups, "neutral"))
        real = aligned[c.clip]
        n = min(len(real), len(d_pred))
        neutral = neutrals[c.speaker]
        tracks.append(ClipTrack.from_markers(c.clip, c.speaker, real[:n], neutral[None]
                                             + d_pred[:n], fps=30, lve=c.speaker in trained))
    return score_clips(tracks)
