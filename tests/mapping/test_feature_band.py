"""The mel filterbank's upper edge (``mapping.mel_fmax_hz``, issue 37): 0 is exactly the old
sr/2 filterbank; a lower edge makes a recording and its 16 kHz copy read nearly the same MFCC;
the warp never reads above the edge; a bad edge is refused naming the setting; a saved model
keeps its edge (one saved before the setting loads as sr/2); the band sweep's rule picks as
stated."""
from __future__ import annotations

import importlib.util
import json
import pathlib

import librosa
import numpy as np
import pytest

from groundwork import modelfile
from groundwork.audio import resample
from groundwork.errors import ParameterError
from mapping import Baseline, build_dataset, split_masks
from mapping.animator import FaceAnimator, StreamingAnimator
from mapping.checkpoint import AudioMapping, rest_mups
from mapping.config import AugmentSettings, MappingConfig, TrainSettings
from mapping.dataset import UttData, training_copies, utterance_key
from mapping.features import MFCC_SETTINGS, audio_features, mfcc
from mapping.filterbank import (VTLP_F_HI, _mel_filters, check_mel_fmax, vtlp_f_hi, vtlp_warp,
                                warped_mel_filters)

SR = 22050
N_FFT = 1024  # 25 ms at 22,050 Hz (551 samples) in the next power of two
TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "choose_feature_band.py"


def speech_like(rng, seconds: float = 2.0) -> np.ndarray:
    """A 150 Hz harmonic series up to sr/2 plus white noise: energy in every band."""
    t = np.arange(int(seconds * SR)) / SR
    y = sum(np.sin(2 * np.pi * 150 * k * t) / k for k in range(1, 70))
    return 0.1 * y + 0.05 * rng.standard_normal(len(t))


def through_16k(y: np.ndarray) -> np.ndarray:
    """``y`` low-passed as a 16 kHz recording is: resampled to 16 kHz and back."""
    return resample(resample(y, sr_in=SR, sr_out=16000), sr_in=16000, sr_out=SR)[:len(y)]


def old_warped_filters(alpha: float) -> np.ndarray:
    """The warped filterbank as written before the setting (top sr/2, boundary 4,800 Hz)."""
    n_mels = MFCC_SETTINGS["n_mels"]
    f = librosa.fft_frequencies(sr=SR, n_fft=N_FFT)
    nyq, scale = SR / 2, VTLP_F_HI * min(alpha, 1.0)
    boundary = scale / alpha
    warped = np.where(f <= boundary, alpha * f,
                      nyq - (nyq - scale) / (nyq - boundary) * (nyq - f))
    mel_f = librosa.mel_frequencies(n_mels + 2, fmin=0.0, fmax=nyq, htk=True)
    ramps = np.subtract.outer(mel_f, warped)
    fdiff = np.diff(mel_f)
    out = np.zeros((n_mels, len(f)), np.float32)
    for i in range(n_mels):
        out[i] = np.maximum(0, np.minimum(-ramps[i] / fdiff[i], ramps[i + 2] / fdiff[i + 1]))
    return out


def test_the_default_edge_is_the_old_filterbank_and_features_exactly(rng):
    y = speech_like(rng)
    old = librosa.filters.mel(sr=SR, n_fft=N_FFT, n_mels=26, fmin=0.0, fmax=SR / 2, htk=True,
                              norm=None)
    assert np.array_equal(_mel_filters(SR, N_FFT, 1.0, SR / 2), old)
    for alpha in (0.9, 1.1):
        assert np.array_equal(warped_mel_filters(SR, N_FFT, alpha), old_warped_filters(alpha))
        assert np.array_equal(warped_mel_filters(SR, N_FFT, alpha, SR / 2),
                              old_warped_filters(alpha))
    base = mfcc(y, sr=SR)
    assert np.array_equal(mfcc(y, sr=SR, mel_fmax_hz=0.0), base)
    assert np.array_equal(mfcc(y, sr=SR, mel_fmax_hz=SR / 2), base)
    assert np.array_equal(audio_features(y, sr=SR, deltas=True, mel_fmax_hz=0),
                          audio_features(y, sr=SR, deltas=True))
    assert not np.allclose(mfcc(y, sr=SR, mel_fmax_hz=7600.0), base)


def test_below_8khz_a_recording_and_its_16khz_copy_read_nearly_the_same_mfcc(rng):
    # Measured (this signal, seed of the rng fixture): RMS difference of the MFCC 23.7 with the
    # edge at sr/2, 1.04 at 8,000 Hz (the resampler's transition band), 0.30 at 7,600 Hz,
    # 0.028 at 4,000 Hz; on GRID s1 speech 11–13 at sr/2 and 0.27–0.32 at 7,600 Hz.
    y = speech_like(rng)
    low = through_16k(y)

    def rms_diff(edge):
        return float(np.sqrt(np.mean((mfcc(y, sr=SR, mel_fmax_hz=edge)
                                      - mfcc(low, sr=SR, mel_fmax_hz=edge)) ** 2)))

    full, at_7600, at_4000 = rms_diff(0.0), rms_diff(7600.0), rms_diff(4000.0)
    assert at_7600 < full / 20
    assert at_4000 < at_7600  # further from the resampler's edge, closer still
    assert full > 5.0  # the problem is real at sr/2: the empty band dominates


@pytest.mark.parametrize("edge", [7600.0, 4000.0])
@pytest.mark.parametrize("alpha", [0.8, 0.9, 1.1, 1.2])
def test_the_warp_reads_nothing_above_the_edge_and_keeps_it_fixed(edge, alpha):
    f = librosa.fft_frequencies(sr=SR, n_fft=N_FFT)
    w = warped_mel_filters(SR, N_FFT, alpha, edge)
    assert not w[:, f > edge].any()
    assert w.sum(1).min() > 0  # no empty filter
    warped = vtlp_warp(f, alpha, SR, f_hi=vtlp_f_hi(edge), f_top=edge)
    assert np.all(np.diff(warped) > 0)  # monotone
    assert vtlp_warp(np.array([0.0, edge]), alpha, SR, f_hi=vtlp_f_hi(edge),
                     f_top=edge) == pytest.approx([0.0, edge])
    assert vtlp_f_hi(edge) < edge


def test_the_warp_boundary_is_jaitly_and_hintons_above_8khz_and_their_ratio_below():
    assert vtlp_f_hi(SR / 2) == vtlp_f_hi(8000.0) == VTLP_F_HI
    assert vtlp_f_hi(7600.0) == pytest.approx(4560.0)
    assert vtlp_f_hi(4000.0) == pytest.approx(2400.0)


@pytest.mark.parametrize("bad", [-1.0, 11025.5, 24000.0, 500.0, float("nan"), "7600", True])
def test_a_bad_edge_is_refused_naming_the_setting(bad, rng):
    with pytest.raises(ParameterError, match=r"mapping\.mel_fmax_hz must be 0 \(sr/2\) or from "
                                             r"1000 to the Nyquist frequency 11025 Hz of 22050 "
                                             r"Hz audio, got"):
        check_mel_fmax(bad, SR)
    if isinstance(bad, float) and bad == bad:
        with pytest.raises(ParameterError, match=r"mapping\.mel_fmax_hz"):
            mfcc(speech_like(rng, 0.2), sr=SR, mel_fmax_hz=bad)


def test_the_config_refuses_a_negative_edge():
    with pytest.raises(ParameterError, match=r"mel_fmax_hz.*-5"):
        MappingConfig(mel_fmax_hz=-5.0)
    assert MappingConfig(mel_fmax_hz=7600.0).mel_fmax_hz == 7600.0


def test_an_edge_above_the_models_nyquist_is_refused_by_the_model():
    with pytest.raises(ParameterError, match=r"mapping\.mel_fmax_hz .* 8000 Hz of 16000 Hz"):
        AudioMapping(None, sample_rate=16000, n_utterance=3, rest_mups=np.zeros(3),
                     mel_fmax_hz=8001.0)


@pytest.fixture(scope="module")
def linear_mapping():
    """A linear baseline on the MFCC of a few seeded signals (a model, not a good one)."""
    rng = np.random.default_rng(3)
    feats = [audio_features(speech_like(rng, 0.5), sr=SR, mel_fmax_hz=7600.0) for _ in range(4)]
    data = [UttData(f"u{i}", "s", "neutral", f"t{i}", f, rng.normal(size=(len(f), 3)),
                    np.zeros(len(f), int)) for i, f in enumerate(feats)]
    masks = [np.ones(d.n_frames, bool) for d in data]
    mapper = Baseline("linear", train=TrainSettings(max_epochs=5, patience=2)).fit(data, masks)
    return AudioMapping(mapper, sample_rate=SR, n_utterance=3, rest_mups=np.zeros(3),
                        mel_fmax_hz=7600.0)


def test_a_saved_model_keeps_its_edge_and_its_features(linear_mapping, tmp_path, rng):
    y = speech_like(rng, 1.0).astype(np.float32)  # the model reads float32 audio
    path = linear_mapping.save(tmp_path / "m.tfmap")
    back = AudioMapping.load(path)
    assert back.mel_fmax_hz == 7600.0
    np.testing.assert_array_equal(back.features(y, SR),
                                  audio_features(y, sr=SR, mel_fmax_hz=7600.0))
    low = resample(y, sr_in=SR, sr_out=16000)
    assert back.predict_audio(low, 16000).tobytes() == linear_mapping.predict_audio(
        low, 16000).tobytes()


def test_a_model_saved_before_the_setting_existed_loads_as_sr_over_2(linear_mapping, tmp_path,
                                                                      rng):
    path = linear_mapping.save(tmp_path / "m.tfmap")
    with np.load(path, allow_pickle=False) as z:
        members = {name: z[name] for name in z.files}
    header = json.loads(str(members.pop("metadata")))  # as format /3 wrote it
    del header["mel_fmax_hz"], header["kind"], header["version"]
    header.update(format="talkingface.mapping/3", sha256=modelfile.checksum(members))
    with open(path, "wb") as f:
        np.savez(f, allow_pickle=False, header=np.array(json.dumps(header)), **members)
    old = AudioMapping.load(path)
    assert old.mel_fmax_hz == 0.0
    y = speech_like(rng, 0.5).astype(np.float32)
    np.testing.assert_array_equal(old.features(y, SR), audio_features(y, sr=SR))


def test_the_dataset_and_its_training_copies_read_the_edge(small_corpus):
    from face_model.motion_units import fit_corpus_units

    units, _ = fit_corpus_units(small_corpus)
    data = build_dataset(small_corpus, units, mel_fmax_hz=7600.0)
    u, d = small_corpus.utterances[0], data[0]
    assert d.mel_fmax_hz == 7600.0
    np.testing.assert_array_equal(d.features, audio_features(
        u.audio, sr=u.sample_rate, n_frames=u.n_frames, mel_fmax_hz=7600.0))
    masks = split_masks(data, "utterance", seed=0)
    copies, _ = training_copies(data, masks, settings=AugmentSettings(),
                                vtlp_range=(1.0, 1.0001), seed=2)
    first = next(i for i, m in enumerate(masks) if m.any())
    alpha = float(np.random.default_rng([2, utterance_key(data[first].utt_id), 0]).uniform(
        1.0, 1.0001))
    np.testing.assert_array_equal(copies[0].features, audio_features(
        data[first].audio, sr=data[first].sample_rate, n_frames=data[first].n_frames,
        vtlp_alpha=alpha, mel_fmax_hz=7600.0))
    with pytest.raises(ParameterError, match=r"mapping\.mel_fmax_hz"):
        build_dataset(small_corpus, units, mel_fmax_hz=20000.0)


def test_streaming_frames_read_the_models_band(small_corpus):
    from face_model.motion_units import fit_corpus_units

    units, _ = fit_corpus_units(small_corpus)
    data = build_dataset(small_corpus, units, mel_fmax_hz=7600.0)
    masks = [np.ones(d.n_frames, bool) for d in data]
    mapper = Baseline("linear", train=TrainSettings(max_epochs=5, patience=2)).fit(data, masks)
    u = small_corpus.utterances[1]
    mapping = AudioMapping(mapper, sample_rate=u.sample_rate, n_utterance=units.n_utterance,
                           rest_mups=rest_mups(units), mel_fmax_hz=7600.0)
    s = StreamingAnimator(FaceAnimator(mapping, units))
    frames = [f for i in range(0, len(u.audio), 1000) for f in s.push(u.audio[i:i + 1000])]
    frames += s.flush()
    np.testing.assert_allclose(np.stack([f.features for f in frames]),
                               mapping.normalized_features(u.audio, u.sample_rate),
                               rtol=0, atol=1e-5)


def _tool():
    spec = importlib.util.spec_from_file_location("choose_feature_band", TOOL)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_band_rule_picks_the_best_mean_among_small_16khz_drops():
    tool = _tool()
    table = {0.0: {22050: 0.83, 16000: 0.70, 8000: 0.44},  # best at 22.05 kHz, drops 0.13
             8000.0: {22050: 0.82, 16000: 0.79, 8000: 0.50},  # drops 0.03: out
             7600.0: {22050: 0.81, 16000: 0.80, 8000: 0.52},
             4000.0: {22050: 0.78, 16000: 0.78, 8000: 0.70}}  # best mean (0.753)
    assert tool.choose(table) == 4000.0
    table[4000.0] = {22050: 0.78, 16000: 0.78, 8000: 0.50}  # mean 0.687 < 7600's 0.710
    assert tool.choose(table) == 7600.0
    # equal means to three decimals: the higher edge (sr/2 counts as 11,025 Hz)
    tie = {0.0: {22050: 0.80, 16000: 0.79, 8000: 0.60},
           4000.0: {22050: 0.7902, 16000: 0.79, 8000: 0.6098}}
    assert tool.choose(tie) == 0.0
    # none qualifies: the smallest drop
    none = {0.0: {22050: 0.83, 16000: 0.70, 8000: 0.44},
            7600.0: {22050: 0.83, 16000: 0.78, 8000: 0.50}}
    assert tool.choose(none) == 7600.0


def test_the_development_sentences_leave_the_pipelines_test_sentences_untouched(small_corpus):
    tool = _tool()
    fit, dev, test = tool.development_sets(small_corpus, run_seed=2002, seed=0)
    texts = [{u.text for u in part} for part in (fit, dev, test)]
    assert all(texts) and not (texts[0] & texts[1]) and not ((texts[0] | texts[1]) & texts[2])
    assert len(fit) + len(dev) + len(test) == len(small_corpus.utterances)
    masks = split_masks(small_corpus.utterances, "utterance", train_fraction=0.8,
                        seed=2002 + 17)
    assert {u.utt_id for u, m in zip(small_corpus.utterances, masks) if not m.any()} == {
        u.utt_id for u in test}
