"""From speech to moving markers, offline and streaming (paper §VI, Figs. 6–7).

:class:`FaceAnimator` bundles a trained :class:`~mapping.checkpoint.AudioMapping`, the Motion Units
and a neutral face: audio → MUPs → deformations (Eq. 2) → markers (n_frames, 79, 2).

Silence: the mapping itself (:class:`~mapping.checkpoint.AudioMapping`) draws frames quieter
than its ``silence_dbfs`` with a closed, neutral mouth, offline and streaming alike.

:class:`StreamingAnimator` takes audio chunks of any size and emits frame k (time k / fps) as soon
as the samples its 3-frame look-ahead needs have arrived: those of frame k + forward's analysis
window, i.e. up to (k + forward)·hop + window/2 samples. Its frames equal the offline frames for
the same audio (the same MFCC columns, the same normalisation and networks, row by row).
Causal cepstral normalisation (``cmvn``, :mod:`mapping.normalize`) keeps its running sums per
stream: each frame's features are pushed through it once, in order, as offline.
With the recogniser gate (:mod:`mapping.recogniser`) the stream also feeds a
:class:`~mapping.recogniser.PhoneStream` whose context and look-ahead are the mapping's: frame
k's window of phones is decided before frame k leaves, from the same blocks of audio as offline,
so the phones are the offline phones too. When the MLPs read the phones
(``mlp_input="phones"``) no network reads the MFCC, and the stream does not compute them (its
frames carry no features).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from face_model.alignment import unflatten
from face_model.layout import default_layout
from groundwork.audio import seconds_to_samples
from groundwork.errors import ParameterError
from mapping.checkpoint import rest_mups
from mapping.features import (MFCC_SETTINGS, algorithmic_latency_s, hop_samples, mfcc,
                               window_dbfs, window_future)
from mapping.recogniser import phone_stream, progress_bars


class FaceAnimator:
    """Audio → MUPs → markers.

    Parameters
    ----------
    mapping : AudioMapping
    units : MotionUnits
    neutral : ndarray (79, 2), optional
        The face to animate (default: the marker layout's neutral face).
    """

    def __init__(self, mapping, units, neutral: np.ndarray | None = None):
        self.mapping = mapping
        self.units = units
        self.neutral = default_layout().neutral if neutral is None else np.asarray(neutral)
        if mapping.n_utterance != units.n_utterance:
            raise ParameterError(f"the mapping estimates {mapping.n_utterance} utterance MUPs but "
                                 f"the Motion Units have {units.n_utterance}")
        if not np.allclose(rest_mups(units), mapping.rest_mups, rtol=0, atol=1e-9):
            raise ParameterError("the mapping was saved with other Motion Units (its neutral-face "
                                 "MUPs differ from these units'): load the units of its run")

    @property
    def rest_(self) -> np.ndarray:
        """Utterance MUPs of the neutral face (what silent frames get)."""
        return self.mapping.rest_mups

    @property
    def silence_dbfs(self) -> float:
        """The level (dBFS) below which a frame is silent and gets :attr:`rest_`."""
        return self.mapping.silence_dbfs

    def check_expression(self, expression: str) -> str:
        """``expression`` if the mapping estimates it, else a ParameterError naming those it
        does."""
        return self.mapping.check_expression(expression)

    def mups(self, y: np.ndarray, sr: int, expression: str = "neutral", *,
             progress: bool = False) -> np.ndarray:
        """MUPs (n_frames, A0 + Ak) of mono audio, with the silence rule applied (the mapping's
        one audio → MUP entry point, :meth:`AudioMapping.predict_audio`). ``progress``: the
        recogniser front end, when the gate has one, prints its cost line and bar on stderr
        (:func:`mapping.recogniser.feed`); the MUPs are the same either way."""
        with progress_bars(progress):
            return self.mapping.predict_audio(y, sr, expression)

    def markers(self, mups: np.ndarray, expression: str = "neutral") -> np.ndarray:
        """Markers (n_frames, 79, 2) in pixels from MUPs (Eq. 2 plus the neutral face)."""
        d = self.units.inverse_transform(mups, expression)
        return self.neutral[None] + unflatten(d)

    def animate(self, y: np.ndarray, sr: int, expression: str = "neutral", *,
                progress: bool = False):
        """``(mups, markers)`` for mono audio ``y`` at ``sr`` Hz (``progress``: see
        :meth:`mups`)."""
        mups = self.mups(y, sr, expression, progress=progress)
        return mups, self.markers(mups, expression)


@dataclass(frozen=True)
class StreamFrame:
    """One emitted frame: its index, its time k / fps (s), MUPs and markers (79, 2), and the
    frame's normalised audio features before context stacking (the row of
    :meth:`~mapping.checkpoint.AudioMapping.normalized_features` for the same audio)."""

    index: int
    time_s: float
    mups: np.ndarray
    markers: np.ndarray
    features: np.ndarray | None = None


class StreamingAnimator:
    """Chunked, causal animation with the mapping's look-ahead (see the module docstring).

    Audio must arrive at the mapping's sample rate (resample beforehand); its MFCC read the
    mapping's band (``mel_fmax_hz``), as offline. Frame models only
    (the gated MLP and the frame baselines); features without deltas.
    """

    def __init__(self, animator: FaceAnimator, expression: str = "neutral"):
        m = animator.mapping
        if m.deltas:
            raise ParameterError("streaming needs a mapping without delta features (deltas "
                                 "look 4 frames further ahead)")
        if not hasattr(m.mapper, "predict_stacked") or getattr(m.mapper, "sequence", False):
            raise ParameterError(f"the {getattr(m.mapper, 'name', '?')} mapping estimates whole "
                                 "utterances and cannot stream frame by frame")
        self.animator = animator
        self.expression = animator.check_expression(expression)
        self.sr, self.fps = m.sample_rate, m.fps
        self.hop = hop_samples(self.sr, self.fps)
        self.half = seconds_to_samples(MFCC_SETTINGS["window_s"], self.sr) // 2
        # a right-aligned window reads the stream delayed by this many samples of silence
        self.delay = window_future(self.sr) if m.window_align == "right" else 0
        ctx = m.mapper.context_
        self.back, self.forward = ctx.back, ctx.forward
        self.context = ctx
        # the phone-input MLPs read no MFCC: the stream skips them
        self._uses_mfcc = getattr(m.mapper, "mlp_input", "mfcc") == "mfcc"
        self.reset()

    def reset(self) -> None:
        self._audio = np.zeros(self.delay, np.float32)  # samples from self._a0 on
        self._a0 = 0
        self._n_samples = self.delay  # of the (delayed) signal the frames are read from
        self._feats: dict[int, np.ndarray] = {}  # normalised MFCC of the frames still needed
        self._n_feats = 0
        self._next_out = 0
        self._done = False
        self._cmvn = self.context.start_stream()  # running CMVN sums (None: no CMVN)
        mapping = self.animator.mapping
        # the recogniser gate's phones: decided ones by frame (None: the gate needs none)
        self._phones = (phone_stream(getattr(mapping.mapper, "recogniser", "pocketsphinx"),
                                     self.sr, self.fps, self.forward, self.back)
                        if mapping.needs_phones else None)
        self._heard: dict[int, list] = {}  # frame → its window of phones
        self._n_heard = 0

    def _hear(self, phones: list) -> None:
        for p in phones:
            self._heard[self._n_heard] = p
            self._n_heard += 1

    @property
    def latency_s(self) -> float:
        """Algorithmic latency: the look-ahead plus the part of the analysis window after the
        frame instant (none when the window is right-aligned)."""
        return algorithmic_latency_s(self.forward, self.sr, self.fps,
                                     self.animator.mapping.window_align)

    def _samples(self, start: int, end: int) -> np.ndarray:
        return self._audio[max(start, self._a0) - self._a0:max(end, self._a0) - self._a0]

    def _feature(self, k: int, final: bool) -> np.ndarray | None:
        # The frame's MFCC from a segment starting two hops earlier: the STFT column sees exactly
        # the samples it sees offline (the window is zero beyond ±window/2 of the frame centre,
        # and a segment from sample 0 reflects at the start as the whole signal does).
        if not self._uses_mfcc:
            return None
        col = min(k, 2)
        start = (k - col) * self.hop
        end = self._n_samples if final else max(k, 2) * self.hop + self.half + 1
        with warnings.catch_warnings():  # short segments at the very start are expected
            warnings.filterwarnings("ignore", message="n_fft=.*too large", category=UserWarning)
            f = mfcc(self._samples(start, end), sr=self.sr, fps=self.fps,
                     n_mfcc=self.animator.mapping.n_mfcc, n_frames=col + 1,
                     mel_fmax_hz=self.animator.mapping.mel_fmax_hz)[col]
        return self.context.normalize(f[None], self._cmvn)[0]

    def _emit(self, k: int, n_total: int | None) -> StreamFrame:
        last = self._n_feats - 1 if n_total is None else n_total - 1
        if self._uses_mfcc:
            rows = [self._feats[min(max(j, 0), last)] for j in range(k - self.back,
                                                                    k + self.forward + 1)]
            x = np.concatenate(rows)[None]
        else:
            x = np.zeros((1, 0), np.float32)
        mapper = self.animator.mapping.mapper
        if self._phones is None:
            mups = mapper.predict_stacked(x, self.expression)
        else:
            mups = mapper.predict_stacked(x, self.expression, np.array([self._heard.pop(k)]))
        # the kept samples start at self._a0 (earlier ones are no longer needed)
        level = window_dbfs(self._audio, k * self.hop - self._a0, self.half)
        mups = self.animator.mapping.silence_fix(mups, np.array([level]))
        markers = self.animator.markers(mups, self.expression)[0]
        return StreamFrame(k, k / self.fps, mups[0], markers, self._feats[k])

    def push(self, chunk: np.ndarray) -> list[StreamFrame]:
        """Add mono samples (any length) at the mapping's sample rate; return the frames that
        became complete (each of :class:`StreamFrame`), in order."""
        if self._done:
            raise ParameterError("the stream was flushed; call reset() to start a new one")
        chunk = np.asarray(chunk, dtype=np.float32)
        if chunk.ndim != 1:
            raise ParameterError(f"chunks must be mono (n_samples,), got shape {chunk.shape}")
        if not np.all(np.isfinite(chunk)):
            raise ParameterError("the audio chunk holds NaN or inf samples")
        self._audio = np.concatenate([self._audio, chunk])
        self._n_samples += len(chunk)
        if self._phones is not None:
            self._hear(self._phones.push_windows(chunk))
        # Frames 0 and 1 wait for frame 2's window too: a segment shorter than the FFT would be
        # padded differently from the whole signal (it costs no latency: frame 0 leaves only
        # with frame 3's features).
        while self._n_samples >= max(self._n_feats, 2) * self.hop + self.half + 1:
            self._add_feature(final=False)
        out = []
        while self._next_out + self.forward < self._n_feats:
            out.append(self._emit(self._next_out, None))
            self._next_out += 1
        self._forget()
        return out

    def _add_feature(self, final: bool) -> None:
        self._feats[self._n_feats] = self._feature(self._n_feats, final)
        self._n_feats += 1

    def _forget(self) -> None:
        """Drop samples and features no future frame needs (a live stream runs for hours)."""
        for j in [j for j in self._feats if 0 < j < self._next_out - self.back]:
            del self._feats[j]  # frame 0 stays: the start is edge-padded with it
        keep = max(0, min((self._n_feats - 2) * self.hop, self._next_out * self.hop - self.half))
        if keep > self._a0:
            self._audio = self._audio[keep - self._a0:]
            self._a0 = keep

    def flush(self) -> list[StreamFrame]:
        """End of the audio: compute the remaining frames (as offline, edge-padded)."""
        if self._done:
            return []
        self._done = True
        n_total = int(np.ceil((self._n_samples - self.delay) / self.hop))
        if self._phones is not None:
            self._hear(self._phones.flush_windows())
        if n_total == 0:
            return []
        while self._n_feats < n_total:
            self._add_feature(final=True)
        out = []
        while self._next_out < n_total:
            out.append(self._emit(self._next_out, n_total))
            self._next_out += 1
        return out
