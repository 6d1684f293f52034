"""The lip-sync tools users already use, each behind one small adapter: a mouth opening per frame.

DESIGN.md, "Evaluation on real data": the peers are scored with the same metrics beside our models.
Each peer turns audio (and, for the transcript mode, words) into one :class:`PeerTrack` on the
project's frame grid (frame ``k`` at ``k / fps`` seconds, ``n_frames`` given by the caller):

==================== ===========================================================================
``loudness``          the loudness envelope, :func:`loudness_opening` (dB of the RMS in 40 ms
                      windows centred on each frame) minus its minimum; no visemes.
``openfacefx-text``   ``openfacefx`` 0.24 transcript mode: with word times, its word-anchor API
                      (``anchors.anchored_segments``: each word's phones stay inside its interval)
                      then ``pipeline.generate_from_alignment``, or, with ``each_word``, each word
                      segmented on its own interval (``pipeline.naive_segments`` of the word over
                      its duration, the track shifted to its start; closed outside every word);
                      with a transcript only, ``pipeline.naive_segments`` over the whole clip.
``openfacefx-energy`` ``openfacefx`` loudness mode, ``energy.generate_from_energy`` on a temporary
                      16-bit PCM WAV at the input rate (it reads nothing else).
``pylipsync``         ``pylipsync`` 0.2.1 (a uLipSync port): ``PhonemeAnalyzer().
                      extract_phoneme_segments`` on the audio resampled to its 16 kHz (below
                      16 kHz it would read the samples as 16 kHz ones), per frame the
                      volume-weighted targets of ``aa ee ih oh ou silence``.
==================== ===========================================================================

The ``openfacefx`` tracks are keyframes (its own reduction, default ``epsilon``, as users get
them), sampled at the frame instants by linear interpolation held at the ends (what its
``retarget._sampler`` does). ``pylipsync`` gives one segment per analysis hop; each segment's
targets sit at its centre and are interpolated to the frame instants the same way.

Neither package gives a mouth opening in pixels: each channel maps to an opening in [0, 1] and
to one of our visemes (:data:`face_model.phones.VISEMES`) through one stated table, chosen a
priori from phonetics and never tuned on scores. Opening = Σ weight × table opening; viseme = the
table viseme of the channel of largest weight (``neutral`` when every weight is below
:data:`SILENT_WEIGHT`).

:data:`OCULUS_TABLE` (``openfacefx``'s Oculus-15 channels, with the ARPAbet phones its
``visemes.PHONEME_TO_VISEME`` sends to each):

======= ============= ======== =========================================================
channel phones        opening  viseme
======= ============= ======== =========================================================
sil     (silence)     0.0      neutral
PP      p b m         0.0      m
FF      f v           0.1      f
TH      th dh         0.2      neutral
DD      t d l         0.2      neutral
kk      k g hh        0.25     neutral
CH      ch jh sh zh   0.2      u  (rounded, protruded: ``face_model.phones`` puts them in u)
SS      s z           0.1      neutral
nn      n ng          0.2      neutral
RR      r er          0.2      u  (rounded: ``face_model.phones`` puts r, er in u)
aa      aa ae ah ay   1.0      a
E       eh ey ih      0.7      i
I       iy y          0.5      i
O       ao ow oy aw   0.8      o
U       uw uh w       0.4      u
======= ============= ======== =========================================================

:data:`ULIPSYNC_TABLE` (``pylipsync``'s templates, the vowels A E I O U of uLipSync):

======= ======== =======
channel opening  viseme
======= ======== =======
aa (A)  1.0      a
ee (E)  0.7      i
ih (I)  0.5      i
oh (O)  0.8      o
ou (U)  0.4      u
silence 0.0      neutral
======= ======== =======

Nothing here is random; both packages are deterministic (``tests/mapping/test_peers.py`` runs
each twice).
"""
from __future__ import annotations

import importlib.metadata
import math
import os
import tempfile
from dataclasses import dataclass

import numpy as np

from face_model.phones import VISEMES
from groundwork.audio import resample, write_wav
from groundwork.errors import ParameterError

PEERS = ("loudness", "openfacefx-text", "openfacefx-energy", "pylipsync")
PACKAGES = ("openfacefx", "pylipsync")

# Oculus-15 channel -> (mouth opening in [0, 1], our viseme); see the module docstring.
OCULUS_TABLE: dict[str, tuple[float, str]] = {
    "sil": (0.0, "neutral"), "PP": (0.0, "m"), "FF": (0.1, "f"),
    "TH": (0.2, "neutral"), "DD": (0.2, "neutral"), "kk": (0.25, "neutral"),
    "CH": (0.2, "u"), "SS": (0.1, "neutral"), "nn": (0.2, "neutral"), "RR": (0.2, "u"),
    "aa": (1.0, "a"), "E": (0.7, "i"), "I": (0.5, "i"), "O": (0.8, "o"), "U": (0.4, "u"),
}
# pylipsync template -> (mouth opening in [0, 1], our viseme).
ULIPSYNC_TABLE: dict[str, tuple[float, str]] = {
    "aa": (1.0, "a"), "ee": (0.7, "i"), "ih": (0.5, "i"), "oh": (0.8, "o"), "ou": (0.4, "u"),
    "silence": (0.0, "neutral"),
}
SILENT_WEIGHT = 1e-3       # below this largest weight a frame is silence (neutral)
PYLIPSYNC_SR = 16000       # PhonemeAnalyzer.TARGET_SAMPLE_RATE
# Word tokens of alignments (GRID, MFA) that mark a pause rather than a word.
PAUSE_TOKENS = frozenset({"", "sil", "sp", "spn"})


@dataclass(frozen=True)
class PeerTrack:
    """One peer's mouth on the frame grid.

    Attributes
    ----------
    opening : ndarray, shape (n_frames,), float64
        A mouth opening in the peer's own units, 0 = closed (dB above the clip's quietest frame
        for ``loudness``; Σ weight × table opening, in [0, 1], for the others).
    visemes : ndarray, shape (n_frames,), int, or None
        Indices into :data:`face_model.phones.VISEMES`; None for ``loudness``.
    peer : str
        One of :data:`PEERS`.
    """

    opening: np.ndarray
    visemes: np.ndarray | None
    peer: str


def loudness_opening(y: np.ndarray, sr: int, n: int, window_s: float = 0.04,
                     fps: float = 30.0) -> np.ndarray:
    """The loudness envelope: dB of the RMS in ``window_s`` windows centred on each frame.

    The floor an audio-driven mouth should beat (FIELD_NOTES, "Real faces from video").

    Parameters
    ----------
    y : ndarray, shape (n_samples,)
        Mono audio.
    sr : int
        Sample rate, in Hz.
    n : int
        Number of frames; frame ``k`` is centred at ``k / fps`` seconds.
    window_s : float
        Window length, in seconds.
    fps : float
        Frame rate, in frames per second.

    Returns
    -------
    ndarray, shape (n,), float64
        ``10 log10(mean(y²) + 1e-10)`` per window (dB re full scale 1.0); -100 where the window
        holds no sample (past the end of the audio).
    """
    half = int(round(window_s * sr / 2))
    centres = (np.arange(n) * sr / fps).astype(int)
    out = np.empty(n)
    for k, c in enumerate(centres):
        seg = y[max(0, c - half):c + half]
        out[k] = 10 * np.log10(np.mean(seg.astype(np.float64) ** 2) + 1e-10) if len(seg) else -100
    return out


def peer_versions() -> dict:
    """``{package: version}`` of the peer packages installed (None when one is missing)."""
    out = {}
    for name in PACKAGES:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = None
    return out


def peer_track(peer: str, y: np.ndarray, sr: int, *, n_frames: int, fps: float,
               words: list[tuple[float, float, str]] | None = None,
               transcript: str | None = None, each_word: bool = False) -> PeerTrack:
    """One peer's mouth opening (and visemes) for one clip, on the project's frame grid.

    Parameters
    ----------
    peer : str
        One of :data:`PEERS`.
    y : ndarray, shape (n_samples,)
        Mono audio, float in [-1, 1] (the ``openfacefx-energy`` WAV clips beyond).
    sr : int
        Sample rate, in Hz.
    n_frames : int
        Output length; frame ``k`` is at ``k / fps`` seconds. Frames past a peer's own track
        hold its last value.
    fps : float
        Frame rate, in frames per second.
    words : list of (start_s, end_s, word), optional
        Word times for ``openfacefx-text`` (time-ordered, not overlapping). Pause tokens
        (:data:`PAUSE_TOKENS`) are dropped.
    transcript : str, optional
        The clip's text for ``openfacefx-text``; with ``words`` too, the words no time covers
        share the gaps between the timed ones (the package's anchored alignment).
    each_word : bool
        ``openfacefx-text`` with ``words``: segment each word on its own interval and shift it
        there (FIELD_NOTES, "Lip-sync tools users already use") instead of the anchored
        alignment over the clip. The package's coarticulation then never reaches outside a
        word: the mouth is closed (``sil``) at every frame outside every word's
        ``[start_s, end_s)``, and ``transcript`` is not read.

    Returns
    -------
    PeerTrack

    Raises
    ------
    ParameterError
        An unknown peer; ``n_frames`` < 1; ``fps`` or ``sr`` not positive; ``y`` not 1-D, empty
        or not finite; ``openfacefx-text`` with neither words nor a transcript, or with words
        the package rejects (with ``each_word``: words out of time order, overlapping or
        ending before they start).
    """
    if peer not in PEERS:
        raise ParameterError(f"peer {peer!r}: unknown; allowed: {', '.join(PEERS)}")
    if isinstance(n_frames, bool) or not isinstance(n_frames, (int, np.integer)) or n_frames < 1:
        raise ParameterError(f"n_frames {n_frames!r}: an integer ≥ 1 is needed")
    if not (isinstance(fps, (int, float, np.number)) and math.isfinite(fps) and fps > 0):
        raise ParameterError(f"fps {fps!r}: a finite frame rate > 0 is needed")
    if not (isinstance(sr, (int, np.integer)) and sr > 0):
        raise ParameterError(f"sr {sr!r}: a positive integer sample rate (Hz) is needed")
    y = np.asarray(y)
    if y.ndim != 1 or len(y) == 0:
        raise ParameterError(f"y: shape {y.shape}; non-empty 1-D mono audio is needed")
    bad = ~np.isfinite(y)
    if bad.any():
        raise ParameterError(f"y: {int(bad.sum())} non-finite samples (NaN/inf), the first at "
                             f"sample {int(np.argmax(bad))}; finite audio is needed")
    times = np.arange(int(n_frames)) / float(fps)
    if peer == "loudness":
        db = loudness_opening(y, int(sr), int(n_frames), fps=float(fps))
        return PeerTrack(db - db.min(), None, peer)
    if peer == "openfacefx-text":
        if each_word and words is not None:
            weights = _openfacefx_each_word(_timed(words), times, float(fps))
        else:
            weights = _openfacefx_text(y, int(sr), times, float(fps), words, transcript)
        return _from_weights(weights, OCULUS_TABLE, peer)
    if peer == "openfacefx-energy":
        return _from_weights(_openfacefx_energy(y, int(sr), times, float(fps)), OCULUS_TABLE,
                             peer)
    return _from_weights(_pylipsync(y, int(sr), times, float(fps)), ULIPSYNC_TABLE, peer)


def _from_weights(weights: dict, table: dict, peer: str) -> PeerTrack:
    """Opening and viseme per frame from ``{channel: (n_frames,) weight}`` and a table."""
    names = list(table)
    w = np.stack([weights.get(name, np.zeros_like(next(iter(weights.values()))))
                  for name in names], axis=1)
    openings = np.array([table[name][0] for name in names])
    visemes = np.array([VISEMES.index(table[name][1]) for name in names])
    opening = (w * openings).sum(axis=1)
    best = visemes[np.argmax(w, axis=1)]
    best[w.max(axis=1) < SILENT_WEIGHT] = VISEMES.index("neutral")
    return PeerTrack(opening.astype(np.float64), best.astype(int), peer)


def _sample_track(track, times: np.ndarray) -> dict:
    """An ``openfacefx`` FaceTrack's channels at ``times`` (linear between keys, held at the
    ends; a channel the track dropped because it never fires is absent, i.e. 0)."""
    out = {}
    for channel in track.channels:
        if channel.name in OCULUS_TABLE and channel.keys:
            kt = np.array([k.time for k in channel.keys])
            kv = np.array([k.value for k in channel.keys])
            out[channel.name] = np.interp(times, kt, kv)
    return out or {"sil": np.ones(len(times))}


def _timed(words) -> list[tuple[float, float, str]]:
    """``words`` as ``(start_s, end_s, word)`` without pause tokens (ParameterError: none left)."""
    timed = [(float(s), float(e), str(w)) for s, e, w in words
             if str(w).strip().lower() not in PAUSE_TOKENS]
    if not timed:
        raise ParameterError("words: no word left after dropping pause tokens "
                             f"{sorted(PAUSE_TOKENS)}; at least one timed word is needed")
    return timed


def _openfacefx_each_word(timed, times, fps) -> dict:
    """Channel weights at ``times`` with each word of ``timed`` segmented alone over its own
    duration (``naive_segments``: silence, its phones, silence), the track sampled at the frame
    times minus the word's start; ``sil`` = 1 at the frames outside every word."""
    from openfacefx.pipeline import generate_from_alignment, naive_segments

    prev_end = 0.0
    for i, (s, e, w) in enumerate(timed):
        if not (math.isfinite(s) and math.isfinite(e) and 0 <= s < e):
            raise ParameterError(f"words: word {i} {w!r} from {s} s to {e} s; allowed: "
                                 "0 <= start_s < end_s")
        if s < prev_end - 1e-9:
            raise ParameterError(f"words: word {i} {w!r} starts at {s} s, before the previous "
                                 f"word ends ({prev_end} s); allowed: words in time order, "
                                 "not overlapping")
        prev_end = e
    weights = {"sil": np.ones(len(times))}
    for s, e, w in timed:
        inside = (times >= s) & (times < e)
        if not inside.any():
            continue
        try:
            segments = naive_segments(w, e - s)
        except ValueError as err:
            raise ParameterError(f"words: openfacefx rejects {w!r}: {err}") from None
        part = _sample_track(generate_from_alignment(segments, fps=fps), times[inside] - s)
        for name in set(weights) | set(part):
            weights.setdefault(name, np.zeros(len(times)))[inside] = part.get(name, 0.0)
    return weights


def _openfacefx_text(y, sr, times, fps, words, transcript) -> dict:
    from openfacefx.anchors import Anchor, anchored_segments
    from openfacefx.pipeline import generate_from_alignment, naive_segments

    duration = len(y) / sr
    if words is not None:
        timed = _timed(words)
        duration = max(duration, max(e for _, e, _ in timed))
        text = transcript if transcript else " ".join(w for _, _, w in timed)
        try:
            segments = anchored_segments(text, duration, [Anchor(w, s, e) for s, e, w in timed])
        except ValueError as err:
            raise ParameterError(f"words: openfacefx rejects them: {err}") from None
    elif transcript:
        segments = naive_segments(transcript, duration)
    else:
        raise ParameterError("peer 'openfacefx-text': needs words (start_s, end_s, word) or a "
                             "transcript; got neither")
    return _sample_track(generate_from_alignment(segments, fps=fps), times)


def _openfacefx_energy(y, sr, times, fps) -> dict:
    from openfacefx.energy import generate_from_energy

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "clip.wav")
        write_wav(path, np.clip(y, -1.0, 1.0), sr)
        track = generate_from_energy(path, fps=fps)
    return _sample_track(track, times)


def _pylipsync(y, sr, times, fps) -> dict:
    from pylipsync import PhonemeAnalyzer

    analyzer = PhonemeAnalyzer()
    # Its own downsampling leaves audio below 16 kHz as is and then reads it as 16 kHz.
    audio = resample(y.astype(np.float32), sr_in=sr, sr_out=PYLIPSYNC_SR)
    rate = max(1, int(round(fps)))          # its hop is 16000 // fps samples: an integer fps
    hop = PYLIPSYNC_SR // rate
    if len(audio) < hop:                     # it refuses audio shorter than one hop
        audio = np.pad(audio, (0, hop - len(audio)))
    segments = analyzer.extract_phoneme_segments(audio, PYLIPSYNC_SR, fps=rate,
                                                 return_seconds=True)
    centres = np.array([(s.start + s.end) / 2 for s in segments])
    names = [p.name for p in segments[0].phonemes]
    targets = np.array([[float(p.target) for p in s.phonemes] for s in segments])
    return {name: np.interp(times, centres, targets[:, j]) for j, name in enumerate(names)}
