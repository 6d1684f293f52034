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

The check is for transcripts a user types, which may be wrong. It also refuses right ones whose
speaker is far from the acoustic model and dictionary (US English): on GRID's British speakers
the words land where GRID's own word times put them (within about 0.1 s), but a phone or two,
mostly a diphthong, scores far below the free decode (s26's ``by``, ``five``, ``white`` heard
as ``OY``, ``now`` as ``OW``; s1's ``z`` said ``zed``): 3 of s1's 200 clips, 5 of s26's 10.

Words with their times
----------------------
A transcript that comes with the source's own word times (a GRID ``.align``) is aligned by
:func:`align_words`: each word's phones within the word's interval, silence between the words.
Each interval's audio is aligned alone (by a decoder without the best-path rescoring and with
wide beams, which on a single short word otherwise often find no path), with the cepstral mean
of the whole recording (pocketsphinx's ``batch`` mean over the recording, held fixed by ``live``
normalisation with ``Decoder.set_cmn``) rather than one of the word alone, and the noise
estimate reset for each word, so that a word's phones depend only on its audio and its
recording. An interval with fewer than three 10 ms frames per phone has no path (the model's
phones have three states); its dictionary phones then divide it evenly, and the result says
which words (on every other clip of GRID s1, 33 of 200 clips had one such word: ``at``, ``in``
or ``with`` in 40–90 ms). On those 200 clips its labels agree with :func:`force_align`'s on
0.85 of the speech frames on average (0.55–0.97); on s1's three test clips, s26 and s31, 0.89
(with each word's own batch mean instead: 0.85). There is no acoustic comparison with free
phone recognition for such a transcript (see :mod:`face_model.video_corpus` for what is
checked instead).
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
# one word's search is small: the default beams (1e-48) lost the only path of 2 of 100 words
_WORD_BEAMS = {"beam": 1e-100, "wbeam": 1e-80, "pbeam": 1e-100, "lpbeam": 1e-80,
               "lponlybeam": 1e-80}
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


def _mono_audio(y, source: str) -> np.ndarray:
    y = np.asarray(y)
    if y.ndim != 1 or len(y) == 0 or not np.all(np.isfinite(y)):
        raise CorpusError(f"{source}: need mono audio with finite samples to align, got shape "
                          f"{y.shape}")
    return y


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
    y = _mono_audio(y, source)
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


@lru_cache(maxsize=1)
def _word_aligner() -> Decoder:
    """The decoder of :func:`align_words`: no best-path rescoring, cepstral mean set by the
    caller (``live`` normalisation; the model's ``feat.params`` says ``batch``)."""
    dec = Decoder(lm=None, loglevel="FATAL", backtrace=False, bestpath=False, **_WORD_BEAMS)
    dec.config["cmn"] = "live"
    dec.reinit_feat()
    return dec


def _recording_cmn(dec: Decoder, buf: bytes, words: str) -> str:
    """The batch cepstral mean of a whole recording (no search)."""
    _new_stream(dec)
    dec.set_align_text(words)
    dec.start_utt()
    dec.process_raw(buf, no_search=True, full_utt=True)
    dec.end_utt()
    return dec.get_cmn()


def _word_phones(dec: Decoder, buf: bytes, words: str, cmn: str):
    """The phones of one word's audio, or None when no alignment was found."""
    _new_stream(dec)
    dec.set_align_text(words)
    try:
        for second_pass in (False, True):
            if second_pass:
                dec.set_alignment()
            dec.set_cmn(cmn)  # live normalisation updates the mean at each utterance's end
            dec.start_utt()
            dec.process_raw(buf, no_search=False, full_utt=True)
            dec.end_utt()
    except RuntimeError:
        _word_aligner.cache_clear()  # a fresh decoder for the next word
        return None
    return dec.get_alignment().phones()


@dataclass(frozen=True)
class WordTimedAlignment:
    """A recording's phones aligned within its words' given intervals (:func:`align_words`).

    ``phones`` are contiguous from 0 to the end of the audio; ``even`` names the words
    (``(index, word)``, 0-based) within whose interval the aligner found no path (too short:
    fewer than three 10 ms frames per phone), so that their dictionary phones divide it evenly.
    """

    phones: list
    even: tuple = ()


def _even_phones(dec: Decoder, words: str, start_s: float, end_s: float) -> list:
    """A word's dictionary phones dividing ``start_s``–``end_s`` evenly."""
    phones = [ph.lower() for w in words.split() for ph in dec.lookup_word(w).split()]
    step = (end_s - start_s) / len(phones)
    return [(start_s + k * step, start_s + (k + 1) * step, ph) for k, ph in enumerate(phones)]


def align_words(y: np.ndarray, sr: int, words, *, source: str) -> WordTimedAlignment:
    """The phones of a recording whose words' times are given: each word's phones within its
    interval (module text, "Words with their times"); no check against free phone recognition.

    Parameters
    ----------
    y : ndarray, shape (n,)
        Mono audio in [-1, 1].
    sr : int
        Its sample rate (Hz); resampled to 16 kHz for the aligner.
    words : sequence of (start_s, end_s, word)
        In time order, not overlapping, inside the audio (seconds), silences left out
        (:attr:`face_model.transcripts.Transcript.words`; checked by
        :meth:`~face_model.transcripts.Transcript.check_word_times`).
    source : str
        The recording's file, for messages.

    Returns
    -------
    WordTimedAlignment
        Phones in the 44 classes, contiguous from 0 to ``len(y) / sr``, every phone other than
        ``sil`` inside one word's interval; and the words within whose interval the aligner
        found no path, whose dictionary phones divide it evenly.

    Raises
    ------
    CorpusError
        Bad audio, no words, or a word not in the dictionary.
    """
    y = _mono_audio(y, source)
    words = [(float(s), float(e), str(w)) for s, e, w in words]
    if not words:
        raise CorpusError(f"{source}: no word times to align to")
    samples = to_pcm16(y, sr)
    segs, even = [], []
    with _LOCK:
        dec, _ = _shared_decoders()
        said = [transcript_words(dec, w, source=source) for _, _, w in words]
        cmn = _recording_cmn(dec, np.ascontiguousarray(samples, "<i2").tobytes(), " ".join(said))
        for k, ((s, e, w), text) in enumerate(zip(words, said)):
            a, b = int(round(s * SAMPLE_RATE)), min(int(round(e * SAMPLE_RATE)), len(samples))
            buf = np.ascontiguousarray(samples[a:b], "<i2").tobytes()
            phones = _word_phones(_word_aligner(), buf, text, cmn) if b > a else None
            if phones is None:
                even.append((k, w))
                segs.extend(_even_phones(dec, text, s, e))
                continue
            t0 = a / SAMPLE_RATE
            for ph in phones:
                name = ph.name.lower()
                segs.append((max(s, t0 + ph.start / FRAMES_PER_S),
                             min(e, t0 + (ph.start + ph.duration) / FRAMES_PER_S),
                             "sil" if name.startswith(("+", "<")) else name))
    segs = [(a, b, phone_class(p, source="pocketsphinx alignment")) for a, b, p in segs]
    return WordTimedAlignment(tidy_segments(segs, len(y) / sr), tuple(even))
