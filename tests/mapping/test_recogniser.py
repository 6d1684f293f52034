"""The recogniser front end (issue 12, part 6): pocketsphinx's phones per frame are the same
offline and live, depend on no audio after their decision time, recover the labelled phones of
a real recording, and drive a gated mapping whose gate is the recogniser — offline = streaming,
saved and loaded as data."""
import dataclasses

import numpy as np
import pytest

from analysis.speech_eval import phone_frames, viseme_index
from analysis.speech_set import SET_DIR, load_speech_set
from face_model.phones import PHONE_INDEX
from groundwork.audio import resample
from groundwork.errors import ParameterError
from groundwork.settings import SettingError
from mapping import build_dataset, make_mapper
from mapping.animator import FaceAnimator
from mapping.checkpoint import AudioMapping
from mapping.config import MappingConfig
from mapping.recogniser import (MIN_UTTERANCE_S, PhoneStream, fit_length, label_windows,
                                phone_inputs, recognise, recognise_windows)
from talkingface.config import Config
from tests.mapping.small_mapping import stream_frames, train_small

SR = 22050  # a model rate (an integer hop at 30 fps)


@pytest.fixture(scope="module")
def a0009():
    """CMU ARCTIC a0009 (real speech) at 22050 Hz, with its labelled phones per frame."""
    item = next(i for i in load_speech_set(SET_DIR) if i.id == "slt_a0009")
    y = resample(item.audio.astype(np.float32), sr_in=item.sr, sr_out=SR)
    n = int(np.ceil(len(y) / (SR // 30)))
    return y, phone_frames(item.phones, np.arange(n) / 30)


def _stream(y, chunks, delay, back=None, stream=None):
    """Feed ``y`` in ``chunks`` (then the rest) to a PhoneStream; its phones, or its windows
    when ``back`` is given."""
    s = stream or PhoneStream(SR, 30, delay, back or 0)
    push, flush = (s.push, s.flush) if back is None else (s.push_windows, s.flush_windows)
    out, i = [], 0
    for n in chunks:
        out += push(y[i:i + n])
        i += n
    out += push(y[i:])
    return np.array(out + flush())


@pytest.mark.parametrize("delay", [0, 3])
def test_live_phones_equal_offline_phones_for_any_chunking(a0009, delay):
    y, _ = a0009
    offline = recognise(y, SR, delay_frames=delay)
    assert len(offline) == int(np.ceil(len(y) / (SR // 30)))
    chunks = np.random.default_rng(5).integers(1, 3000, size=60)
    np.testing.assert_array_equal(_stream(y, chunks, delay), offline)
    np.testing.assert_array_equal(_stream(y, [1] * 50 + [len(y)], delay), offline)


def test_a_phone_does_not_depend_on_audio_after_its_decision(a0009):
    y, _ = a0009
    hop, delay = SR // 30, 3
    cut = 60  # frames; audio from sample cut·hop on is replaced
    other = y.copy()
    other[cut * hop:] = np.random.default_rng(0).normal(0, 0.2, len(y) - cut * hop)
    a, b = recognise(y, SR, delay_frames=delay), recognise(other, SR, delay_frames=delay)
    decided = cut - delay  # frames decided from the first `cut` blocks
    np.testing.assert_array_equal(a[:decided + 1], b[:decided + 1])
    assert not np.array_equal(a, b)  # the replaced audio does change later phones


def test_a_fresh_decoder_per_stream_makes_phones_independent_of_earlier_audio(a0009):
    y, _ = a0009
    first = recognise(y, SR)
    recognise(np.random.default_rng(1).normal(0, 0.3, SR * 2).astype(np.float32), SR)
    np.testing.assert_array_equal(recognise(y, SR), first)


def test_the_phones_of_real_speech_match_its_labels(a0009):
    """Trained on real speech, the recogniser labels the real a0009 mostly right (its viseme
    frame accuracy with 100 ms of look-ahead, FIELD_NOTES: about 0.8; our MFCC gate: 0.5)."""
    y, true = a0009
    heard = recognise(y, SR, delay_frames=3)
    acc = float(np.mean(viseme_index(heard) == viseme_index(true)))
    assert acc >= 0.7, acc
    assert set(np.unique(heard)) <= set(PHONE_INDEX.values())


@pytest.mark.parametrize("sr, delay, message", [
    (16000, 3, "sample rate 16000 Hz has no integer hop at 30 fps"),
    (SR, -1, "delay_frames must be a non-negative integer, got -1"),
    (SR, 1.5, "delay_frames must be a non-negative integer, got 1.5"),
])
def test_bad_stream_settings_are_refused(sr, delay, message):
    with pytest.raises(ParameterError, match=message):
        PhoneStream(sr, 30, delay)


def test_a_flushed_stream_refuses_more_audio():
    s = PhoneStream(SR)
    s.push(np.zeros(SR // 10, np.float32))
    s.flush()
    with pytest.raises(ParameterError, match="the phone stream has ended"):
        s.push(np.zeros(10, np.float32))
    assert s.flush() == []


def test_fit_length_cuts_or_repeats_the_last_label():
    np.testing.assert_array_equal(fit_length(np.array([1, 2, 3]), 2), [1, 2])
    np.testing.assert_array_equal(fit_length(np.array([1, 2, 3]), 5), [1, 2, 3, 3, 3])


# -- a gated mapping whose gate is the recogniser ----------------------------------------------

@pytest.fixture(scope="module")
def recogniser_mapping(small_corpus):
    t = train_small(small_corpus, split="random_frames", gate_front_end="recogniser",
                    min_class_frames=5)
    return t.mapping, t.units, t.data


def test_the_recogniser_gate_uses_the_recognised_phones(recogniser_mapping):
    mapping, _, data = recogniser_mapping
    m, d = mapping.mapper, data[0]
    assert m.gate_ is None and m.needs_phones
    assert len(m.bank_.nets_) > 1  # several classes for the phones to choose from
    assert d.recognised.shape == (d.n_frames, 7)
    own = d.recognised[:, 3]  # each frame's own phone in its window
    np.testing.assert_array_equal(m.gate_classes(d.features, d.recognised),
                                  m.group_of_phone_[own])
    # the phones offline are those the data carries (one PhoneStream, the same look-ahead)
    u_audio = d.audio
    np.testing.assert_array_equal(mapping.gate_classes(u_audio, d.sample_rate),
                                  m.group_of_phone_[own])
    other = d.recognised.copy()
    other[:] = PHONE_INDEX["m"]  # the lips' class, which the corpus speaks
    assert m.group_of_phone_[other[0, 3]] != m.group_of_phone_[PHONE_INDEX["aa"]]
    assert not np.allclose(m.predict(d.features, "neutral", other),
                           m.predict(d.features, "neutral", d.recognised))


def test_the_recogniser_gate_refuses_an_estimate_without_phones(recogniser_mapping):
    m, d = recogniser_mapping[0].mapper, recogniser_mapping[2][0]
    with pytest.raises(ParameterError, match="this mapping's gate is the phone recogniser"):
        m.predict(d.features)
    with pytest.raises(ParameterError, match=f"recognised phones must be {d.n_frames} windows "
                                              "of 7 class indices in 0..43, got shape"):
        m.predict(d.features, "neutral", d.recognised[:-1])


def test_a_recogniser_gated_model_round_trips_without_a_mixture(recogniser_mapping, tmp_path):
    mapping, _, data = recogniser_mapping
    path = mapping.save(tmp_path / "r.tfmap")
    back = AudioMapping.load(path)
    assert back.mapper.gate_front_end == "recogniser" and back.mapper.gate_ is None
    d = data[1]
    np.testing.assert_array_equal(back.predict_audio(d.audio, d.sample_rate),
                                  mapping.predict_audio(d.audio, d.sample_rate))


@pytest.mark.parametrize("chunk", [1, 777, 10**7])
def test_streaming_with_the_recogniser_gate_equals_offline(recogniser_mapping, small_corpus,
                                                           chunk):
    mapping, units, _ = recogniser_mapping
    animator = FaceAnimator(mapping, units)
    u = small_corpus.utterances[2]
    mups, _ = animator.animate(u.audio, u.sample_rate, "smile")
    frames = stream_frames(animator, u.audio, chunk, "smile")
    assert [f.index for f in frames] == list(range(len(mups)))
    # the same rows as offline (to float32 rounding of (1, d) against (n, d) products)
    np.testing.assert_allclose(np.stack([f.mups for f in frames]), mups, rtol=0, atol=1e-3)


# -- windows of phones and the phone-input MLPs ------------------------------------------------

def test_windows_live_equal_windows_offline_and_hold_the_frames_phone(a0009):
    y, _ = a0009
    back, delay = 3, 3
    offline = recognise_windows(y, SR, delay_frames=delay, back=back)
    assert offline.shape == (int(np.ceil(len(y) / (SR // 30))), back + 1 + delay)
    chunks = np.random.default_rng(7).integers(1, 4000, size=40)
    np.testing.assert_array_equal(_stream(y, chunks, delay, back), offline)
    # the frame's own column is the phone decided alone; frames before 0 are silence
    np.testing.assert_array_equal(offline[:, back], recognise(y, SR, delay_frames=delay))
    assert np.all(offline[0, :back] == PHONE_INDEX["sil"])
    # a window's past is the hypothesis at decision time, not a copy of earlier decisions
    assert not np.array_equal(offline[1:, back - 1], offline[:-1, back])


def test_a_window_does_not_depend_on_audio_after_its_decision(a0009):
    y, _ = a0009
    hop, back, delay, cut = SR // 30, 3, 3, 60
    other = y.copy()
    other[cut * hop:] = np.random.default_rng(2).normal(0, 0.2, len(y) - cut * hop)
    a = recognise_windows(y, SR, delay_frames=delay, back=back)
    b = recognise_windows(other, SR, delay_frames=delay, back=back)
    np.testing.assert_array_equal(a[:cut - delay + 1], b[:cut - delay + 1])


def test_phone_inputs_are_one_hot_per_window_position():
    w = np.array([[0, 5, 43], [2, 2, 2]])
    x = phone_inputs(w)
    assert x.shape == (2, 3 * 44) and x.dtype == np.float32
    np.testing.assert_array_equal(x.sum(axis=1), [3, 3])
    for r in range(2):
        for j in range(3):
            assert x[r, j * 44 + w[r, j]] == 1.0


def test_phone_input_needs_the_recogniser_gate():
    with pytest.raises(SettingError, match="mlp_input is 'phones'; allowed: 'mfcc' unless "
                                           "gate_front_end is 'recogniser'"):
        MappingConfig(mlp_input="phones")
    assert MappingConfig(mlp_input="phones", gate_front_end="recogniser").mlp_input == "phones"


@pytest.fixture(scope="module")
def phone_input_mapping(small_corpus):
    t = train_small(small_corpus, gate_front_end="recogniser", mlp_input="phones",
                    min_class_frames=5, vtlp_range=(0.9, 1.1))
    return t.mapping, t.units, t.data, t.copies


def test_warped_copies_are_recognised_for_the_phone_input(phone_input_mapping):
    _, _, data, (copies, masks) = phone_input_mapping
    assert copies and all(c.recognised is not None for c in copies)
    for c, m in zip(copies, masks):
        assert c.recognised.shape == (c.n_frames, 7) and len(m) == c.n_frames


def test_the_phone_input_mlps_read_the_phones_not_the_mfcc(phone_input_mapping):
    mapping, _, data, _ = phone_input_mapping
    m, d = mapping.mapper, data[0]
    assert all(net.x_mean_.shape == (7 * 44,) for net in m.bank_.nets_.values())
    same = m.predict(d.features, "neutral", d.recognised)
    noise = np.random.default_rng(3).normal(size=d.features.shape).astype(np.float32)
    np.testing.assert_array_equal(m.predict(noise, "neutral", d.recognised), same)
    other = d.recognised.copy()
    other[:, 4:] = PHONE_INDEX["m"]  # only the window's future changes; the gate does not
    changed = m.predict(d.features, "neutral", other)
    assert not np.allclose(changed, same)


def test_a_phone_input_model_round_trips_and_streams_as_offline(phone_input_mapping, tmp_path,
                                                                small_corpus):
    mapping, units, data, _ = phone_input_mapping
    back = AudioMapping.load(mapping.save(tmp_path / "p.tfmap"))
    assert back.mapper.mlp_input == "phones"
    u = small_corpus.utterances[1]
    np.testing.assert_array_equal(back.predict_audio(u.audio, u.sample_rate, "sad"),
                                  mapping.predict_audio(u.audio, u.sample_rate, "sad"))
    animator = FaceAnimator(back, units)
    mups, _ = animator.animate(u.audio, u.sample_rate, "sad")
    frames = stream_frames(animator, u.audio, 1000, "sad")
    assert [f.index for f in frames] == list(range(len(mups)))
    np.testing.assert_allclose(np.stack([f.mups for f in frames]), mups, rtol=0, atol=1e-3)
    assert all(f.features is None for f in frames)  # no MFCC computed: no network reads them


def test_a_long_stream_is_cut_into_utterances_at_pauses_alike_offline_and_live():
    """Real sentences one after another with short pauses: the stream begins new utterances
    (the hypothesis stays short however long it runs), at the same blocks offline and live."""
    items = load_speech_set(SET_DIR)[:6]
    pause = np.zeros(SR // 2, np.float32)
    y = np.concatenate([np.concatenate([resample(i.audio.astype(np.float32), sr_in=i.sr,
                                                 sr_out=SR), pause]) for i in items])
    assert len(y) / SR > 2 * MIN_UTTERANCE_S
    live = PhoneStream(SR, 30, 3, 3)
    got = _stream(y, np.random.default_rng(11).integers(1, 5000, size=400), 3, 3, live)
    assert live.utterances >= 2
    offline = recognise_windows(y, SR, delay_frames=3, back=3)
    np.testing.assert_array_equal(got, offline)
    assert np.mean(offline[:, 3] != PHONE_INDEX["sil"]) > 0.3  # speech is still heard


def test_label_windows_hold_the_labelled_phones_around_each_frame():
    sil = PHONE_INDEX["sil"]
    np.testing.assert_array_equal(label_windows(np.array([1, 2, 3]), 1, 2),
                                  [[sil, 1, 2, 3], [1, 2, 3, sil], [2, 3, sil, sil]])


def test_phone_input_trained_on_labels_needs_no_recognition_and_learns_the_labelled_mouths(
        small_corpus):
    """``phone_training="labels"``: the MLPs learn from the labelled windows (no recogniser run
    on the training audio); fed the labelled windows of the training utterances, they draw the
    mouths they were trained on better than from the mean."""
    from face_model.motion_units import fit_corpus_units

    cfg = Config()
    mcfg = dataclasses.replace(cfg.mapping, gate_front_end="recogniser", mlp_input="phones",
                               phone_training="labels", min_class_frames=5,
                               train=dataclasses.replace(cfg.mapping.train, max_epochs=60))
    units, _ = fit_corpus_units(small_corpus)
    data = build_dataset(small_corpus, units)  # no recognised phones at all
    assert all(d.recognised is None for d in data)
    masks = [np.ones(d.n_frames, bool) for d in data]
    m = make_mapper("gated_mlp", mcfg, n_utterance=units.n_utterance,
                    random_state=cfg.seed).fit(data, masks)
    neutral = [d for d in data if d.expression == "neutral"]
    err, base = 0.0, 0.0
    mean = np.concatenate([d.mups for d in neutral]).mean(0)
    for d in neutral:
        pred = m.predict(d.features, "neutral", label_windows(d.phones, 3, 3))
        err += float(((pred - d.mups) ** 2).sum())
        base += float(((mean - d.mups) ** 2).sum())
    assert err < 0.5 * base, (err, base)


def test_the_oracle_reads_the_labelled_phones_and_refuses_audio(small_corpus):
    """``gate_front_end="labels"`` (the ceiling's oracle): training and estimation read the
    corpus's phone labels; animating audio is refused with the reason."""
    t = train_small(small_corpus, gate_front_end="labels", mlp_input="phones",
                    min_class_frames=5)
    m, d = t.mapping.mapper, t.data[0]
    assert d.recognised is None  # no recogniser ran
    np.testing.assert_array_equal(m.utterance_phones(d), label_windows(d.phones, 3, 3))
    np.testing.assert_array_equal(m.gate_classes(d.features, m.utterance_phones(d)),
                                  m.group_of_phone_[d.phones])
    assert t.result.gate["neutral_test"] == 1.0  # the gate is the labels themselves
    with pytest.raises(ParameterError, match="this mapping is an oracle .* cannot animate "
                                             "audio"):
        t.mapping.predict_audio(small_corpus.utterances[0].audio, SR)
