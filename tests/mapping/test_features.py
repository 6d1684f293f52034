"""MFCC at 30 fps, context stacking and the normaliser."""
import numpy as np
import pytest

from groundwork.errors import NotFittedError, ParameterError
from mapping.features import FeatureNormalizer, hop_samples, mfcc, stack_context


def test_hop_is_exact_or_refused():
    assert hop_samples(22050) == 735 and hop_samples(44100) == 1470 and hop_samples(48000) == 1600
    with pytest.raises(ParameterError, match="sample rate 16000 Hz has no integer hop at 30 fps"):
        hop_samples(16000)


def test_one_frame_per_video_frame_and_centred(rng):
    sr = 22050
    y = 0.01 * rng.standard_normal(sr * 2)  # 2 s of faint noise
    assert mfcc(y, sr=sr).shape == (60, 10)
    assert mfcc(y, sr=sr, n_frames=57).shape == (57, 10)
    # A loud burst centred at frame 30 (t = 1.0 s) changes frame 30 most.
    burst = y.copy()
    k = 30 * 735
    burst[k - 100:k + 100] += np.hanning(200)
    diff = np.abs(mfcc(burst, sr=sr) - mfcc(y, sr=sr)).sum(1)
    assert diff.argmax() == 30


def test_silence_stays_finite_and_rates_agree(rng):
    assert np.all(np.isfinite(mfcc(np.zeros(22050), sr=22050)))
    t = np.arange(44100) / 44100
    tone = 0.3 * np.sin(2 * np.pi * 440 * t) + 0.01 * rng.standard_normal(len(t))
    a = mfcc(tone[::2], sr=22050)  # the same second of sound at half the rate
    b = mfcc(tone, sr=44100)
    assert a.shape == b.shape == (30, 10)  # frames depend on time, not on the sample rate
    # A steady tone gives nearly the same coefficient vector in consecutive inner frames.
    inner = b[3:-3]
    assert min(np.corrcoef(inner[i], inner[i + 1])[0, 1] for i in range(len(inner) - 1)) > 0.9


def test_bad_audio_is_refused():
    with pytest.raises(ParameterError, match="mono"):
        mfcc(np.zeros((100, 2)), sr=22050)
    with pytest.raises(ParameterError, match="NaN"):
        mfcc(np.array([0.0, np.nan]), sr=22050)
    with pytest.raises(ParameterError, match="no integer hop"):
        mfcc(np.zeros(16000), sr=16000)


def test_context_stacking_order_and_edges():
    x = np.arange(5, dtype=float)[:, None]  # frames 0..4, one feature
    s = stack_context(x, back=2, forward=1)
    assert s.shape == (5, 4)
    assert s[0].tolist() == [0, 0, 0, 1]  # edge-padded history
    assert s[2].tolist() == [0, 1, 2, 3]
    assert s[4].tolist() == [2, 3, 4, 4]  # edge-padded future
    assert np.array_equal(stack_context(x, back=0, forward=0), x)


def test_normaliser_round_trip_and_errors(rng):
    X = rng.standard_normal((200, 10)) * 5 + 3
    n = FeatureNormalizer().fit(X)
    Z = n.transform(X)
    assert np.allclose(Z.mean(0), 0, atol=1e-5) and np.allclose(Z.std(0), 1, atol=1e-4)
    assert np.allclose(n.inverse_transform(Z), X, atol=1e-4)
    with pytest.raises(NotFittedError):
        FeatureNormalizer().transform(X)
    with pytest.raises(ParameterError, match=r"features must be \(n_frames, 10\)"):
        n.transform(X[:, :3])
