"""Speaker and channel normalisation (issue 12): causal CMVN with a prior, one definition for the
offline path and streaming (frames equal bit for bit), saved in the model; the VTLP warp of the
mel filterbank (α = 1 is today's MFCC exactly); the config keys that switch them."""
import dataclasses

import librosa
import numpy as np
import pytest

from groundwork.errors import ParameterError
from groundwork.settings import SettingError
from mapping.config import AugmentSettings, MappingConfig
from mapping.features import MFCC_SETTINGS, ContextFeatures, mfcc
from mapping.filterbank import _mel_filters, vtlp_warp, warped_mel_filters
from mapping.normalize import CepstralNormalizer

N0 = 5


@pytest.fixture
def prior(rng):
    return rng.normal(3.0, 2.0, size=(400, 4))


@pytest.mark.parametrize("mode", ["mean", "meanvar"])
def test_cmvn_is_the_documented_running_formula(prior, rng, mode):
    norm = CepstralNormalizer(mode, N0).fit(prior)
    mu0, var0 = prior.mean(0), prior.var(0)
    x = rng.normal(-1.0, 0.5, size=(50, 4))
    y = norm.transform(x)
    for t in (0, 1, 7, 49):
        w = N0 + t + 1
        m = (N0 * mu0 + x[:t + 1].sum(0)) / w
        v = (N0 * (var0 + mu0**2) + (x[:t + 1] ** 2).sum(0)) / w - m**2
        want = x[t] - m if mode == "mean" else (x[t] - m) / np.sqrt(v)
        np.testing.assert_allclose(y[t], want, rtol=1e-10, atol=1e-12)


def test_cmvn_removes_a_channel_offset_as_the_prior_fades(prior, rng):
    """A constant cepstral offset c (a linear channel) leaves c·n0/(n0 + t + 1) after CMVN: half
    after n0 frames, and nothing once the utterance is long."""
    norm = CepstralNormalizer("mean", N0).fit(prior)
    x = rng.normal(size=(200, 4))
    c = np.array([4.0, -2.0, 1.0, 0.5])
    left = norm.transform(x + c) - norm.transform(x)
    t = np.arange(200)[:, None]
    np.testing.assert_allclose(left, c * N0 / (N0 + t + 1), atol=1e-12)


@pytest.mark.parametrize("mode", ["mean", "meanvar"])
def test_cmvn_pushed_in_any_blocks_equals_offline_bit_for_bit(prior, rng, mode):
    norm = CepstralNormalizer(mode, N0).fit(prior)
    x = rng.normal(size=(97, 4)).astype(np.float32)
    offline = norm.transform(x)
    for sizes in ([1] * 97, [3, 1, 50, 43], [97]):
        stream, parts, i = norm.start(), [], 0
        for n in sizes:
            parts.append(stream.push(x[i:i + n]))
            i += n
        assert np.array_equal(np.concatenate(parts), offline)


def test_context_features_apply_cmvn_before_the_standardisation(prior, rng):
    feats = [rng.normal(size=(60, 4)) + k for k in range(3)]
    masks = [np.arange(60) % 3 > 0 for _ in feats]
    plain = ContextFeatures(1, 1).fit(feats, masks)
    assert plain.cmvn_ is None and plain.start_stream() is None
    ctx = ContextFeatures(1, 1, "meanvar", N0).fit(feats, masks)
    train_rows = np.concatenate([f[m] for f, m in zip(feats, masks)])
    np.testing.assert_allclose(ctx.cmvn_.prior_mean_, train_rows.mean(0))
    z = np.concatenate([ctx.cmvn_.transform(f)[m] for f, m in zip(feats, masks)])
    np.testing.assert_allclose(ctx.normalizer_.mean_, z.mean(0))
    np.testing.assert_array_equal(ctx.normalize(feats[1]),
                                  ctx.normalizer_.transform(ctx.cmvn_.transform(feats[1])))
    assert ctx.transform(feats[1]).shape == (60, 12)


def test_context_features_keep_cmvn_in_their_arrays(prior, rng):
    feats = [rng.normal(size=(40, 4)) for _ in range(2)]
    ctx = ContextFeatures(2, 1, "meanvar", 9).fit(feats)
    arrays, params = ctx.to_arrays()
    assert params == {"back": 2, "forward": 1, "cmvn": "meanvar", "cmvn_warmup_frames": 9}
    assert {"cmvn/mean", "cmvn/var"} <= set(arrays)
    back = ContextFeatures.from_arrays(arrays, params)
    np.testing.assert_array_equal(back.transform(feats[0]), ctx.transform(feats[0]))
    # a context window saved before CMVN existed: no cmvn key, no prior → "none"
    old_arrays, old_params = ContextFeatures(2, 1).fit(feats).to_arrays()
    old_params = {"back": 2, "forward": 1}
    assert ContextFeatures.from_arrays(old_arrays, old_params).cmvn == "none"
    with pytest.raises(ParameterError, match="cmvn must be one of none, mean, meanvar"):
        ContextFeatures.from_arrays(arrays, {**params, "cmvn": "median"})
    with pytest.raises(ParameterError, match="cmvn/var"):
        ContextFeatures.from_arrays({k: v for k, v in arrays.items() if k != "cmvn/var"}, params)


def test_cmvn_errors(prior):
    with pytest.raises(ParameterError, match="cmvn_warmup_frames must be an integer >= 1"):
        CepstralNormalizer("mean", 0).fit(prior)
    with pytest.raises(ParameterError, match="features must be \\(n_frames, 4\\)"):
        CepstralNormalizer("mean", 3).fit(prior).transform(np.zeros((3, 5)))
    with pytest.raises(ParameterError, match="cmvn must be one of"):
        ContextFeatures(3, 3, "yes").fit([prior])


# -- VTLP ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("sr", [22050, 48000])
def test_vtlp_alpha_1_is_todays_filterbank_and_mfcc(sr, rng):
    n_fft = 1 << (int(round(MFCC_SETTINGS["window_s"] * sr)) - 1).bit_length()
    ref = librosa.filters.mel(sr=sr, n_fft=n_fft, n_mels=26, fmin=0.0, fmax=sr / 2, htk=True,
                              norm=None)
    assert np.array_equal(warped_mel_filters(sr, n_fft, 1.0), ref)  # the warp code at α = 1
    assert np.array_equal(_mel_filters(sr, n_fft, 1.0), ref)
    y = rng.normal(scale=0.1, size=sr // 2)
    assert np.array_equal(mfcc(y, sr=sr, vtlp_alpha=1.0), mfcc(y, sr=sr))
    warped = mfcc(y, sr=sr, vtlp_alpha=0.9)
    assert warped.shape == mfcc(y, sr=sr).shape and not np.allclose(warped, mfcc(y, sr=sr))


def test_vtlp_warp_is_piecewise_linear_and_keeps_the_band_edges():
    sr = 22050
    f = np.linspace(0, sr / 2, 1001)
    for alpha in (0.9, 1.1):
        w = vtlp_warp(f, alpha, sr)
        assert w[0] == 0 and w[-1] == pytest.approx(sr / 2) and np.all(np.diff(w) > 0)
        low = f <= 4800 * min(alpha, 1) / alpha
        np.testing.assert_allclose(w[low], alpha * f[low])
    with pytest.raises(ParameterError, match="vtlp alpha must be in \\[0.8, 1.2\\], got 1.5"):
        vtlp_warp(f, 1.5, sr)


# -- config -------------------------------------------------------------------------------------
def test_the_config_names_are_the_modules_names():
    from mapping.augment import NOISE_BETA
    from mapping.config import CMVN_NAMES, NOISE_COLOURS
    from mapping.normalize import CMVN_MODES

    assert CMVN_NAMES == CMVN_MODES and NOISE_COLOURS == tuple(NOISE_BETA)


def test_the_robustness_keys_are_off_by_default():
    m = MappingConfig()
    assert (m.cmvn, m.vtlp_range, m.augment.copies) == ("none", (1.0, 1.0), 0)
    assert m.augment == AugmentSettings()


@pytest.mark.parametrize("change, match", [
    (dict(cmvn="median"), "cmvn is 'median'; allowed: none, mean, meanvar"),
    (dict(cmvn_warmup_frames=0), "cmvn_warmup_frames is 0"),
    (dict(vtlp_range=(1.1, 0.9)), "vtlp_range is \\[1.1, 0.9\\]"),
    (dict(vtlp_range=(0.5, 1.0)), "vtlp_range"),
])
def test_bad_robustness_keys_are_refused(change, match):
    with pytest.raises(SettingError, match=match):
        dataclasses.replace(MappingConfig(), **change)


@pytest.mark.parametrize("change, match", [
    (dict(copies=-1), "copies is -1"),
    (dict(noise_prob=1.5), "noise_prob is 1.5"),
    (dict(snr_db=()), "snr_db"),
    (dict(noise_colours=("grey",)), "noise_colours"),
    (dict(tempo_range=(1.2, 0.8)), "tempo_range"),
])
def test_bad_augment_settings_are_refused(change, match):
    with pytest.raises(SettingError, match=match):
        AugmentSettings(**change)
