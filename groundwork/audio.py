"""Audio reading (every format libsndfile reads) and writing (mono PCM16 WAV) with explicit
checks, and the one seconds ↔ samples helper.

The corpus stores mono 16-bit PCM WAV. Reading goes through soundfile (libsndfile), so WAV
(PCM 8/16/24/32-bit, float 32/64-bit), FLAC, OGG/Vorbis, MP3 and libsndfile's other formats are
read; it refuses what it cannot read faithfully (a truncated WAV, an empty or corrupt file, an
unknown format, NaN/inf samples) with a message naming the file. Stereo and other sample rates
are handled by the caller's choice (mix down / resample, or refuse).
"""
from __future__ import annotations

import wave
from math import gcd
from pathlib import Path

import numpy as np
import soundfile as sf
from scipy.signal import resample_poly

from groundwork.errors import CorpusError, ParameterError

_UNKNOWN_LENGTH = 0xFFFFFFFF  # a streamed WAV's data size: read to the end of the file


class AudioFileError(CorpusError, ParameterError):
    """An audio file that cannot be read faithfully: a corpus file (:class:`CorpusError`) or a
    file the user gave (:class:`ParameterError`), whichever the caller catches."""


def seconds_to_samples(seconds: float, sr: int) -> int:
    """The number of samples nearest to a duration (or the sample index nearest to a time).

    The project's one seconds → samples conversion: ``int(round(seconds * sr))``, Python's
    rounding (halves to even). Callers that need at least one sample wrap it in ``max(1, …)``.

    Parameters
    ----------
    seconds : float
        Duration or time, in seconds.
    sr : int or float
        Sample rate, in Hz.

    Returns
    -------
    int
        Samples.
    """
    return int(round(seconds * sr))


def _wav_data_sizes(path: Path) -> tuple[int, int, int] | None:
    """``(declared bytes, bytes in the file, bytes per frame)`` of a RIFF WAVE file's data
    chunk, or None when ``path`` is not RIFF WAVE (libsndfile reads a truncated WAV without a
    word, so the header is compared with the file here)."""
    with open(path, "rb") as f:
        head = f.read(12)
        if len(head) < 12 or head[:4] != b"RIFF" or head[8:] != b"WAVE":
            return None
        align = 0
        while len(chunk := f.read(8)) == 8:
            cid, size = chunk[:4], int.from_bytes(chunk[4:], "little")
            if cid == b"data":
                start = f.tell()
                return size, f.seek(0, 2) - start, align
            body = f.read(size + size % 2)  # chunks are padded to an even size
            if cid == b"fmt " and len(body) >= 14:
                align = int.from_bytes(body[12:14], "little")
    return None


def read_wav(path, *, mix_to_mono: bool = False) -> tuple[np.ndarray, int]:
    """Read an audio file: WAV, and every other format libsndfile reads.

    The name stays ``read_wav`` (the corpus format is WAV), but FLAC, OGG/Vorbis, MP3, float
    WAV … (``soundfile.available_formats()``) are read the same way. Integer PCM is scaled by
    1 / 2^(bits - 1) (8-bit: unsigned, offset 128), so PCM files read bit-identically to the
    ``wave``-module reader this replaced.

    Parameters
    ----------
    path : path-like
    mix_to_mono : bool
        Average the channels of a multi-channel file. If False, such a file is refused.

    Returns
    -------
    y : ndarray, shape (n_samples,), float32
        In [-1, 1] for integer PCM (WAV, FLAC); float WAV and lossy (OGG, MP3) files keep their
        decoded values, which may exceed full scale.
    sr : int, Hz

    Raises
    ------
    AudioFileError
        (both a :class:`CorpusError` and a :class:`ParameterError`) The file is missing, empty,
        in an unknown format, corrupt or truncated, holds no samples or NaN/inf samples, or
        (without ``mix_to_mono``) is not mono.
    """
    path = Path(path)
    if path.is_dir():
        raise AudioFileError(f"{path} is a folder, not an audio file")
    if not path.is_file():
        raise AudioFileError(f"{path}: audio file not found")
    if path.stat().st_size == 0:
        raise AudioFileError(f"{path}: empty file (0 bytes), not audio")
    try:
        sizes = _wav_data_sizes(path)
        with sf.SoundFile(str(path)) as f:
            n_ch, sr, n_declared = f.channels, f.samplerate, f.frames
            y = f.read(dtype="float64", always_2d=True)
    except (sf.SoundFileError, RuntimeError, OSError) as exc:
        why = (getattr(exc, "error_string", None) or str(exc)).rstrip(".")
        raise AudioFileError(f"{path}: not a readable PCM WAV, float WAV, FLAC, OGG or MP3 file, "
                             f"nor another format of libsndfile {sf.__libsndfile_version__} "
                             f"({why})") from None
    declared, present, align = sizes or (0, 0, 0)
    if align and declared != _UNKNOWN_LENGTH and declared > present:
        raise AudioFileError(f"{path}: truncated WAV: header declares {declared // align} "
                             f"samples per channel, the file holds {present // align}")
    if len(y) != n_declared:
        raise AudioFileError(f"{path}: corrupt or truncated audio: the header declares "
                             f"{n_declared} samples per channel, {len(y)} could be decoded")
    if len(y) == 0:
        raise AudioFileError(f"{path}: audio file holds no samples")
    if n_ch != 1 and not mix_to_mono:
        raise AudioFileError(f"{path}: {n_ch} channels; the corpus format requires mono audio")
    bad = ~np.isfinite(y)
    if bad.any():
        raise AudioFileError(f"{path}: {int(bad.sum())} non-finite samples (NaN/inf), the "
                             f"first at sample {int(np.argmax(bad.any(axis=1)))}")
    return y.mean(axis=1).astype(np.float32), int(sr)


def write_wav(path, y: np.ndarray, sr: int) -> None:
    """Write mono audio as a 16-bit PCM WAV file.

    Parameters
    ----------
    path : path-like
    y : ndarray, shape (n_samples,)
        Float in [-1, 1] (scaled by 32767, rounded and clipped), or already int16.
    sr : int
        Sample rate, in Hz.

    Raises
    ------
    ParameterError
        ``y`` is not 1-D, or holds NaN or inf.
    """
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
    """Polyphase resampling (scipy ``resample_poly``) from ``sr_in`` to ``sr_out`` Hz.

    Parameters
    ----------
    y : ndarray, shape (n_samples,)
    sr_in, sr_out : int
        Sample rates, in Hz.

    Returns
    -------
    ndarray, shape (about n_samples · sr_out / sr_in,), float32
        ``y`` itself (as float32) when the rates are equal.

    Raises
    ------
    ParameterError
        A sample rate that is not positive.
    """
    if sr_in <= 0 or sr_out <= 0:
        raise ParameterError(f"resample: sample rates must be positive, got {sr_in} → {sr_out}")
    if sr_in == sr_out:
        return np.asarray(y, dtype=np.float32)
    g = gcd(int(sr_in), int(sr_out))
    return resample_poly(y, sr_out // g, sr_in // g).astype(np.float32)
