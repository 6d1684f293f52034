"""Training-time augmentation (issue 12): every augmentation keeps the length and the rate (tempo
returns the scale it applied), is reproducible from its seed and acts at the configured
strength; the training copies are drawn per (seed, utterance, copy), never of test utterances,
and a tempo change keeps the copy's features and targets aligned."""
import dataclasses

import numpy as np
import pytest
import scipy.signal as sps

from mapping import augment as A
from mapping.config import AugmentSettings
from mapping.dataset import UttData, copies_per_utterance, training_copies, utterance_key
from mapping.features import audio_features, frame_rms_dbfs

SR = 22050
OFF = AugmentSettings(tempo_prob=0, pitch_prob=0, reverb_prob=0, noise_prob=0, babble_prob=0,
                      telephone_prob=0, gain_prob=0, clip_prob=0)


def voice(seed: int, seconds: float = 1.0, f0: float = 130.0) -> np.ndarray:
    """A crude voiced signal: a pulse train through two resonances, 4 Hz syllables."""
    rng = np.random.default_rng(seed)
    n = int(SR * seconds)
    t = np.arange(n) / SR
    src = (np.diff(np.floor(np.cumsum(np.full(n, f0 * (1 + 0.05 * rng.random()))) / SR),
                   prepend=0) > 0).astype(float)
    y = src
    for fc in (700.0, 1200.0 + 400 * rng.random()):
        b, a = sps.iirpeak(fc, Q=8, fs=SR)
        y = sps.lfilter(b, a, y)
    y *= 0.5 * (1 - np.cos(2 * np.pi * 4 * t))
    return (0.3 * y / np.abs(y).max()).astype(np.float32)


def snr_db(clean, noisy) -> float:
    clean = clean.astype(np.float64)
    return 10 * np.log10(np.mean(clean**2) / np.mean((noisy - clean) ** 2))


def peak_hz(y) -> float:
    spec = np.abs(np.fft.rfft(y * np.hanning(len(y))))
    return float(np.fft.rfftfreq(len(y), 1 / SR)[np.argmax(spec)])


def tone(hz: float, seconds: float = 1.0) -> np.ndarray:
    return (0.5 * np.sin(2 * np.pi * hz * np.arange(int(SR * seconds)) / SR)).astype(np.float32)


RIR = A.image_method_rir([5, 4, 3], [2.0, 3.1, 1.6], [3.5, 1.2, 1.2], rt60=0.3, sr=SR)
# name → f(y, rng): each augmentation at full strength
AUGMENTATIONS = {
    "white_noise": lambda y, g: A.mix_at_snr(y, A.coloured_noise(len(y), g), 10.0),
    "pink_noise": lambda y, g: A.mix_at_snr(y, A.coloured_noise(len(y), g, beta=1.0), 10.0),
    "babble": lambda y, g: A.mix_at_snr(y, A.babble([voice(7), voice(8), voice(9, 0.3)],
                                                    len(y), g), 10.0),
    "reverb": lambda y, g: A.reverberate(y, A.random_room_rir(g, sr=SR, rt60_range=(0.2, 0.4))),
    "telephone": lambda y, g: A.telephone_band(y, sr=SR),
    "gain_clip": lambda y, g: A.gain_clip(y, float(g.uniform(3, 12))),
    "clip": lambda y, g: A.clip_fraction(y, 0.05),
    "pitch": lambda y, g: A.pitch_shift(y, sr=SR, semitones=float(g.uniform(1, 2))),
}


@pytest.mark.parametrize("name", sorted(AUGMENTATIONS))
def test_each_augmentation_keeps_length_and_is_reproducible(name):
    y, f = voice(0), AUGMENTATIONS[name]
    a = f(y, np.random.default_rng(1))
    assert a.shape == y.shape and a.dtype == y.dtype and np.all(np.isfinite(a))
    assert np.array_equal(a, f(y, np.random.default_rng(1)))  # same seed: identical
    assert not np.allclose(a, y)  # it did something
    if name in ("white_noise", "pink_noise", "babble", "reverb", "gain_clip", "pitch"):
        assert not np.array_equal(a, f(y, np.random.default_rng(2)))  # another seed: another


def test_the_full_pipeline_is_reproducible_and_seed_dependent():
    on = AugmentSettings(copies=1, tempo_prob=1, pitch_prob=1, reverb_prob=1, noise_prob=1,
                         babble_prob=1, telephone_prob=1, gain_prob=1, clip_prob=1)
    y, others = voice(0), [voice(3), voice(4)]

    def run(seed):
        return A.augment(y, sr=SR, settings=on, rng=np.random.default_rng([seed, 5, 0]),
                         others=others)

    (a, sa, pa), (b, sb, pb), (c, _, _) = run(1), run(1), run(2)
    assert np.array_equal(a, b) and sa == sb and pa == pb
    assert set(pa) == {"tempo_rate", "pitch_semitones", "reverb", "noise", "babble_snr_db",
                       "telephone", "gain_db", "clip_fraction"}
    assert sa == len(a) / len(y) and sa == pytest.approx(1 / pa["tempo_rate"], rel=1e-3)
    assert len(a) != len(c) or not np.array_equal(a, c)
    # every stage off: the audio comes back unchanged
    same, scale, params = A.augment(y, sr=SR, settings=OFF, rng=np.random.default_rng(0))
    assert np.array_equal(same, y) and scale == 1.0 and params == {}


@pytest.mark.parametrize("beta", [0.0, 1.0])
@pytest.mark.parametrize("target", [0.0, 10.0, 20.0])
def test_noise_is_mixed_at_the_requested_snr(beta, target):
    y = voice(1)
    noisy = A.mix_at_snr(y, A.coloured_noise(len(y), np.random.default_rng(3), beta=beta), target)
    assert abs(snr_db(y, noisy) - target) < 0.5


def test_pink_noise_has_a_falling_spectrum():
    n = A.coloured_noise(2**16, np.random.default_rng(0), beta=1.0)
    f, p = sps.welch(n, fs=SR, nperseg=2048)
    low, high = p[(f > 100) & (f < 200)].mean(), p[(f > 6400) & (f < 12800)].mean()
    assert 10 * np.log10(low / high) == pytest.approx(10 * np.log10(64 / 1.5), abs=3)


def test_the_telephone_band_passes_speech_frequencies_only():
    for hz, kept in ((100, False), (1000, True), (6000, False)):
        y = tone(hz)
        out = A.telephone_band(y, sr=SR)
        ratio = np.sqrt(np.mean(out[2000:-2000] ** 2) / np.mean(y[2000:-2000] ** 2))
        assert (ratio > 0.9) if kept else (ratio < 0.1), (hz, ratio)
    # zero phase: the 1 kHz tone is not delayed
    assert np.abs(A.telephone_band(tone(1000), sr=SR) - tone(1000))[3000:-3000].max() < 0.02


def test_gain_and_clipping_act_at_their_strength():
    y = voice(2)
    np.testing.assert_allclose(A.gain_clip(y, -6.0), y * 10 ** (-6 / 20), rtol=1e-6)
    loud = A.gain_clip(y, 20.0)
    assert np.abs(loud).max() == 1.0
    clipped = A.clip_fraction(y, 0.05)
    assert np.mean(np.abs(clipped) >= np.abs(clipped).max()) == pytest.approx(0.05, abs=0.01)


def test_reverberation_keeps_rms_and_timing_and_the_rir_decays_as_asked():
    y = np.zeros(SR, np.float32)
    y[SR // 2] = 1.0  # an impulse: the output is the aligned response
    out = A.reverberate(y, RIR)
    assert out.shape == y.shape and np.sqrt(np.mean(out**2)) == pytest.approx(
        np.sqrt(np.mean(y**2)), rel=1e-6)
    assert abs(int(np.argmax(np.abs(out))) - SR // 2) <= 1  # no delay against the labels
    edc = np.cumsum(RIR[::-1] ** 2)[::-1]
    edc_db = 10 * np.log10(edc / edc[0] + 1e-300)
    t5, t25 = np.argmax(edc_db <= -5), np.argmax(edc_db <= -25)
    assert 0.2 < 3 * (t25 - t5) / SR < 0.5  # T20-estimated RT60 near the 0.3 s asked for
    bank = A.rir_bank(SR, 1, (0.2, 0.3), 3)
    assert len(bank) == 3 and all(np.array_equal(a, b) for a, b in
                                  zip(bank, A.rir_bank.__wrapped__(SR, 1, (0.2, 0.3), 3)))


def test_tempo_changes_the_duration_and_returns_its_scale():
    y = tone(440)
    fast, scale = A.tempo(y, 1.25)
    assert scale == len(fast) / len(y) and len(fast) == round(len(y) / 1.25)
    assert peak_hz(fast) == pytest.approx(440, abs=3)  # the pitch is kept


def test_pitch_shift_moves_a_tone_by_its_semitones():
    out = A.pitch_shift(tone(440), sr=SR, semitones=2.0)
    assert len(out) == SR and peak_hz(out) == pytest.approx(440 * 2 ** (2 / 12), abs=4)


def test_retiming_targets_and_labels():
    targets = np.arange(10, dtype=np.float32)[:, None] * np.array([1.0, -2.0], np.float32)
    out = A.retime_targets(targets, 2.0, 19)  # twice as slow: frame k shows input frame k / 2
    np.testing.assert_allclose(out[:, 0], np.arange(19) / 2)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(A.retime_labels(np.arange(10), 0.5, 5), [0, 2, 4, 6, 8])


# -- training copies ----------------------------------------------------------------------------
def utt(utt_id: str, y: np.ndarray, speaker: str = "s1") -> UttData:
    feats = audio_features(y, sr=SR)
    n = len(feats)
    return UttData(utt_id, speaker, "neutral", utt_id, feats,
                   np.linspace(0, 1, n, dtype=np.float32)[:, None].repeat(2, 1),
                   np.arange(n) % 44, audio=y, sample_rate=SR)


@pytest.fixture(scope="module")
def data():
    return [utt(f"u{i}", voice(i, 0.8), speaker=f"s{i % 2}") for i in range(4)]


def test_copies_are_of_training_utterances_only_and_reproducible(data):
    masks = [np.ones(d.n_frames, bool) for d in data[:3]] + [np.zeros(data[3].n_frames, bool)]
    on = AugmentSettings(copies=2)
    copies, cmasks = training_copies(data, masks, settings=on, seed=4)
    assert [c.utt_id for c in copies] == [f"u{i}+copy{c}" for i in range(3) for c in range(2)]
    again, _ = training_copies(data, masks, settings=on, seed=4)
    assert all(np.array_equal(a.features, b.features) for a, b in zip(copies, again))
    other, _ = training_copies(data, masks, settings=on, seed=5)
    assert not all(np.array_equal(a.features, b.features) for a, b in zip(copies, other)
                   if a.n_frames == b.n_frames)
    for c, m in zip(copies, cmasks):
        assert c.n_frames == len(c.mups) == len(c.phones) == len(m) and m.all()
    # off by default, and nothing for a split without training frames
    assert training_copies(data, masks, settings=AugmentSettings()) == ([], [])
    assert training_copies(data, [np.zeros(d.n_frames, bool) for d in data],
                           settings=on) == ([], [])


def test_the_vtlp_warp_alone_makes_one_warped_copy_drawn_from_its_seed(data):
    masks = [np.ones(d.n_frames, bool) for d in data]
    assert copies_per_utterance(AugmentSettings(), (0.9, 1.1)) == 1
    assert copies_per_utterance(AugmentSettings(), (1.0, 1.0)) == 0
    copies, _ = training_copies(data, masks, settings=AugmentSettings(), vtlp_range=(0.9, 1.1),
                                seed=3)
    assert len(copies) == len(data)
    for d, c in zip(data, copies):  # the audio is untouched: only the filterbank is warped
        assert c.n_frames == d.n_frames and np.array_equal(c.mups, d.mups)
        alpha = np.random.default_rng([3, utterance_key(d.utt_id), 0]).uniform(0.9, 1.1)
        np.testing.assert_array_equal(c.features, audio_features(d.audio, sr=SR,
                                                                 n_frames=d.n_frames,
                                                                 vtlp_alpha=alpha))
        assert not np.allclose(c.features, d.features)
    unwarped, _ = training_copies(data, masks, settings=AugmentSettings(),
                                  vtlp_range=(1.0, 1.0))
    assert unwarped == []


@pytest.mark.parametrize("rate", [0.8, 1.2])
def test_a_tempo_copy_keeps_features_and_targets_aligned(rate):
    """A tone starting at a known frame: after the tempo change, the copy's target step (0 → 1
    at the onset, re-timed), its phone labels and its audio onset (the first frame within 6 dB
    of the tone's level) fall on the same frame."""
    n = int(SR * 1.5)
    onset = 21  # frame
    y = np.zeros(n, np.float32)
    y[onset * 735:] = tone(300, 1.5)[:n - onset * 735]
    d = utt("tone", y)
    d.mups[:] = 0
    d.mups[onset:] = 1
    d.phones[:] = 0
    d.phones[onset:] = 5
    settings = dataclasses.replace(OFF, copies=1, tempo_prob=1.0, tempo_range=(rate, rate))
    (c,), (m,) = training_copies([d], [np.ones(d.n_frames, bool)], settings=settings, seed=0)
    assert c.n_frames == int(np.ceil(round(n / rate) / 735)) and m.all()
    stretched, _ = A.tempo(y, rate)  # the copy's audio (the phase vocoder is deterministic)
    np.testing.assert_array_equal(c.features, audio_features(stretched, sr=SR,
                                                             n_frames=c.n_frames))
    level = frame_rms_dbfs(stretched, sr=SR, n_frames=c.n_frames)
    audio_onset = int(np.argmax(level > np.median(level[-10:]) - 6))
    target_onset = int(np.argmax(c.mups[:, 0] > 0.5))
    label_onset = int(np.argmax(c.phones == 5))
    assert abs(target_onset - onset / rate) <= 1 and abs(label_onset - onset / rate) <= 1
    assert abs(audio_onset - target_onset) <= 1


def test_the_experiment_fits_on_the_copies_and_estimates_the_originals(data):
    from mapping.config import MappingConfig
    from mapping.experiment import run_experiment

    base = dataclasses.replace(MappingConfig(), method="linear", baselines=(),
                               splits=("utterance",))
    plain = run_experiment(data, base, n_utterance=1, seed=0)[0]
    noisy = run_experiment(data, dataclasses.replace(
        base, augment=dataclasses.replace(OFF, copies=1, noise_prob=1.0)), n_utterance=1,
        seed=0)[0]
    assert len(noisy.predictions) == len(data)
    assert all(np.array_equal(a, b) for a, b in zip(noisy.masks, plain.masks))
    assert [len(p) for p in noisy.predictions] == [d.n_frames for d in data]
    assert not np.allclose(noisy.predictions[3], plain.predictions[3])
