"""The hama phoneme recogniser as the gate's front end (issue 29), offline and live alike.

hama 1.7.0 (Apache-2.0, a wheel with its own engine and a 4.7 MB multilingual phoneme model, no
download) reads 16 kHz audio and gives, every 20 ms, log posteriors over 191 tokens: 189 IPA
symbols (:mod:`mapping.ipa` maps each to a phone class or to none), a word boundary and the CTC
blank. Its phone *identity* is the point of it (a model trained on real voices); its *timing*
is CTC's: each phone is one spike of posterior among blanks, and the model attends over its
whole input, so a phone depends on the audio around it.

Timing from the posteriors. A spike is an output frame whose most probable token is a phone
symbol different from the frame before's (CTC's collapse). Between two spikes the labels change
:data:`BOUNDARY` of the way from the first to the second (one half: the nearer spike); each spike
labels its frames up to :data:`REACH` output frames on each side, and a frame no spike reaches
is silence. The spikes sit :data:`SPIKE_LAG` output frames (20 ms each) after the phone they
mark, so video frame k (instant k / fps) reads output frame ⌊50·k / fps⌋ + SPIKE_LAG; with
:data:`EDGE`, a frame whose instant was heard but whose spike would lie past the end of the
audio decoded reads the decode's last output frame (else silence). These settings and the
streams' resampler (:data:`RESAMPLE_QUALITY`) are chosen on the development part of the
real-speech set (``analysis/real_speech``, part ``dev``) by

    python tools/choose_hama_timing.py

which prints the sweep (viseme frame accuracy: lag × reach × boundary on whole utterances, then
resampler × edge rule on streams at 22,050 Hz with a 100-ms look-ahead), its tie rule and the
pick; ``--check`` fails when the constants here are not the pick.

Streaming (:class:`HamaStream`). The audio (at the mapping's rate) is cut into blocks of one
video frame and resampled to 16 kHz by one ``soxr.ResampleStream``, as for pocketsphinx. Every
``hop_frames`` blocks the model decodes the last ``window_s`` seconds heard (a window starting
on the 20-ms output grid, so every decode labels the same global output frames); then every
frame k with k + ``delay_frames`` ≤ blocks heard (the audio has reached its instant plus the
look-ahead, as for pocketsphinx) is decided from the latest decode, with its window of
phones k − back … k + delay_frames (past frames outside the decode keep the phones they were
decided with; future ones not yet decoded are silence). A frame is thus decided exactly
``delay_frames`` frames after its instant, from audio reaching ``delay_frames − hop_frames + 1``
to ``delay_frames`` frames past it: the look-ahead is a bound. At the end of the audio one last
decode decides the rest. Every decision reads only the blocks fed, never how the
caller cut its chunks, so offline (:func:`mapping.recogniser.recognise_windows`) and live give
the same phones for any chunking. The cost is one model run on ``window_s`` of audio per
``hop_frames`` frames (``bench/bench_streaming.py`` measures it). That is also what lets a long
recording show its progress: :func:`mapping.recogniser.recognise_windows` with ``progress``
feeds the stream a second at a time under a bar, with one line of the cost measured on the
first seconds (:func:`mapping.recogniser.feed`), and hears the same phones.
:func:`whole_utterance` is one model run on all the audio, the offline reference only: it has
no progress of its own (the passes over many recordings count recordings).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import soxr

from face_model.phones import PHONE_INDEX
from groundwork.errors import ParameterError
from mapping.block_stream import BlockStream, check_stream_args
from mapping.ipa import BLANK, check_vocabulary

HAMA_RATE = 16000  # Hz, the model's rate
OUTPUT_HOP = 320  # samples of 16 kHz audio per output frame (20 ms)
OUTPUT_FPS = HAMA_RATE // OUTPUT_HOP  # 50
# The four timing settings below are chosen on the development part of the real-speech set by
# `python tools/choose_hama_timing.py` (it prints the sweep; `--check` fails when these differ).
SPIKE_LAG = 1  # output frames from a phone to its spike
REACH = 6  # output frames a spike labels on each side at most
BOUNDARY = 0.65  # where between two spikes the labels change, as a fraction of the way
EDGE = False  # a frame whose spike lies past the decode's end reads the decode's last frame
WINDOW_S = 1.0  # seconds of audio each streaming decode reads
HOP_FRAMES = 3  # video frames between streaming decodes
MIN_DECODE_SAMPLES = OUTPUT_HOP  # a decode needs one output frame of audio
# soxr's resampler quality for the streams (chosen by tools/choose_hama_timing.py on the streams
# at 22,050 Hz and a 100-ms look-ahead): "QQ" is the quick (cubic) one, with no delay; the others
# filter better but hold some audio back, which a bounded look-ahead pays for
RESAMPLE_QUALITY = "LQ"
RESAMPLE_QUALITIES = ("QQ", "LQ", "MQ", "HQ", "VHQ")  # soxr's, quickest first
SILENCE = PHONE_INDEX["sil"]
RECOGNISER_NAME = "hama-1.7.0 phoneme CTC"

_MODEL: tuple | None = None  # (ASRModel, class index per token, blank id), loaded once


def model() -> tuple:
    """``(hama ASRModel, class index of every token (-1: none), blank id)``, loaded once per
    process; the vocabulary is checked against :mod:`mapping.ipa` (a symbol the table lacks is a
    :class:`ParameterError` naming it)."""
    global _MODEL
    if _MODEL is None:
        from hama.asr import ASRModel  # a 4.7 MB model and 0.1 s of imports: only when used
        m = ASRModel()
        classes = np.asarray(check_vocabulary(m.decoder_tokens), dtype=np.int64)
        _MODEL = (m, classes, m.decoder_tokens.index(BLANK))
    return _MODEL


def log_posteriors(x: np.ndarray) -> np.ndarray:
    """The model's log posteriors (n_out, 191) of 16 kHz mono float audio ``x`` (≥ one output
    frame of samples); output frame i covers samples [320 i, 320 (i + 1))."""
    m, _, _ = model()
    wav = np.ascontiguousarray(np.clip(x, -1.0, 1.0), dtype=np.float32).reshape(1, -1)
    if wav.shape[1] < MIN_DECODE_SAMPLES:
        raise ParameterError(f"hama needs at least {MIN_DECODE_SAMPLES} samples, got "
                             f"{wav.shape[1]}")
    lp, n = m.session.run([m._log_probs_output_name, m._out_lengths_output_name],
                          {m._waveform_input_name: wav,
                           m._waveform_lengths_input_name: np.array([wav.shape[1]], np.int64)})
    return np.asarray(lp[0][: int(np.asarray(n).reshape(-1)[0])])


def output_classes(log_probs: np.ndarray, *, reach: int = REACH,
                   boundary: float = BOUNDARY) -> np.ndarray:
    """Phone class per output frame (n_out,) from the posteriors' spikes (see the module
    docstring): between two spikes s < s', frame f belongs to s when f − s ≤ ``boundary`` ·
    (s' − s) (0.5: the nearer spike, a tie to the earlier), else to s'; a frame before the
    first spike or after the last belongs to it; each spike labels its frames up to ``reach``
    frames away, other frames are silence."""
    if not 0.0 < boundary < 1.0:
        raise ParameterError(f"boundary must be a fraction of the way between two spikes in "
                             f"(0, 1), got {boundary!r}")
    _, classes, blank = model()
    spike = assigned_spikes(log_probs, classes, blank, reach=reach, boundary=boundary)
    best = np.asarray(log_probs).argmax(axis=1)
    return np.where(spike >= 0, classes[best[np.maximum(spike, 0)]], SILENCE).astype(np.int64)


def assigned_spikes(log_probs: np.ndarray, classes: np.ndarray, blank: int, *,
                    reach: int = REACH,
                    boundary: float = BOUNDARY) -> np.ndarray:
    """The spike each output frame belongs to (n_out,) int64 (−1: none), by the rule of
    :func:`output_classes` (whose classes are those of these spikes' best tokens, silence at
    −1) on log posteriors (n_out, n_tokens) with token classes
    ``classes`` (n_tokens,) (−1: none) and the blank's id."""
    best = np.asarray(log_probs).argmax(axis=1)
    before = np.r_[-1, best[:-1]]
    spikes = np.nonzero((best != blank) & (classes[best] >= 0) & (best != before))[0]
    out = np.full(len(best), -1, dtype=np.int64)
    if not len(spikes):
        return out
    frames = np.arange(len(best))
    right = np.clip(np.searchsorted(spikes, frames), 0, len(spikes) - 1)
    left = np.clip(right - 1, 0, len(spikes) - 1)
    nearest = np.where(frames - spikes[left] <= boundary * (spikes[right] - spikes[left]),
                       spikes[left], spikes[right])
    near = np.abs(nearest - frames) <= reach
    out[near] = nearest[near]
    return out


class HamaStream(BlockStream):
    """Recognised phones per video frame of one audio stream (see the module docstring); the
    same interface as :class:`mapping.recogniser.PhoneStream`.

    Parameters
    ----------
    sample_rate : int
        The rate of the audio pushed (Hz); block k (video frame k) ends at sample
        round((k + 1) · sample_rate / fps).
    fps : int
        Video frames per second.
    delay_frames : int
        Frames of look-ahead before a frame's phone is decided (≥ 0).
    back : int
        Past frames in each decision's window (≥ 0).
    window_s : float
        Seconds of audio each decode reads (> 0).
    hop_frames : int
        Video frames between decodes (≥ 1).
    timing : Timing
        Spike lag, reach, boundary and edge rule (default: the module's constants).
    resample_quality : str
        soxr's quality for the resampling to 16 kHz, one of :data:`RESAMPLE_QUALITIES`.
    """

    def __init__(self, sample_rate: int, fps: int = 30, delay_frames: int = 3, back: int = 0,
                 *, window_s: float = WINDOW_S, hop_frames: int = HOP_FRAMES,
                 timing: "Timing | None" = None, resample_quality: str = RESAMPLE_QUALITY):
        check_stream_args(sample_rate, fps, delay_frames, back)
        if isinstance(hop_frames, bool) or not isinstance(hop_frames, (int, np.integer)) \
                or hop_frames < 1:
            raise ParameterError(f"hop_frames must be an integer ≥ 1, got {hop_frames!r}")
        if not np.isfinite(window_s) or window_s <= 0:
            raise ParameterError(f"window_s must be a positive number of seconds, got "
                                 f"{window_s!r}")
        if resample_quality not in RESAMPLE_QUALITIES:
            raise ParameterError(f"resample_quality must be one of {RESAMPLE_QUALITIES}, got "
                                 f"{resample_quality!r}")
        self.timing = Timing() if timing is None else timing
        model()  # load (and check the vocabulary) before the first block
        self._start(sample_rate, fps, delay_frames, back)
        self.hop_frames = int(hop_frames)
        self.window = int(round(window_s * HAMA_RATE))
        self._resampler = (None if self.sample_rate == HAMA_RATE else
                           soxr.ResampleStream(self.sample_rate, HAMA_RATE, 1,
                                               dtype="float32", quality=resample_quality))
        self._heard = np.zeros(0, np.float32)  # 16 kHz audio from sample self._h0 on
        self._h0 = 0
        self._fed = 0  # 16 kHz samples heard
        self.decodes = 0  # model runs so far
        self.record: list | None = None  # a list: every decode kept as (blocks heard, decode)
        self._latest = (0, np.zeros(0, np.int64))  # the latest decode (none yet: silence)

    def _feed(self, block: np.ndarray, last: bool = False) -> None:
        x = block if self._resampler is None else self._resampler.resample_chunk(block,
                                                                                 last=last)
        if len(x):
            self._heard = np.concatenate([self._heard, x.astype(np.float32)])
            self._fed += len(x)
            keep = self.window + OUTPUT_HOP  # the next window starts no earlier than this
            if len(self._heard) > 2 * keep:
                cut = ((self._fed - keep - self._h0) // OUTPUT_HOP) * OUTPUT_HOP
                if cut > 0:
                    self._heard, self._h0 = self._heard[cut:], self._h0 + cut

    def _decode(self) -> tuple[int, np.ndarray]:
        """``(first global output frame, classes per output frame)`` of the last window heard;
        early in the stream the window is filled on the left with silence (a short input makes
        the model hear phones in noise)."""
        start = max(0, self._fed - self.window)
        start = (start // OUTPUT_HOP) * OUTPUT_HOP
        x = self._heard[start - self._h0:]
        if len(x) < MIN_DECODE_SAMPLES:
            return start // OUTPUT_HOP, np.zeros(0, np.int64)
        pad = -(-max(0, self.window - len(x)) // OUTPUT_HOP) * OUTPUT_HOP
        self.decodes += 1
        decode = ((start - pad) // OUTPUT_HOP,
                  output_classes(log_posteriors(np.concatenate([np.zeros(pad, np.float32), x])),
                                 reach=self.timing.reach, boundary=self.timing.boundary))
        if self.record is not None:
            self.record.append((self._blocks, decode))
        return decode

    def _label(self, decode: tuple, j: int) -> int:
        if j < 0:
            return SILENCE
        label = read_frame(decode, j, self.fps, lag=self.timing.lag, edge=self.timing.edge)
        if label is None:  # before the window: as decided then
            return self._windows[j][self.back] if j < len(self._windows) else SILENCE
        return label

    def _decide_due(self, decode: tuple, until: int) -> list[list[int]]:
        out = []
        while len(self._windows) < until:
            k = len(self._windows)
            window = [self._label(decode, j) for j in range(k - self.back, k + self.delay + 1)]
            self._windows.append(window)
            out.append(window)
        return out

    def push_windows(self, chunk: np.ndarray) -> list[list[int]]:
        """Add mono samples (any length); return the windows of the frames newly decided."""
        out = []
        for block in self._blocks_of(chunk):
            self._feed(block)
            self._blocks += 1
            if self._blocks % self.hop_frames == 0:
                self._latest = self._decode()
            # frame k is due once k + delay blocks are in (and, with no look-ahead, once audio
            # follows its instant: the last frame exists only if it does): the latest decode
            out += self._decide_due(self._latest, min(self._blocks - self.delay + 1,
                                                      self._blocks))
        return out

    def flush_windows(self) -> list[list[int]]:
        """End of the audio: the windows of the remaining frames, from one last decode."""
        rest = self._end()
        if rest is None:
            return []
        self._feed(rest, last=True)
        if self.n_total <= len(self._windows):
            return []
        return self._decide_due(self._decode(), self.n_total)


def read_frame(decode: tuple, j: int, fps: int, *, lag: int = SPIKE_LAG,
               edge: bool = EDGE) -> int | None:
    """Video frame j's phone in a decode ``(first global output frame, classes)``: the class of
    output frame ⌊50·j / fps⌋ + ``lag``; when the frame's instant was heard but its spike
    lies past the decode's end, the class of the decode's last frame if ``edge`` (what is heard
    at the edge of the audio), else silence; silence for a frame not heard yet; None before the
    decode's window."""
    first, classes = decode
    g0 = (j * OUTPUT_FPS) // fps  # the output frame holding the frame's instant
    g = g0 + lag
    end = first + len(classes)
    if g < first:
        return None
    if g < end:
        return int(classes[g - first])
    if edge and g0 < end and len(classes):
        return int(classes[-1])
    return SILENCE


@dataclass(frozen=True)
class Timing:
    """How phones are read from the posteriors' spikes (see the module docstring): the spike
    ``lag`` and ``reach`` (output frames), the ``boundary`` between two spikes (fraction of the
    way) and the ``edge`` rule; the defaults are the module's constants."""

    lag: int = SPIKE_LAG
    reach: int = REACH
    boundary: float = BOUNDARY
    edge: bool = EDGE


@dataclass(frozen=True)
class StreamDecodes:
    """The decodes one :class:`HamaStream` made of some audio: ``(blocks heard, decode)`` every
    ``HOP_FRAMES`` blocks, the blocks of the whole audio, the end-of-audio decode and the number
    of video frames."""

    decodes: list
    blocks: int
    final: tuple
    n_frames: int


def stream_decodes(y: np.ndarray, sample_rate: int, fps: int, *, timing: Timing | None = None,
                   resample_quality: str = RESAMPLE_QUALITY) -> StreamDecodes:
    """Every decode a :class:`HamaStream` (any look-ahead: a decode reads only the audio heard)
    makes of audio ``y``."""
    stream = HamaStream(sample_rate, fps, 0, 0, timing=timing,
                        resample_quality=resample_quality)
    stream.record = []
    stream.push(y)
    decodes = list(stream.record)  # one every HOP_FRAMES blocks
    blocks = stream._blocks
    stream.flush()
    final = (stream.record[len(decodes)][1] if len(stream.record) > len(decodes)
             else stream._decode())  # the end-of-audio decode
    return StreamDecodes(decodes, blocks, final, -(-len(y) * fps // sample_rate))


def labels_from_decodes(sd: StreamDecodes, fps: int, delays, *, lag: int = SPIKE_LAG,
                        edge: bool = EDGE) -> dict:
    """``{look-ahead frames: phone per video frame}`` read from a stream's decodes ``sd`` (see
    :func:`labels_at_delays`) with the spike ``lag`` and ``edge`` rule given."""
    n = sd.n_frames
    at = np.array([b for b, _ in sd.decodes], dtype=np.int64)
    none = (0, np.zeros(0, np.int64))
    out = {}
    for d in delays:
        labels = np.full(n, SILENCE, dtype=np.int64)
        # frame k is decided at block k + d (or at the end) by the latest decode made by then
        due = max(int(d), 1)  # blocks past frame k when it is decided
        which = np.searchsorted(at, np.arange(n) + due, side="right") - 1
        for k in range(n):
            decode = (sd.final if k + due > sd.blocks else
                      sd.decodes[which[k]][1] if which[k] >= 0 else none)
            label = read_frame(decode, k, fps, lag=lag, edge=edge)
            labels[k] = SILENCE if label is None else label
        out[int(d)] = labels
    return out


def labels_at_delays(y: np.ndarray, sample_rate: int, fps: int, delays, *,
                     timing: Timing | None = None,
                     resample_quality: str = RESAMPLE_QUALITY) -> dict:
    """``{look-ahead frames: phone per video frame}``: for each look-ahead of ``delays``, the
    phones a :class:`HamaStream` with that ``delay_frames`` (and ``timing``,
    ``resample_quality``) decides on audio ``y`` — from one stream's decodes, since a decode
    reads only the audio heard, whatever the look-ahead. Frame k with look-ahead d is decided
    once k + d blocks are heard, by the latest decode (one every ``HOP_FRAMES`` blocks), or at
    the end of the audio by the last decode."""
    timing = Timing() if timing is None else timing
    sd = stream_decodes(y, sample_rate, fps, timing=timing, resample_quality=resample_quality)
    return labels_from_decodes(sd, fps, delays, lag=timing.lag, edge=timing.edge)


def whole_posteriors(y16: np.ndarray) -> tuple[np.ndarray | None, int]:
    """``(log posteriors, output frames of padding)`` of one 16 kHz utterance decoded whole,
    filled on the left with silence to ``WINDOW_S`` as a stream's first decodes are (None for
    audio shorter than one output frame)."""
    pad = -(-max(0, int(WINDOW_S * HAMA_RATE) - len(y16)) // OUTPUT_HOP) * OUTPUT_HOP
    if len(y16) < MIN_DECODE_SAMPLES:
        return None, pad // OUTPUT_HOP
    x = np.concatenate([np.zeros(pad, np.float32), np.asarray(y16, np.float32)])
    return log_posteriors(x), pad // OUTPUT_HOP


def whole_frames(log_probs: np.ndarray | None, pad: int, n_frames: int, fps: int = 30, *,
                 timing: Timing | None = None) -> np.ndarray:
    """Phone class per video frame (n_frames,) from :func:`whole_posteriors`' output, read
    with ``timing`` (default: the module's constants)."""
    timing = Timing() if timing is None else timing
    classes = (output_classes(log_probs, reach=timing.reach, boundary=timing.boundary)[pad:]
               if log_probs is not None else np.zeros(0, np.int64))
    return np.array([read_frame((0, classes), k, fps, lag=timing.lag, edge=timing.edge)
                     for k in range(n_frames)], dtype=np.int64).reshape(n_frames)


def whole_utterance(y16: np.ndarray, n_frames: int, fps: int = 30) -> np.ndarray:
    """Phone class per video frame (n_frames,) of one 16 kHz utterance decoded whole (no
    streaming: every phone sees all the audio; a clip shorter than ``WINDOW_S`` filled on the
    left with silence, as a stream's first decodes are) — the recogniser's offline
    reference."""
    return whole_frames(*whole_posteriors(y16), n_frames, fps)
