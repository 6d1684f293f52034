"""Phones of a real recording by forced alignment of its transcript, and the check that the
transcript is what the recording says.

Alignment uses pocketsphinx 5.1.1's en-US acoustic model and ``cmudict-en-us.dict`` (both in the
wheel; nothing is downloaded), in two passes as in the package's own alignment test: words first
(``set_align_text``, silences and noise allowed between words), then phones and states
(``set_alignment``). Phones come in 10 ms frames; silences and noise are ``sil``; the ends are
padded with silence to the length of the audio. pocketsphinx 5.1.1's second pass sometimes fails
to reach the final state on a correct transcript (its issue #339; 34 of 400 GRID clips) and
then fails on every later one until it is re-initialised; the alignment is then redone once by a
decoder without the best-path rescoring of the first pass (``bestpath=False``), which aligned
all 34. The front end's noise estimate is reset before each recording (:func:`align_audio`), so
a recording's phones do not depend on what the decoder heard before.

Transcript check
----------------
Forced alignment mostly finds a path even through words that were not said, so a transcript
that does not match the audio must be caught by a statistic. The acoustic score of the forced
alignment (the sum of its phones' scores) is compared with that of a free phone-loop decode of
the same audio (pocketsphinx ``allphone`` search with the wheel's phone language model): a
transcript that matches scores close to the free decode (often better), a wrong one much worse.
The statistic is

    gap = (aligned score − free score) / speech frames of the free decode

(pocketsphinx's integer log-score units, base 1.0001; speech frames are those the free decode
gives a phone rather than silence or noise, so leading and trailing silence does not dilute it).
A transcript is refused when ``gap < −MAX_SCORE_GAP`` or when no alignment is found at all.

The threshold is chosen on data by

    python tools/choose_alignment_threshold.py --grid-dir ../shared/grid-s1

which re-runs the measurement on a GRID speaker folder (speaker s1: 400 clips; audio decoded from
the ``.mpg`` to 16 kHz mono by FFmpeg, transcripts from the ``.align`` files without
``sil``/``sp``): each clip aligned with its own transcript, with the transcript of the clip 7
places further in sorted order within its half, and with its own first 3 words. Development set:
the clips whose ids sort into the first half; check set: the rest. The threshold is the
development set's least total error (own transcripts refused plus wrong ones accepted, as
rates, over thresholds 0.5, 1.0, … 15.0; ties to the smallest); the command prints the sweep,
both halves at the pick (refusals, acceptances, alignments not found, the own transcripts'
gaps) and the pick, and ``--check`` fails when :data:`MAX_SCORE_GAP` is not it.
"""
from __future__ import annotations

import os
import re
import threading
import warnings
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from pocketsphinx import Decoder, get_model_path

from face_model.corpus import PhoneSegment
from face_model.phones import phone_class
from groundwork.audio import resample
from groundwork.errors import CorpusError

SAMPLE_RATE = 16000  # Hz, the acoustic model's rate
FRAMES_PER_S = 100  # pocketsphinx's default frame rate
ALIGNER_NAME = "pocketsphinx-5.1.1 forced alignment"
MAX_SCORE_GAP = 4.0  # chosen by tools/choose_alignment_threshold.py (module docstring)
_LOOP_SETTINGS = {"lw": 2.0, "beam": 1e-20, "pbeam": 1e-20, "bestpath": False}
_LOCK = threading.Lock()  # the shared decoders are used by one thread at a time
_RETRY_LOCK = threading.Lock()


def aligner() -> Decoder:
    """A decoder with the wheel's default en-US model and dictionary, no language model."""
    return Decoder(lm=None, loglevel="FATAL", backtrace=False)


@lru_cache(maxsize=1)
def _retry_aligner() -> Decoder:
    """The decoder that redoes an alignment whose second pass failed (see the module docstring)."""
    return Decoder(lm=None, loglevel="FATAL", backtrace=False, bestpath=False)


def phone_loop() -> Decoder:
    """A decoder of free phone sequences: the en-US model with its phone language model."""
    model = get_model_path()
    return Decoder(hmm=os.path.join(model, "en-us", "en-us"),
                   allphone=os.path.join(model, "en-us-phone.lm.bin"),
                   samprate=SAMPLE_RATE, loglevel="FATAL", **_LOOP_SETTINGS)


@lru_cache(maxsize=1)
def _shared_decoders() -> tuple[Decoder, Decoder]:
    return aligner(), phone_loop()


def transcript_words(dec: Decoder, transcript: str, *, source: str = "") -> str:
    """The words of ``transcript`` as the aligner takes them: lower case, hyphens split,
    punctuation dropped.

    Raises
    ------
    CorpusError
        The transcript has no words, or words the dictionary does not hold.
    """
    where = f"{source}: " if source else ""
    words = re.sub(r"[^a-z0-9' ]+", " ", transcript.lower().replace("-", " ")).split()
    if not words:
        raise CorpusError(f"{where}the transcript {transcript!r} has no words; forced "
                          f"alignment needs the words spoken")
    oov = [w for w in words if dec.lookup_word(w) is None]
    if oov:
        raise CorpusError(f"{where}words not in pocketsphinx's cmudict-en-us.dict: {oov}; "
                          f"write them as dictionary words (numbers spelt out: 'two', not '2')")
    return " ".join(words)


def tidy_segments(segs, duration_s: float) -> list[PhoneSegment]:
    """Contiguous segments from 0 to ``duration_s``: gaps and the ends filled with silence,
    adjacent silences merged, times rounded to 0.1 ms.

    Parameters
    ----------
    segs : iterable of (start_s, end_s, phone)
        In time order; phones in the 44 classes.
    duration_s : float
        The length of the audio.

    Returns
    -------
    list of PhoneSegment
    """
    out: list[PhoneSegment] = []
    t = 0.0
    for s, e, p in list(segs) + [(duration_s, duration_s, "sil")]:
        if s > t + 1e-9:
            out.append(PhoneSegment(round(t, 4), round(s, 4), "sil"))
        if e > s:
            out.append(PhoneSegment(round(s, 4), round(e, 4), p))
        t = max(t, e)
    merged: list[PhoneSegment] = []
    for seg in out:
        if merged and merged[-1].phone == seg.phone == "sil":
            merged[-1] = PhoneSegment(merged[-1].start_s, seg.end_s, "sil")
        elif seg.end_s > seg.start_s:
            merged.append(seg)
    return merged


def _new_stream(dec: Decoder) -> None:
    """Reset the front end's noise estimates (``remove_noise``), which otherwise carry over from
    the audio decoded before: a recording then decodes as by a new decoder, whatever came first."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # "deprecated and unnecessary"
        dec.start_stream()


def _two_passes(dec: Decoder, buf: bytes, words: str, new_stream: bool = True):
    """The alignment of ``buf`` to ``words`` (words, then phones), or None if none was found."""
    if new_stream:
        _new_stream(dec)
    dec.set_align_text(words)
    try:
        for second_pass in (False, True):
            if second_pass:
                dec.set_alignment()
            dec.start_utt()
            dec.process_raw(buf, no_search=False, full_utt=True)
            dec.end_utt()
    except RuntimeError:  # "Failed to stop utterance processing": no path reached the end
        dec.reinit()  # else every later alignment by this decoder fails too
        return None
    return dec.get_alignment()


def _alignment(dec: Decoder, samples: np.ndarray, transcript: str, source: str,
               new_stream: bool = True):
    words = transcript_words(dec, transcript, source=source)
    buf = np.ascontiguousarray(samples, dtype="<i2").tobytes()
    al = _two_passes(dec, buf, words, new_stream)
    if al is None:
        with _RETRY_LOCK:
            al = _two_passes(_retry_aligner(), buf, words)
    return al


def _phones(al, duration_s: float) -> tuple[list[PhoneSegment], int]:
    """The alignment's phones in the 44 classes, and the sum of their acoustic scores."""
    segs, score = [], 0
    for ph in al.phones():
        name = ph.name.lower()
        name = "sil" if name.startswith(("+", "<")) else name
        segs.append((ph.start / FRAMES_PER_S, (ph.start + ph.duration) / FRAMES_PER_S,
                     phone_class(name, source="pocketsphinx alignment")))
        score += ph.score
    return tidy_segments(segs, duration_s), score


def align(dec: Decoder, samples: np.ndarray, transcript: str, *, source: str = "",
          new_stream: bool = False) -> list[PhoneSegment]:
    """The phones of int16 16 kHz mono ``samples`` spoken as ``transcript``.

    No check that the transcript matches (see :func:`align_audio`).

    Parameters
    ----------
    dec : Decoder
        From :func:`aligner`.
    samples : ndarray of int16, shape (n,)
    transcript : str
    source : str
        The recording's file, for messages.
    new_stream : bool
        Reset the decoder's noise estimate first, so that the result does not depend on what
        ``dec`` aligned before. False (the default) lets it carry over from the recordings
        ``dec`` aligned before, as when the shipped labels of ``analysis/real_speech`` were
        made (in manifest order, one decoder): they are reproduced byte for byte that way.

    Returns
    -------
    list of PhoneSegment
        Phones in the 44 classes, contiguous from 0 to the end of the audio.

    Raises
    ------
    CorpusError
        An empty transcript, words not in the dictionary, or no alignment found.
    """
    al = _alignment(dec, samples, transcript, source, new_stream)
    if al is None:
        raise CorpusError(f"{source or 'audio'}: no alignment of the transcript "
                          f"{transcript!r} to the audio was found")
    return _phones(al, len(samples) / SAMPLE_RATE)[0]


@dataclass(frozen=True)
class ForcedAlignment:
    """One recording aligned to its transcript, and how well the transcript matches.

    ``words`` are ``(start_s, end_s, word)`` of the transcript's words (no silences);
    ``aligned_score`` and ``free_score`` are the acoustic scores of the forced alignment and of
    the free phone decode, ``speech_frames`` the frames the free decode gives a phone.
    """

    phones: list
    words: list
    aligned_score: int
    free_score: int
    speech_frames: int

    @property
    def gap(self) -> float:
        """(aligned − free score) per speech frame: about 0 or above when the words match."""
        return (self.aligned_score - self.free_score) / max(self.speech_frames, 1)


def _free_decode(loop: Decoder, buf: bytes) -> tuple[int, int]:
    """Acoustic score of the best free phone sequence, and its number of speech frames."""
    _new_stream(loop)
    loop.start_utt()
    loop.process_raw(buf, no_search=False, full_utt=True)
    loop.end_utt()
    lmath = loop.get_logmath()
    score, speech = 0, 0
    for seg in loop.seg():
        score += lmath.log(seg.ascore)
        if seg.word != "SIL" and not seg.word.startswith("+"):
            speech += seg.end_frame - seg.start_frame + 1
    return score, speech


def to_pcm16(y: np.ndarray, sr: int) -> np.ndarray:
    """Float audio in [-1, 1] at ``sr`` Hz as int16 samples at 16 kHz (clipped at full scale)."""
    y16 = resample(np.asarray(y, np.float64), sr_in=int(sr), sr_out=SAMPLE_RATE)
    return np.round(np.asarray(y16, np.float64) * 32768).clip(-32768, 32767).astype(np.int16)


def force_align(y: np.ndarray, sr: int, transcript: str, *, source: str) -> ForcedAlignment:
    """Align mono float audio to its transcript and score the match (no threshold applied).

    Parameters
    ----------
    y : ndarray, shape (n,)
        Mono audio in [-1, 1].
    sr : int
        Its sample rate (Hz); resampled to 16 kHz for the aligner.
    transcript : str
        The words spoken.
    source : str
        The recording's file, for messages.

    Returns
    -------
    ForcedAlignment
        Phones contiguous from 0 to ``len(y) / sr``.

    Raises
    ------
    CorpusError
        No samples, non-finite samples, an empty transcript, words not in the dictionary, or
        no alignment found (the transcript does not match the audio).
    """
    y = np.asarray(y)
    if y.ndim != 1 or len(y) == 0 or not np.all(np.isfinite(y)):
        raise CorpusError(f"{source}: need mono audio with finite samples to align, got shape "
                          f"{y.shape}")
    samples = to_pcm16(y, sr)
    with _LOCK:
        dec, loop = _shared_decoders()
        al = _alignment(dec, samples, transcript, source)
        if al is None:
            raise CorpusError(f"{source}: the transcript {transcript!r} does not match the "
                              f"audio (no alignment of its words to the audio was found)")
        phones, aligned = _phones(al, len(y) / sr)
        words = [(w.start / FRAMES_PER_S, (w.start + w.duration) / FRAMES_PER_S,
                  re.sub(r"\(\d+\)$", "", w.name)) for w in al.words()
                 if not w.name.startswith(("<", "+", "["))]
        free, speech = _free_decode(loop, np.ascontiguousarray(samples, "<i2").tobytes())
    return ForcedAlignment(phones, words, int(aligned), int(free), int(speech))


def check_transcript_matches(result: ForcedAlignment, transcript: str, *, source: str,
                             max_gap: float = MAX_SCORE_GAP) -> None:
    """Refuse a transcript whose alignment scores far below the free phone decode.

    Raises
    ------
    CorpusError
        ``result.gap < -max_gap``; the message names the file, the transcript and the scores.
    """
    if result.gap < -max_gap:
        n = max(result.speech_frames, 1)
        raise CorpusError(
            f"{source}: the transcript {transcript!r} does not match the audio (alignment "
            f"score {result.aligned_score / n:.1f} per speech frame against "
            f"{result.free_score / n:.1f} for free phone recognition; allowed gap {max_gap:g})")


def align_audio(y: np.ndarray, sr: int, transcript: str, *, source: str,
                max_gap: float = MAX_SCORE_GAP) -> list[PhoneSegment]:
    """The phones of a recording from its transcript, refusing a transcript that does not match.

    Parameters
    ----------
    y : ndarray, shape (n,)
        Mono audio in [-1, 1].
    sr : int
        Its sample rate (Hz).
    transcript : str
        The words spoken (in ``cmudict-en-us.dict``; case and punctuation are ignored).
    source : str
        The recording's file, named in every message.
    max_gap : float
        The largest shortfall of the alignment score behind the free phone decode, per speech
        frame (see the module docstring for how :data:`MAX_SCORE_GAP` was measured).

    Returns
    -------
    list of PhoneSegment
        Phones in the 44 classes, contiguous from 0 to ``len(y) / sr``.

    Raises
    ------
    CorpusError
        An empty transcript, words not in the dictionary, bad audio, or a transcript that does
        not match the audio.
    """
    result = force_align(y, sr, transcript, source=source)
    check_transcript_matches(result, transcript, source=source, max_gap=max_gap)
    return result.phones
