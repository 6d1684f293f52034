"""The mel filterbank of the audio features (:mod:`mapping.features`): its band and its VTLP warp.

:data:`N_MELS` triangular filters on the HTK mel scale, unnormalised, from 0 Hz to an upper
edge ``fmax`` (:func:`_mel_filters`, librosa's ``filters.mel`` itself when unwarped). The power
spectrum of each frame goes through them before the log and the DCT.

Band (issue 37): the upper edge is the setting ``mapping.mel_fmax_hz``
(:func:`check_mel_fmax`); 0 means sr/2, the filterbank of every model saved before the setting
existed. The edge decides which band the features read. A model trained with filters up to
sr/2 = 11,025 Hz reads, from a 16 kHz recording resampled to its rate, empty bands above 8 kHz;
with the edge at or below 8 kHz the features of a 22.05 kHz and a 16 kHz recording of the same
speech nearly agree. The edge is chosen on development data by
``python tools/choose_feature_band.py`` (its table is the evidence; no figure is typed here).

Speaker warp for training (issue 12): a warp factor α ≠ 1 warps the filterbank by vocal-tract
length perturbation (Jaitly & Hinton 2013, :func:`vtlp_warp`, :func:`warped_mel_filters`);
α = 1 is exactly the filterbank above. The warp keeps the filterbank's upper edge fixed
(:func:`vtlp_warp`'s ``f_top``) and its boundary frequency inside the band (:func:`vtlp_f_hi`),
so a warped filterbank reads no frequency above the edge either.
"""
from __future__ import annotations

import functools

import librosa
import numpy as np

from groundwork.errors import ParameterError

N_MELS = 26  # triangular filters (HTK), MFCC_SETTINGS["n_mels"] of mapping.features
MIN_MEL_FMAX_HZ = 1000.0  # below it the 26 filters narrow to single FFT bins or none
VTLP_F_HI = 4800.0  # Hz: the warp's upper boundary frequency (Jaitly & Hinton 2013)
VTLP_F_HI_RATIO = 4800.0 / 8000.0  # theirs to the top of their band (16 kHz audio: 8 kHz)
VTLP_LIMITS = (0.8, 1.2)  # warp factors accepted (the warp stays monotone)


def check_mel_fmax(mel_fmax_hz, sr: int) -> float:
    """The filterbank's upper edge in Hz for rate ``sr``: ``mel_fmax_hz`` itself, or sr/2 for 0.

    Parameters
    ----------
    mel_fmax_hz : float
        ``mapping.mel_fmax_hz``: 0 (sr/2) or a frequency in [:data:`MIN_MEL_FMAX_HZ`, sr/2], Hz.
    sr : int
        Sample rate, in Hz.

    Returns
    -------
    float
        The upper edge, Hz.

    Raises
    ------
    ParameterError
        Naming ``mapping.mel_fmax_hz``, the value and the range allowed at ``sr``.
    """
    ok = (not isinstance(mel_fmax_hz, bool) and isinstance(mel_fmax_hz, (int, float, np.number))
          and np.isfinite(mel_fmax_hz)
          and (mel_fmax_hz == 0 or MIN_MEL_FMAX_HZ <= mel_fmax_hz <= sr / 2))
    if not ok:
        raise ParameterError(f"mapping.mel_fmax_hz must be 0 (sr/2) or from {MIN_MEL_FMAX_HZ:g} "
                             f"to the Nyquist frequency {sr / 2:g} Hz of {sr} Hz audio, got "
                             f"{mel_fmax_hz!r}")
    return float(mel_fmax_hz) if mel_fmax_hz else sr / 2.0


def vtlp_f_hi(f_top: float) -> float:
    """The warp's boundary frequency for a filterbank ending at ``f_top`` Hz: :data:`VTLP_F_HI`,
    or Jaitly & Hinton's ratio (:data:`VTLP_F_HI_RATIO`) of ``f_top`` when that is lower, so the
    boundary stays inside the band (4,800 Hz for any top from 8 kHz up, as before the setting)."""
    return min(VTLP_F_HI, VTLP_F_HI_RATIO * float(f_top))


@functools.lru_cache(maxsize=64)
def _mel_filters(sr: int, n_fft: int, alpha: float = 1.0, fmax: float | None = None
                 ) -> np.ndarray:
    """The 26 HTK-scale triangular filters (unnormalised) from 0 Hz to ``fmax`` (default sr/2),
    cached per rate, FFT size, VTLP warp factor and upper edge; ``alpha == 1`` is librosa's
    filterbank itself."""
    fmax = sr / 2.0 if fmax is None else float(fmax)
    if alpha == 1.0:
        mel = librosa.filters.mel(sr=sr, n_fft=n_fft, n_mels=N_MELS,
                                  fmin=0.0, fmax=fmax, htk=True, norm=None)
    else:
        mel = warped_mel_filters(sr, n_fft, alpha, fmax)
    mel.setflags(write=False)
    return mel


def vtlp_warp(freqs: np.ndarray, alpha: float, sr: float, f_hi: float = VTLP_F_HI,
              f_top: float | None = None) -> np.ndarray:
    """Piecewise-linear VTLP warp of frequencies (Hz), Jaitly & Hinton (2013), Eq. in §2.

    f' = α·f up to f_b = f_hi·min(α, 1)/α, then the straight line from (f_b, α·f_b) to
    (f_top, f_top) (``f_top``: the filterbank's upper edge, default sr/2): 0 ↦ 0 and
    f_top ↦ f_top, monotone for α in :data:`VTLP_LIMITS` while f_hi < f_top (:func:`vtlp_f_hi`
    keeps it so); frequencies above f_top stay above it.
    """
    if not VTLP_LIMITS[0] <= alpha <= VTLP_LIMITS[1]:
        raise ParameterError(f"vtlp alpha must be in [{VTLP_LIMITS[0]}, {VTLP_LIMITS[1]}], "
                             f"got {alpha!r}")
    f = np.asarray(freqs, dtype=np.float64)
    nyq = sr / 2.0 if f_top is None else float(f_top)
    scale = f_hi * min(alpha, 1.0)
    boundary = scale / alpha
    upper = nyq - (nyq - scale) / (nyq - boundary) * (nyq - f)
    return np.where(f <= boundary, alpha * f, upper)


def warped_mel_filters(sr: int, n_fft: int, alpha: float, fmax: float | None = None
                       ) -> np.ndarray:
    """The filterbank of :func:`_mel_filters` with every FFT bin at its VTLP-warped frequency:
    filter i weights bin k by its triangle at W_α(f_k), i.e. the spectrum is warped before the
    standard filters. The warp's fixed top is the filterbank's upper edge ``fmax`` (default
    sr/2) and its boundary :func:`vtlp_f_hi` of it, so no bin above ``fmax`` is read.
    librosa's own arithmetic (``librosa.filters.mel``, HTK scale, no norm), so α = 1 gives its
    filters exactly. Shape (n_mels, 1 + n_fft // 2), float32."""
    n_mels = N_MELS
    top = sr / 2.0 if fmax is None else float(fmax)
    fftfreqs = vtlp_warp(librosa.fft_frequencies(sr=sr, n_fft=n_fft), alpha, sr,
                         f_hi=vtlp_f_hi(top), f_top=top)
    mel_f = librosa.mel_frequencies(n_mels + 2, fmin=0.0, fmax=top, htk=True)
    fdiff = np.diff(mel_f)
    ramps = np.subtract.outer(mel_f, fftfreqs)
    weights = np.zeros((n_mels, len(fftfreqs)), dtype=np.float32)
    for i in range(n_mels):
        lower = -ramps[i] / fdiff[i]
        upper = ramps[i + 2] / fdiff[i + 1]
        weights[i] = np.maximum(0, np.minimum(lower, upper))
    return weights
