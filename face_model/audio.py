"""WAV reading and writing with explicit checks, and the one seconds ↔ samples helper.

The corpus stores mono 16-bit PCM. Reading refuses what it cannot read faithfully (a truncated
file, a non-PCM encoding) with a message naming the file; stereo and other sample rates are
handled by the caller's choice (mix down / resample, or refuse).
"""
from __future__ import annotations

import wave
from math import gcd
from pathlib import Path

import numpy as np
from scipy.signal import resample_poly

from face_model.errors import CorpusError, ParameterError

_PCM_DTYPES = {1: np.uint8, 2: np.int16, 4: np.int32}


def seconds_to_samples(seconds: float, sr: int) -> int:
    """Nearest sample index of a time in seconds at sample rate ``sr`` (Hz)."""
    return int(round(seconds * sr))


def read_wav(path, *, mix_to_mono: bool = False) -> tuple[np.ndarray, int]:
    """Read a PCM WAV file.

    Parameters
    ----------
    path : path-like
    mix_to_mono : bool
        Average the channels of a multi-channel file. If False, such a file is refused.

    Returns
    -------
    y : ndarray, shape (n_samples,), float32 in [-1, 1]
    sr : int, Hz

    Raises
    ------
    CorpusError
        The file is missing, not a PCM WAV, truncated, empty, or (without ``mix_to_mono``) not mono.
    """
    path = Path(path)
    if not path.is_file():
        raise CorpusError(f"{path}: audio file not found")
    try:
        with wave.open(str(path), "rb") as w:
            n_ch, width, sr, n_declared = (
                w.getnchannels(),
                w.getsampwidth(),
                w.getframerate(),
                w.getnframes(),
            )
            raw = w.readframes(n_declared)
    except (wave.Error, EOFError) as exc:
        raise CorpusError(f"{path}: not a readable PCM WAV file ({exc}); "
                          "allowed: uncompressed PCM, 8/16/24/32-bit") from exc
    n_read = len(raw) // (width * n_ch)
    if n_read != n_declared:
        raise CorpusError(
            f"{path}: truncated WAV: header declares {n_declared} samples per channel, "
            f"the file holds {n_read}"
        )
    if n_read == 0:
        raise CorpusError(f"{path}: WAV file holds no samples")
    if n_ch != 1 and not mix_to_mono:
        raise CorpusError(f"{path}: {n_ch} channels; the corpus format requires mono audio")
    if width == 3:
        b = np.frombuffer(raw, dtype=np.uint8).reshape(-1, 3)
        ints = (b[:, 0].astype(np.int32) | (b[:, 1].astype(np.int32) << 8)
                | (b[:, 2].astype(np.int32) << 16))
        ints = np.where(ints >= 1 << 23, ints - (1 << 24), ints)
        y = ints.astype(np.float64) / (1 << 23)
    else:
        ints = np.frombuffer(raw, dtype=_PCM_DTYPES[width]).astype(np.float64)
        y = (ints - 128.0) / 128.0 if width == 1 else ints / float(1 << (8 * width - 1))
    y = y.reshape(-1, n_ch).mean(axis=1)
    return y.astype(np.float32), sr


def write_wav(path, y: np.ndarray, sr: int) -> None:
    """Write mono audio as 16-bit PCM. ``y`` is float in [-1, 1] or already int16."""
    y = np.asarray(y)
    if y.ndim != 1:
        raise ParameterError(f"write_wav: y must be 1-D mono audio, got shape {y.shape}")
    if y.dtype != np.int16:
        if not np.all(np.isfinite(y)):
            raise ParameterError(f"write_wav: audio for {path} holds NaN or inf")
        y = np.clip(np.round(y * 32767.0), -32768, 32767).astype(np.int16)
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(int(sr))
        w.writeframes(y.astype("<i2").tobytes())


def resample(y: np.ndarray, *, sr_in: int, sr_out: int) -> np.ndarray:
    """Polyphase resampling (scipy ``resample_poly``) from ``sr_in`` to ``sr_out`` Hz."""
    if sr_in <= 0 or sr_out <= 0:
        raise ParameterError(f"resample: sample rates must be positive, got {sr_in} → {sr_out}")
    if sr_in == sr_out:
        return np.asarray(y, dtype=np.float32)
    g = gcd(int(sr_in), int(sr_out))
    return resample_poly(y, sr_out // g, sr_in // g).astype(np.float32)
