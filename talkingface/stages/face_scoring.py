"""Models and peers scored against real faces (``talkingface evaluate-face`` and the report's
real-speaker section): real clips from videos or from a corpus, lips predicted from their audio,
and the comparison of :mod:`analysis.face_eval` (its rules: speech frames, valid frames,
closures on /p b m/, chance).

Both sides are compared in the aligned frame (:func:`face_model.alignment.align_markers`: the
glasses markers on the layout's): the real markers aligned; the prediction is the speaker's
neutral face plus the model's deformation (Eq. 2) from the audio. The neutral face is, for a
speaker the model was trained on, the one its Motion Units were fitted with (``neutrals`` in
their metadata: training sentences only) or else the training corpus's
(:func:`face_model.alignment.speaker_neutrals`) — then LVE is reported; for any other speaker
the median of the aligned first frames of its clips here. Clips scored as a speaker the model
was trained on must show that speaker's face: the median of their aligned first frames is
compared with the speaker's neutral face (:func:`face_model.face_match.check_face_match`: the
shape's misfit after a similarity fit, at most :data:`face_model.face_match.MAX_FACE_MISFIT` % of
the face's size), and clips of another face are refused before any scoring. The prediction has
exactly the clip's frames (the model's frames cut, or the last one repeated, to the clip's
``n_frames``).

Input rate: with ``input_rate`` the clip's audio is resampled (:func:`groundwork.audio.resample`)
to that rate and the model (or peer) hears it at that rate.

The transcript peer (``openfacefx-text``) is given the clip's word times when it has them (a
corpus's ``words/`` files, or a video's GRID ``.align``): each word segmented on its own interval
and shifted there (:func:`peer_opening`); without them, the transcript over the speech span. Its
pooled scores say which timing each clip got (``word_times``).
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from analysis.face_eval import ClipTrack, FaceScores, phone_segments, score_clips
from face_model.alignment import align_markers, speaker_neutrals, unflatten
from face_model.corpus import load_corpus
from face_model.face_match import check_face_match
from face_model.forced_align import align_audio
from face_model.landmarks import extract_landmarks
from face_model.layout import mouth_opening
from face_model.transcripts import find_transcript
from face_model.video_corpus import FPS as VIDEO_FPS
from face_model.video_corpus import ClipRefused, FromVideoSettings, clip_data
from face_model.video_import import check_sources
from groundwork.audio import resample
from groundwork.errors import CorpusError, TalkingFaceError
from mapping.peers import peer_track
from mapping.recogniser import fit_length


@dataclass(frozen=True)
class RealClip:
    """One real clip: mono audio, the 79 markers (image pixels) at ``fps``, its phone labels
    (None: unknown), per frame whether a face was detected (``valid``), its transcript, and its
    words' times, ``((start_s, end_s, word), ...)`` in seconds from the start of its audio
    (None: unknown)."""

    clip: str
    speaker: str
    audio: np.ndarray
    sample_rate: int
    markers: np.ndarray
    fps: float
    phones: tuple | None = None
    valid: np.ndarray | None = None
    text: str = ""
    words: tuple | None = None

    @property
    def n_frames(self) -> int:
        return len(self.markers)


def _valid(quality, n: int) -> np.ndarray | None:
    """Frames whose face was detected: not interpolated (the quality file's 2nd column)."""
    return None if quality is None else np.asarray(quality)[:n, 1] == 0


def clips_from_corpus(corpus_dir, utt_ids=None) -> list[RealClip]:
    """The utterances of a corpus folder (all, or ``utt_ids`` in corpus order)."""
    corpus = load_corpus(corpus_dir)
    keep = None if utt_ids is None else set(utt_ids)
    return [RealClip(u.utt_id, u.speaker, u.audio, u.sample_rate, u.markers, float(u.fps),
                     phone_segments(u.phones), _valid(u.quality, u.n_frames), u.text,
                     _word_tuples(u.words))
            for u in corpus.utterances if keep is None or u.utt_id in keep]


def _word_tuples(words) -> tuple | None:
    """``((start_s, end_s, word), ...)`` of a corpus's or a transcript's words (None: none)."""
    if not words:
        return None
    return tuple((float(w[0]), float(w[1]), str(w[2])) if isinstance(w, tuple) else
                 (float(w.start_s), float(w.end_s), str(w.word)) for w in words)


def _phones_of(video: Path, y: np.ndarray, sr: int
               ) -> tuple[tuple | None, str, tuple | None, str]:
    """``(phones, text, words, why)``: the clip's transcript (:func:`face_model.transcripts.
    find_transcript`) forced-aligned, and its word times when it gives them (a GRID ``.align``);
    None and the reason when there is none or it fails."""
    try:
        t = find_transcript(video)
        if t is None:
            return None, "", None, "no transcript beside it"
        phones = phone_segments(align_audio(y, sr, t.text, source=str(video)))
        return phones, t.text, _word_tuples(t.words), ""
    except TalkingFaceError as exc:
        return None, "", None, str(exc)


def clips_from_videos(src, *, speaker: str, workers: int = 2, progress: bool = True,
                      settings: FromVideoSettings | None = None) -> tuple[list, list, list]:
    """``(clips, refused, unaligned)``: the videos of ``src`` through the landmark worker
    (clips whose face is missed too often are refused with the reason, as the import does);
    each clip's transcript, when one is found beside it, forced-aligned to give its phones
    (``unaligned``: ``(clip, why)`` of the clips without phones, hence without speech frames)."""
    settings = (settings or FromVideoSettings()).check()
    videos = check_sources(src)
    clips, refused, unaligned = [], [], []
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
            phones, text, words, why = _phones_of(v, c.audio, c.sample_rate)
            if phones is None:
                unaligned.append((v.stem, why))
            clips.append(RealClip(v.stem, speaker, c.audio, c.sample_rate, c.markers,
                                  float(VIDEO_FPS),
                                  phones, ~np.asarray(c.interpolated, bool), text, words))
    if not clips:
        first = refused[0][1] if refused else f"{src}: no clip could be read"
        raise CorpusError(first + (f" (and {len(refused) - 1} more clips refused)"
                                   if len(refused) > 1 else ""))
    return clips, refused, unaligned


def at_rate(c: RealClip, input_rate: int | None) -> tuple[np.ndarray, int]:
    """The clip's audio at ``input_rate`` Hz (as is when None or equal)."""
    if input_rate is None or int(input_rate) == c.sample_rate:
        return c.audio, c.sample_rate
    return resample(c.audio, sr_in=c.sample_rate, sr_out=int(input_rate)), int(input_rate)


def _first_frame_neutrals(clips: list, aligned: dict) -> dict:
    firsts: dict = {}
    for c in clips:
        firsts.setdefault(c.speaker, []).append(aligned[c.clip][0])
    return {spk: np.median(np.stack(f), axis=0) for spk, f in firsts.items()}


def model_neutrals(animator, clips: list, aligned: dict, training_corpus=None
                   ) -> tuple[dict, set]:
    """``(neutral per speaker, speakers the model was trained on)`` (module docstring)."""
    neutrals = _first_frame_neutrals(clips, aligned)
    if training_corpus is None:
        return neutrals, set()
    if not hasattr(training_corpus, "utterances"):
        training_corpus = load_corpus(training_corpus)
    trained = {c.speaker for c in clips} & {u.speaker for u in training_corpus.utterances}
    fitted = animator.units.metadata_.get("neutrals")
    if fitted:
        own = {k: np.asarray(v, np.float64) for k, v in fitted.items()}
    else:
        own = speaker_neutrals(training_corpus,
                               model=animator.units.metadata_.get("alignment", "similarity"))
    neutrals.update({k: v for k, v in own.items() if k in trained})
    return neutrals, trained


def check_faces(clips: list, aligned: dict, neutrals: dict, trained: set) -> dict:
    """``{speaker: misfit (percent)}`` of the clips of each speaker in ``trained`` against its
    neutral face in ``neutrals``; raises :class:`groundwork.errors.ParameterError` naming the
    speaker and its first clip when a misfit is above the threshold (module docstring)."""
    own = _first_frame_neutrals(clips, aligned)
    return {spk: check_face_match(spk, [c.clip for c in clips if c.speaker == spk], own[spk],
                                  neutrals[spk])
            for spk in sorted(trained)}


def predicted_markers(animator, c: RealClip, neutral: np.ndarray, input_rate=None
                      ) -> np.ndarray:
    """The model's markers (n_frames, 79, 2) for clip ``c`` on ``neutral``: exactly the clip's
    frames."""
    y, sr = at_rate(c, input_rate)
    mups = fit_length(animator.mups(y, sr), c.n_frames)
    return neutral[None] + unflatten(animator.units.inverse_transform(mups, "neutral"))


def score_model(animator, clips: list, *, training_corpus=None, input_rate=None,
                progress: bool = False) -> FaceScores:
    """Score ``animator`` (:class:`mapping.animator.FaceAnimator`) on real ``clips``.

    ``training_corpus`` (a loaded corpus or its folder), when given, names the speakers the
    model was trained on: their neutral face is the model's (module docstring) and their LVE is
    scored, once their own neutral face is found to fit it (:func:`check_faces`: clips of
    another face raise :class:`groundwork.errors.ParameterError`). ``input_rate``: the audio's
    rate the model hears (Hz; None: the clip's own).
    """
    alignment = animator.units.metadata_.get("alignment", "similarity")
    aligned = {c.clip: align_markers(c.markers, model=alignment) for c in clips}
    neutrals, trained = model_neutrals(animator, clips, aligned, training_corpus)
    check_faces(clips, aligned, neutrals, trained)
    tracks = []
    for c in tqdm(clips, desc="scoring", unit="clip", disable=not progress, leave=False):
        pred = predicted_markers(animator, c, neutrals[c.speaker], input_rate)
        tracks.append(ClipTrack.from_markers(c.clip, c.speaker, aligned[c.clip], pred, c.fps,
                                             phones=c.phones, valid=c.valid,
                                             lve=c.speaker in trained))
    return score_clips(tracks)


def speech_span(c: RealClip) -> tuple[int, int] | None:
    """``(first, stop)`` frames from the first to the last non-silence phone (None: no phones
    or no speech)."""
    if not c.phones:
        return None
    speech = [(s, e) for s, e, ph in c.phones if ph != "sil"]
    if not speech:
        return None
    a = int(np.ceil(speech[0][0] * c.fps - 1e-9))
    b = min(c.n_frames, int(np.ceil(speech[-1][1] * c.fps - 1e-9)))
    return (a, b) if b > a else None


# What timing the transcript peer got for a clip (:func:`peer_timing`).
WORD_TIMING = "words"  # each word on its own interval (the clip's word times)
SPAN_TIMING = "speech span"  # the transcript over the speech span (no word times)
NO_TIMING = "none"  # neither words nor a transcript with phones: closed throughout


def peer_timing(c: RealClip) -> str:
    """Which timing ``openfacefx-text`` gets for clip ``c``: :data:`WORD_TIMING` when it has word
    times, :data:`SPAN_TIMING` when it has a transcript and a speech span, else
    :data:`NO_TIMING`."""
    if c.words:
        return WORD_TIMING
    return SPAN_TIMING if c.text and speech_span(c) is not None else NO_TIMING


def peer_opening(peer: str, c: RealClip, input_rate=None) -> np.ndarray:
    """One peer's opening for clip ``c`` (n_frames,). ``openfacefx-text`` is given the clip's
    word times when it has them (``c.words``): each word segmented on its own interval and
    shifted there (:func:`mapping.peers.peer_track` with ``each_word``), closed (0) at every
    frame outside every word. Without word times it gets the transcript only, spread by its own
    segmentation over the speech span (:func:`speech_span`: the audio of those frames; closed,
    0, outside it)."""
    y, sr = at_rate(c, input_rate)
    if peer != "openfacefx-text":
        return peer_track(peer, y, sr, n_frames=c.n_frames, fps=c.fps).opening
    timing = peer_timing(c)
    if timing == WORD_TIMING:
        return peer_track(peer, y, sr, n_frames=c.n_frames, fps=c.fps, words=list(c.words),
                          each_word=True).opening
    out = np.zeros(c.n_frames)
    if timing == NO_TIMING:
        return out
    a, b = speech_span(c)
    part = y[int(round(a * sr / c.fps)):int(round(b * sr / c.fps))]
    out[a:b] = peer_track(peer, part, sr, n_frames=b - a, fps=c.fps,
                          transcript=c.text).opening
    return out


def score_peer(peer: str, clips: list, *, input_rate=None, progress: bool = False
               ) -> FaceScores:
    """Score a peer (:data:`mapping.peers.PEERS`) on real ``clips``: its opening against the
    real aligned inner-lip opening, by the same rules. For ``openfacefx-text`` the pooled
    figures also say which timing each clip got: ``word_times`` (``{clip: "words" | "speech
    span" | "none"}``, :func:`peer_timing`) and ``word_time_clips`` (how many had words)."""
    tracks = []
    for c in tqdm(clips, desc=peer, unit="clip", disable=not progress, leave=False):
        real = mouth_opening(align_markers(c.markers))
        tracks.append(ClipTrack(c.clip, c.speaker, real, peer_opening(peer, c, input_rate),
                                c.fps, c.phones, c.valid))
    scores = score_clips(tracks)
    if peer == "openfacefx-text":
        timing = {c.clip: peer_timing(c) for c in clips}
        scores.pooled["word_times"] = timing
        scores.pooled["word_time_clips"] = sum(t == WORD_TIMING for t in timing.values())
    return scores
