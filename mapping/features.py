"""Audio features of the mapping (paper §VI): 10 MFCC per 30 fps frame, and the context window.

Frame k is centred at k / fps seconds, like video frame k. The hop is exactly ``sr / fps``
samples. A rate without an integer hop is refused, and the caller resamples. HTK-style settings,
written down here and in :data:`MFCC_SETTINGS`:

* analysis window: 25 ms Hamming, centred on the frame instant (signal edge-padded by reflection);
* power spectrum → 26 triangular mel filters (HTK mel scale) from 0 Hz to the upper edge
  ``mel_fmax_hz`` (``mapping.mel_fmax_hz``; 0 means sr/2, the filterbank of every model saved
  before the setting existed);
* natural log with a floor of 1e-10 (digital silence stays finite);
* DCT-II (orthonormal); c0 dropped, c1…c_n kept; sinusoidal lifter L = 22.

Window alignment (issue 13): ``align="centre"`` (the paper's, above) reads
:func:`window_future` samples after the frame instant, 12.5 ms at 22050 Hz; ``align="right"``
delays the signal by exactly that many samples (zeros in front), so frame k's MFCC window and its
level window end at sample k·hop: a frame reads no sample after its instant, and the mapping's
look-ahead is its only latency (:func:`algorithmic_latency_s`).

Band and speaker warp (issues 37 and 12): the filterbank, its upper edge ``mel_fmax_hz`` and
the training-time VTLP warp ``vtlp_alpha`` (1: none) are :mod:`mapping.filterbank`'s. Causal
cepstral normalisation (:mod:`mapping.normalize`) is part of :class:`ContextFeatures`, before
its standardisation.
"""
from __future__ import annotations

import librosa
import numpy as np

from groundwork.audio import seconds_to_samples
from groundwork.errors import NotFittedError, ParameterError
from mapping.filterbank import N_MELS, _mel_filters, check_mel_fmax
from mapping.normalize import CepstralNormalizer, check_cmvn
from mapping.state import ArrayGroup, nest

MFCC_SETTINGS = {"window_s": 0.025, "window": "hamming", "n_mels": N_MELS, "fmin": 0.0,
                 "fmax": "mapping.mel_fmax_hz (0: sr/2)", "mel_scale": "htk",
                 "log_floor": 1e-10, "dct": "II, ortho", "c0": "dropped", "lifter": 22}


WINDOW_ALIGNS = ("centre", "right")


# The version of the feature computation: cached features (mapping.dataset) are keyed by it and
# librosa's version; raise it whenever a change here changes what audio_features returns.
FEATURES_VERSION = f"1/librosa-{librosa.__version__}"


def window_future(sr: int) -> int:
    """Samples after the frame instant that a centred frame reads: the last non-zero sample of
    its MFCC window (the ``win``-sample window centred in the ``n_fft`` frame) or the end of
    its level window (:func:`window_dbfs`), whichever is later."""
    win = seconds_to_samples(MFCC_SETTINGS["window_s"], sr)
    n_fft = 1 << (win - 1).bit_length()
    mfcc_last = (n_fft - win) // 2 + win - 1 - n_fft // 2
    return max(mfcc_last, win // 2)


def check_align(align: str) -> None:
    """``align`` is one of :data:`WINDOW_ALIGNS`, else a ParameterError."""
    if align not in WINDOW_ALIGNS:
        raise ParameterError(f"window alignment must be one of {WINDOW_ALIGNS}, got {align!r}")


def aligned(y: np.ndarray, sr: int, align: str) -> np.ndarray:
    """The signal the frames are read from.

    Parameters
    ----------
    y : ndarray, shape (n_samples,)
    sr : int
        Sample rate, in Hz.
    align : {"centre", "right"}

    Returns
    -------
    ndarray, shape (n_samples,) or (n_samples + window_future(sr),)
        ``y`` itself (centre), or ``y`` delayed by :func:`window_future` samples of silence
        (right).
    """
    check_align(align)
    if align == "centre":
        return y
    return np.concatenate([np.zeros(window_future(sr), dtype=np.asarray(y).dtype), y])


def algorithmic_latency_s(forward: int, sr: int, fps: int = 30, align: str = "centre"
                          ) -> float:
    """Seconds of audio after frame k's instant that frame k waits for: ``forward`` frames of
    context, plus the centred window's :func:`window_future` samples (none when right-aligned).

    Parameters
    ----------
    forward : int
        Frames of look-ahead context.
    sr : int
        Sample rate, in Hz.
    fps : int
        Frames per second.
    align : {"centre", "right"}

    Returns
    -------
    float
        Seconds.
    """
    check_align(align)
    return forward / fps + (window_future(sr) / sr if align == "centre" else 0.0)


def hop_samples(sr: int, fps: int = 30) -> int:
    """The exact hop in samples, or a ParameterError naming the rate."""
    if sr <= 0 or fps <= 0 or sr % fps:
        raise ParameterError(f"sample rate {sr} Hz has no integer hop at {fps} fps; resample "
                             "to e.g. 22050, 44100 or 48000 Hz")
    return sr // fps


def mfcc(y: np.ndarray, *, sr: int, fps: int = 30, n_mfcc: int = 10,
         n_frames: int | None = None, vtlp_alpha: float = 1.0, align: str = "centre",
         mel_fmax_hz: float = 0.0) -> np.ndarray:
    """MFCC per video frame.

    Parameters
    ----------
    y : ndarray, shape (n_samples,)
        Mono audio, float.
    sr : int
        Sample rate in Hz; ``sr / fps`` must be an integer.
    fps : int
        Frames per second (30 in the paper).
    n_mfcc : int
        Coefficients c1 … c_n_mfcc (10 in the paper).
    n_frames : int, optional
        Number of frames to return. The default is the frames whose centre lies inside the
        audio, ``ceil(n_samples / hop)``.
    vtlp_alpha : float
        VTLP warp factor of the mel filterbank (training-time speaker warp,
        :func:`mapping.filterbank.vtlp_warp`); 1.0 (the default, and always at inference) is
        the unwarped filterbank.
    align : {"centre", "right"}
        The analysis window centred on the frame instant, or ending at it (:func:`aligned`).
    mel_fmax_hz : float
        Upper edge of the mel filterbank, Hz; 0 (the default) is sr/2
        (:func:`mapping.filterbank.check_mel_fmax`).

    Returns
    -------
    ndarray, shape (n_frames, n_mfcc), frame-major.
    """
    y = np.asarray(y, dtype=np.float64)
    if y.ndim != 1:
        raise ParameterError(f"audio must be mono (n_samples,), got shape {y.shape}")
    if len(y) == 0 or not np.all(np.isfinite(y)):
        raise ParameterError("audio is empty or holds NaN/inf samples")
    if not 1 <= n_mfcc <= MFCC_SETTINGS["n_mels"] - 1:
        raise ParameterError(f"n_mfcc must be in 1..{MFCC_SETTINGS['n_mels'] - 1}, got {n_mfcc}")
    hop = hop_samples(sr, fps)
    fmax = check_mel_fmax(mel_fmax_hz, sr)
    n_out = int(np.ceil(len(y) / hop)) if n_frames is None else int(n_frames)
    y = aligned(y, sr, align)
    win = seconds_to_samples(MFCC_SETTINGS["window_s"], sr)
    n_fft = 1 << (win - 1).bit_length()
    power = np.abs(librosa.stft(y, n_fft=n_fft, hop_length=hop, win_length=win,
                                window=MFCC_SETTINGS["window"], center=True,
                                pad_mode="reflect")) ** 2
    mel = _mel_filters(sr, n_fft, float(vtlp_alpha), fmax)
    logmel = np.log(np.maximum(mel @ power, MFCC_SETTINGS["log_floor"]))
    cep = librosa.feature.mfcc(S=logmel, n_mfcc=n_mfcc + 1, dct_type=2, norm="ortho",
                               lifter=MFCC_SETTINGS["lifter"])[1:]
    feats = cep.T  # frame-major
    if len(feats) < n_out:  # more frames asked for than the audio has: repeat the last
        feats = np.concatenate([feats, np.repeat(feats[-1:], n_out - len(feats), axis=0)])
    return feats[:n_out].astype(np.float32)


def stack_context(features: np.ndarray, *, back: int = 3, forward: int = 3) -> np.ndarray:
    """Concatenate each frame with ``back`` previous and ``forward`` next frames (edge-padded).

    (n_frames, n_features) → (n_frames, (back + 1 + forward) · n_features), ordered oldest first.
    The paper uses 3 + 1 + 3 (about 100 ms look-ahead at 30 fps).
    """
    x = np.asarray(features)
    if x.ndim != 2:
        raise ParameterError(f"features must be (n_frames, n_features), got {x.shape}")
    if back < 0 or forward < 0:
        raise ParameterError(f"context sizes must be >= 0, got back={back}, forward={forward}")
    padded = np.pad(x, ((back, forward), (0, 0)), mode="edge")
    n = len(x)
    return np.concatenate([padded[i:i + n] for i in range(back + forward + 1)], axis=1)


class FeatureNormalizer:
    """Per-feature standardisation fitted on training data only (scikit-learn style)."""

    def fit(self, X: np.ndarray) -> "FeatureNormalizer":
        """Mean and standard deviation (1 where it is 0) of training frames ``X``, shape
        (n_frames >= 2, n_features), finite."""
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 2 or len(X) < 2 or not np.all(np.isfinite(X)):
            raise ParameterError(f"normaliser needs finite (n_frames >= 2, n_features) data, "
                                 f"got shape {X.shape}")
        self.mean_ = X.mean(0)
        self.scale_ = np.where(X.std(0) > 0, X.std(0), 1.0)
        return self

    def transform(self, X: np.ndarray) -> np.ndarray:
        """(n_frames, n_features) → standardised, float32."""
        if not hasattr(self, "mean_"):
            raise NotFittedError("FeatureNormalizer is not fitted yet: call fit() first")
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] != len(self.mean_):
            raise ParameterError(f"features must be (n_frames, {len(self.mean_)}), got {X.shape}")
        return ((X - self.mean_) / self.scale_).astype(np.float32)

    def inverse_transform(self, Z: np.ndarray) -> np.ndarray:
        """Standardised (n_frames, n_features) → the original scale, float64."""
        return np.asarray(Z, dtype=np.float64) * self.scale_ + self.mean_

    def to_arrays(self) -> tuple[dict, dict]:
        """``({"mean": (n_features,), "scale": (n_features,)}, {})`` (see :mod:`mapping.state`)."""
        if not hasattr(self, "mean_"):
            raise NotFittedError("FeatureNormalizer is not fitted yet: call fit() first")
        return {"mean": self.mean_, "scale": self.scale_}, {}

    @classmethod
    def from_arrays(cls, arrays, params: dict) -> "FeatureNormalizer":
        """The fitted normaliser of :meth:`to_arrays`."""
        g = ArrayGroup.of(arrays)
        norm = cls()
        norm.mean_ = g.take("mean", (None,))
        norm.scale_ = g.take("scale", norm.mean_.shape)
        return norm


def audio_features(y: np.ndarray, *, sr: int, fps: int = 30, n_mfcc: int = 10,
                   deltas: bool = False, n_frames: int | None = None,
                   vtlp_alpha: float = 1.0, align: str = "centre", mel_fmax_hz: float = 0.0
                   ) -> np.ndarray:
    """MFCC per frame, optionally followed by their first differences (librosa ``delta``,
    9-frame regression window, edges interpolated).

    Parameters
    ----------
    y, sr, fps, n_mfcc, n_frames, vtlp_alpha, align, mel_fmax_hz
        As for :func:`mfcc` (audio (n_samples,), Hz, frames per second, coefficients, frames,
        the training-time speaker warp (1.0: none), the window's alignment, the filterbank's
        upper edge in Hz (0: sr/2)).
    deltas : bool
        Append the first differences.

    Returns
    -------
    ndarray, shape (n_frames, n_mfcc · (1 + deltas)), float32, frame-major.
    """
    feats = mfcc(y, sr=sr, fps=fps, n_mfcc=n_mfcc, n_frames=n_frames, vtlp_alpha=vtlp_alpha,
                 align=align, mel_fmax_hz=mel_fmax_hz)
    if not deltas:
        return feats
    width = min(9, len(feats) if len(feats) % 2 else len(feats) - 1)
    if width < 3:
        d = np.zeros_like(feats)
    else:
        d = librosa.feature.delta(feats.T, width=width, order=1, mode="interp").T
    return np.concatenate([feats, d.astype(np.float32)], axis=1)


class ContextFeatures:
    """Normalise raw per-frame features (fitted on training frames only), then stack context.

    Per frame: causal cepstral normalisation (``cmvn``, :mod:`mapping.normalize`; "none" skips
    it), then the standardisation fitted on the training frames, then the context window.

    Parameters
    ----------
    back, forward : int
        Context frames before and after the current one (paper: 3 and 3).
    cmvn : {"none", "mean", "meanvar"}
        Per-utterance causal cepstral mean (and variance) normalisation.
    cmvn_warmup_frames : int
        The weight of the CMVN prior (the training frames' mean and variance), in frames.
    """

    def __init__(self, back: int = 3, forward: int = 3, cmvn: str = "none",
                 cmvn_warmup_frames: int = 30):
        self.back = back
        self.forward = forward
        self.cmvn = cmvn
        self.cmvn_warmup_frames = cmvn_warmup_frames

    def fit(self, features: list, masks: list | None = None) -> "ContextFeatures":
        """``features``: per-utterance (n_frames, n_features) arrays; ``masks``: the training
        frames of each (all frames when omitted)."""
        check_cmvn(self.cmvn, self.cmvn_warmup_frames)
        masks = masks if masks is not None else [None] * len(features)

        def rows(fs):
            return np.concatenate([f if m is None else f[m] for f, m in zip(fs, masks)])

        self.cmvn_ = None
        if self.cmvn != "none":
            self.cmvn_ = CepstralNormalizer(self.cmvn, self.cmvn_warmup_frames).fit(
                rows(features))
            features = [self.cmvn_.transform(f) for f in features]
        self.normalizer_ = FeatureNormalizer().fit(rows(features))
        return self

    def to_arrays(self) -> tuple[dict, dict]:
        """The normaliser's arrays under ``normalizer/`` (and the CMVN prior under ``cmvn/``);
        parameters ``back``, ``forward``, ``cmvn``, ``cmvn_warmup_frames``."""
        if not hasattr(self, "normalizer_"):
            raise NotFittedError("ContextFeatures is not fitted yet: call fit() first")
        arrays, _ = self.normalizer_.to_arrays()
        arrays = nest("normalizer", arrays)
        if self.cmvn_ is not None:
            arrays.update(nest("cmvn", self.cmvn_.to_arrays()[0]))
        return arrays, {"back": self.back, "forward": self.forward, "cmvn": self.cmvn,
                        "cmvn_warmup_frames": int(self.cmvn_warmup_frames)}

    @classmethod
    def from_arrays(cls, arrays, params: dict) -> "ContextFeatures":
        """The fitted context window of :meth:`to_arrays` (a model saved before CMVN existed
        has no ``cmvn`` and loads as ``"none"``)."""
        check_context(params["back"], params["forward"])
        cmvn = params.get("cmvn", "none")
        warmup = params.get("cmvn_warmup_frames", 30)
        check_cmvn(cmvn, warmup)
        g = ArrayGroup.of(arrays)
        ctx = cls(params["back"], params["forward"], cmvn, warmup)
        ctx.normalizer_ = FeatureNormalizer.from_arrays(g.group("normalizer"), {})
        ctx.cmvn_ = None if cmvn == "none" else CepstralNormalizer.from_arrays(
            g.group("cmvn"), {"mode": cmvn, "warmup_frames": warmup})
        return ctx

    @property
    def n_inputs(self) -> int:
        if not hasattr(self, "normalizer_"):
            raise NotFittedError("ContextFeatures is not fitted yet: call fit() first")
        return len(self.normalizer_.mean_) * (self.back + 1 + self.forward)

    def start_stream(self):
        """The per-utterance CMVN state for :meth:`normalize` in a stream (None: no CMVN)."""
        if not hasattr(self, "normalizer_"):
            raise NotFittedError("ContextFeatures is not fitted yet: call fit() first")
        return None if self.cmvn_ is None else self.cmvn_.start()

    def normalize(self, features: np.ndarray, stream=None) -> np.ndarray:
        """Raw frames (n_frames, n_features) → normalised, not stacked (float32).

        ``stream``: the state of :meth:`start_stream` when the frames continue a stream (pushed
        in order); by default the frames are one whole utterance from its frame 0.
        """
        if not hasattr(self, "normalizer_"):
            raise NotFittedError("ContextFeatures is not fitted yet: call fit() first")
        x = np.asarray(features)
        if self.cmvn_ is not None:
            x = (stream if stream is not None else self.cmvn_.start()).push(x)
        return self.normalizer_.transform(x)

    def transform(self, features: np.ndarray) -> np.ndarray:
        """(n_frames, n_features) raw → (n_frames, n_inputs) normalised and stacked."""
        if not hasattr(self, "normalizer_"):
            raise NotFittedError("ContextFeatures is not fitted yet: call fit() first")
        x = np.asarray(features)
        if x.ndim == 2 and not np.all(np.isfinite(x)):
            raise ParameterError("features hold NaN or inf values")
        return stack_context(self.normalize(x), back=self.back, forward=self.forward)


def window_dbfs(y: np.ndarray, centre: int, half: int) -> float:
    """Level (dBFS) of the analysis window ``y[centre − half : centre + half + 1]``.

    Parameters
    ----------
    y : ndarray, shape (n_samples,)
        Audio, full scale 1.
    centre, half : int
        The window's centre and half-width, in samples.

    Returns
    -------
    float
        dBFS (10·log10 of the mean square, floored at 1e-20); -200.0 for an empty window.
    """
    seg = np.asarray(y[max(0, centre - half):centre + half + 1], dtype=np.float64)
    return float(10 * np.log10(np.mean(seg**2) + 1e-20)) if len(seg) else -200.0


def frame_rms_dbfs(y: np.ndarray, *, sr: int, fps: int = 30, n_frames: int,
                   align: str = "centre") -> np.ndarray:
    """Level (dBFS) of each frame's 25 ms analysis window, centred at k / fps or ending there.

    Parameters
    ----------
    y : ndarray, shape (n_samples,)
    sr : int
        Sample rate, in Hz; ``sr / fps`` must be an integer.
    fps : int
        Frames per second.
    n_frames : int
    align : {"centre", "right"}
        :func:`aligned`.

    Returns
    -------
    ndarray, shape (n_frames,)
        dBFS per frame (:func:`window_dbfs`).
    """
    hop = hop_samples(sr, fps)
    y = aligned(y, sr, align)
    half = seconds_to_samples(MFCC_SETTINGS["window_s"], sr) // 2
    return np.array([window_dbfs(y, k * hop, half) for k in range(n_frames)])


def check_context(back, forward) -> None:
    """Frames of context before and after a frame: non-negative integers."""
    for name, value in (("context_back", back), ("context_forward", forward)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise ParameterError(f"{name} must be a non-negative integer, got {value!r}")


def check_seed(random_state) -> None:
    """A seed: a non-negative integer."""
    if isinstance(random_state, bool) or not isinstance(random_state, (int, np.integer)) \
            or random_state < 0:
        raise ParameterError(f"random_state must be a non-negative integer, got "
                             f"{random_state!r}")
