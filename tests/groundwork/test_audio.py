"""Audio input through soundfile (libsndfile): every WAV encoding, FLAC, OGG and MP3 read into
the same float32 (n_samples,) array; PCM read bit-identically to the ``wave``-module reader it
replaced; every unreadable file refused with one line naming it."""
import re
import wave
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from groundwork.audio import AudioFileError, read_wav, seconds_to_samples, write_wav
from groundwork.errors import CorpusError, ParameterError

SR = 22050


def _old_read_wav(path, *, mix_to_mono=False):
    """The reader read_wav replaced (Python's wave module, PCM only), kept as the reference."""
    with wave.open(str(path), "rb") as w:
        n_ch, width, sr, n = w.getnchannels(), w.getsampwidth(), w.getframerate(), w.getnframes()
        raw = w.readframes(n)
    if width == 3:
        b = np.frombuffer(raw, dtype=np.uint8).reshape(-1, 3)
        ints = (b[:, 0].astype(np.int32) | (b[:, 1].astype(np.int32) << 8)
                | (b[:, 2].astype(np.int32) << 16))
        ints = np.where(ints >= 1 << 23, ints - (1 << 24), ints)
        y = ints.astype(np.float64) / (1 << 23)
    else:
        ints = np.frombuffer(raw, dtype={1: np.uint8, 2: np.int16, 4: np.int32}[width])
        ints = ints.astype(np.float64)
        y = (ints - 128.0) / 128.0 if width == 1 else ints / float(1 << (8 * width - 1))
    return y.reshape(-1, n_ch).mean(axis=1).astype(np.float32), sr


@pytest.fixture
def tone(rng):
    """Half a second of a chord with a little noise, peak about 0.6, float64."""
    t = np.arange(SR // 2) / SR
    y = 0.4 * np.sin(2 * np.pi * 220 * t) + 0.3 * np.sin(2 * np.pi * 660 * t)
    return y + 0.01 * rng.standard_normal(len(t))


def _snr_db(ref, est):
    return 10 * np.log10(np.sum(ref**2) / np.sum((ref - est) ** 2))


# -- bit-identical where the old reader could read -------------------------------------------
def test_a_corpus_wav_reads_bit_identically_to_the_old_reader(small_corpus_dir):
    for path in sorted((small_corpus_dir / "audio").glob("*.wav"))[:3]:
        y, sr = read_wav(path)
        old, old_sr = _old_read_wav(path)
        assert sr == old_sr and y.dtype == np.float32 and y.shape == old.shape
        assert np.array_equal(y, old)


@pytest.mark.parametrize("subtype", ["PCM_U8", "PCM_16", "PCM_24", "PCM_32"])
@pytest.mark.parametrize("channels", [1, 2])
def test_every_pcm_width_reads_bit_identically_to_the_old_reader(tmp_path, tone, subtype,
                                                                 channels):
    path = tmp_path / "x.wav"
    data = np.stack([tone, -0.5 * tone], axis=1)[:, :channels]
    sf.write(path, data, SR, subtype=subtype)
    y, sr = read_wav(path, mix_to_mono=True)
    old, _ = _old_read_wav(path)
    assert sr == SR and y.dtype == np.float32 and y.shape == (len(tone),)
    assert np.array_equal(y, old)


def test_what_write_wav_writes_reads_back(tmp_path, tone):
    path = tmp_path / "x.wav"
    write_wav(path, tone, SR)
    assert sf.info(path).subtype == "PCM_16"  # the corpus format stays PCM16
    y, sr = read_wav(path)
    assert sr == SR and np.max(np.abs(y - tone)) <= 2 / 32767  # written × 32767, read / 32768


# -- formats the old reader refused ---------------------------------------------------------
@pytest.mark.parametrize("fmt, subtype, atol", [
    ("WAV", "FLOAT", 0.0),  # exact: the float32 samples themselves
    ("WAV", "DOUBLE", 0.0),
    ("WAV", "PCM_24", 2.0**-23),
    ("FLAC", "PCM_16", 2.0**-15),
    ("FLAC", "PCM_24", 2.0**-23),
])
def test_lossless_files_round_trip(tmp_path, tone, fmt, subtype, atol):
    x = tone.astype(np.float32)
    path = tmp_path / f"x.{fmt.lower()}"
    sf.write(path, x, SR, format=fmt, subtype=subtype)
    y, sr = read_wav(path)
    assert sr == SR and y.dtype == np.float32 and y.shape == x.shape
    assert np.max(np.abs(y - x)) <= atol


@pytest.mark.parametrize("fmt, subtype", [("OGG", "VORBIS"), ("MP3", "MPEG_LAYER_III")])
def test_lossy_files_read_close_to_what_was_written(tmp_path, tone, fmt, subtype):
    # the pinned soundfile wheel ships a libsndfile with both codecs: a missing one is a failure
    assert fmt in sf.available_formats(), f"libsndfile {sf.__libsndfile_version__} lacks {fmt}"
    path = tmp_path / f"x.{fmt.lower()}"
    sf.write(path, tone, SR, format=fmt, subtype=subtype)
    y, sr = read_wav(path)
    assert sr == SR and y.dtype == np.float32 and y.ndim == 1
    n = min(len(y), len(tone))
    lag = int(np.argmax(np.correlate(y[:n], tone[:n], "full"))) - (n - 1)  # codec delay
    assert abs(lag) < 2000 and abs(len(y) - len(tone)) < 3000
    ref = tone[max(0, -lag):n - max(0, lag)]
    est = y[max(0, lag):max(0, lag) + len(ref)]
    assert _snr_db(ref, est) > 15


def test_a_float_file_keeps_values_over_full_scale(tmp_path, tone):
    path = tmp_path / "loud.wav"
    sf.write(path, 2.5 * tone, SR, subtype="FLOAT")
    y, _ = read_wav(path)
    assert np.max(np.abs(y)) > 1.0 and np.allclose(y, 2.5 * tone, atol=1e-6)


def test_stereo_is_mixed_only_when_asked(tmp_path, tone):
    path = tmp_path / "st.flac"
    sf.write(path, np.stack([tone, np.zeros_like(tone)], axis=1), SR, subtype="PCM_24")
    with pytest.raises(CorpusError, match=r"st\.flac: 2 channels; the corpus format requires "
                                          r"mono audio"):
        read_wav(path)
    y, _ = read_wav(path, mix_to_mono=True)
    assert np.allclose(y, tone / 2, atol=2.0**-23)


# -- one clear line for every file that cannot be read --------------------------------------
def _truncated_wav(p: Path, tone) -> Path:
    write_wav(p, tone, SR)
    p.write_bytes(p.read_bytes()[:-1000])
    return p


def _truncated_flac(p: Path, tone) -> Path:
    sf.write(p, tone, SR, format="FLAC")
    p.write_bytes(p.read_bytes()[:len(p.read_bytes()) // 3])
    return p


def _nan_wav(p: Path, tone) -> Path:
    x = tone.copy()
    x[100] = np.nan
    sf.write(p, x, SR, subtype="FLOAT")
    return p


@pytest.mark.parametrize("name, make, message", [
    ("missing.wav", lambda p, t: p, r": audio file not found"),
    ("empty.wav", lambda p, t: p.write_bytes(b"") and p or p, r": empty file \(0 bytes\), "
                                                              r"not audio"),
    ("text.wav", lambda p, t: p.write_text("this is not audio") and p,
     r": not a readable PCM WAV, float WAV, FLAC, OGG or MP3 file, nor another format of "
     r"libsndfile [\d.]+ \(Format not recognised\)"),
    ("noise.ogg", lambda p, t: p.write_bytes(b"OggS" + bytes(range(256)) * 8) and p,
     r": not a readable PCM WAV.*\("),
    ("header.wav", lambda p, t: p.write_bytes(b"RIFF\x24\x00\x00\x00WAVEfmt ") and p,
     r": not a readable PCM WAV.*\("),
    ("cut.wav", _truncated_wav, r": truncated WAV: header declares 11025 samples per channel, "
                                r"the file holds 10525"),
    ("cut.flac", _truncated_flac, r": (not a readable PCM WAV.*|corrupt or truncated audio.*)"),
    ("silent.wav", lambda p, t: sf.write(p, np.zeros(0), SR) or p, r": audio file holds no "
                                                                  r"samples"),
    ("nan.wav", _nan_wav, r": 1 non-finite samples \(NaN/inf\), the first at sample 100"),
])
def test_an_unreadable_file_is_refused_with_its_name(tmp_path, tone, name, make, message):
    path = make(tmp_path / name, tone)
    with pytest.raises(AudioFileError) as info:
        read_wav(path)
    err = info.value
    assert isinstance(err, CorpusError) and isinstance(err, ParameterError)
    assert str(err).startswith(str(path)) and "\n" not in str(err)
    assert re.match(message, str(err)[len(str(path)):]), str(err)


@pytest.mark.parametrize("seconds, sr, samples", [
    (0.025, 22050, 551),  # the 25 ms MFCC window: 551.25
    (0.025, 44100, 1102),  # 1102.5: Python rounds halves to even
    (0.025, 48000, 1200),
    (0.01, 16000, 160),
    (0.0, 22050, 0),
    (1.5, 8000, 12000),
    (0.00001, 22050, 0),  # shorter than half a sample: callers wrap it in max(1, ...)
])
def test_seconds_to_samples_rounds_to_the_nearest_sample(seconds, sr, samples):
    n = seconds_to_samples(seconds, sr)
    assert n == samples and type(n) is int
    assert n == int(round(seconds * sr))  # the inline conversion it replaced, bit for bit
