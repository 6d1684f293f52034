"""The related-work baselines (§III-C), the method registry and the saved audio → MUP model."""
from __future__ import annotations

import dataclasses
import inspect
import json

import numpy as np
import pytest

from face_model.motion_units import fit_corpus_units
from groundwork.audio import resample
from groundwork.errors import NotFittedError, ParameterError
from mapping import BASELINES, METHODS, Baseline, GatedMLP, build_dataset, make_mapper, mfcc
from mapping.checkpoint import KIND, VERSION, AudioMapping, rest_mups
from mapping.config import MappingConfig, TrainSettings
from mapping.dataset import split_masks
from mapping.features import audio_features, frame_rms_dbfs
from tests.mapping.phone_runs import A0, N_FEAT, phone_run_data

# Short training of every network: the synthetic mapping is easy.
TRAIN = TrainSettings(max_epochs=150, patience=25)


def config(**changes) -> MappingConfig:
    """The mapping section for the small synthetic data, with some values changed."""
    base = dict(train=TRAIN, min_class_frames=15, gate_components=2)
    base.update(changes)
    return dataclasses.replace(MappingConfig(), **base)


def synthetic_data(seed: int = 0) -> list:
    return phone_run_data(seed, n_utt=4, n_seg=10, seg_len=7)


@pytest.fixture(scope="module")
def data():
    return synthetic_data()


@pytest.fixture(scope="module")
def masks(data):
    return split_masks(data, "random_frames", train_fraction=0.8, seed=0)


# -- baselines ---------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", BASELINES)
def test_baseline_beats_the_training_mean(kind, data, masks):
    b = Baseline(kind, train=TRAIN, random_state=0).fit(data, masks)
    assert b.name == kind and b.reference
    assert sorted(b.models_) == ["neutral", "smile"]  # one regressor per expression
    err_model = err_mean = 0.0
    for e in ("neutral", "smile"):
        idx = [i for i, d in enumerate(data) if d.expression == e]
        Y = np.concatenate([data[i].mups[masks[i]] for i in idx])
        P = np.concatenate([b.predict(data[i].features, e)[masks[i]] for i in idx])
        assert P.shape == Y.shape and P.dtype == np.float32 and np.all(np.isfinite(P))
        err_model += np.sum((P - Y) ** 2)
        err_mean += np.sum((Y - Y.mean(0)) ** 2)  # the best constant per expression
    assert err_model < 0.5 * err_mean, (kind, err_model / err_mean)


def test_baseline_errors(data, masks):
    b = Baseline("knn", train=TRAIN)  # stored as given ...
    assert b.kind == "knn" and b.name == "knn"
    with pytest.raises(ParameterError, match=r"unknown baseline 'knn'; allowed: vq, linear, "
                                             r"gmm_regression, mlp_large, tdnn, gru"):
        b.fit(data, masks)  # ... and refused when training starts
    with pytest.raises(NotFittedError, match="baseline knn is not trained yet"):
        b.predict(data[0].features)
    b = Baseline("linear", train=TRAIN)
    with pytest.raises(NotFittedError, match="baseline linear is not trained yet"):
        b.predict(data[0].features)
    b.fit(data, masks)
    with pytest.raises(ParameterError, match=r"expression 'sad' was not trained; allowed: "
                                             r"neutral, smile"):
        b.predict(data[0].features, "sad")


def test_baseline_context_sizes(data, masks):
    """mlp_large sees 5 + 1 + 5 frames, tdnn single frames, the others the given 3 + 1 + 3."""
    train = dataclasses.replace(TRAIN, max_epochs=2)
    assert Baseline("mlp_large", train=train).fit(data, masks).context_.n_inputs == 11 * N_FEAT
    assert Baseline("tdnn", train=train).fit(data, masks).context_.n_inputs == N_FEAT
    assert Baseline("linear", train=train).fit(data, masks).context_.n_inputs == 7 * N_FEAT
    assert Baseline("linear", context_back=1, context_forward=0).fit(
        data, masks).context_.n_inputs == 2 * N_FEAT


def test_baseline_stores_its_arguments_verbatim():
    params = dict(kind="gru", context_back=2, context_forward=1, cmvn="mean",
                  cmvn_warmup_frames=12, train=TrainSettings(max_epochs=7, patience=3),
                  random_state=42)
    b = Baseline(**params)
    for name, value in params.items():
        assert getattr(b, name) is value, name
    assert set(params) == set(inspect.signature(Baseline).parameters)  # every parameter checked
    assert not hasattr(b, "models_")  # nothing learnt before fit


def test_make_mapper():
    assert METHODS == ("gated_mlp", *BASELINES)
    g = make_mapper("gated_mlp", config(), n_utterance=5, random_state=2)
    assert isinstance(g, GatedMLP) and g.n_utterance == 5 and g.random_state == 2
    for kind in BASELINES:
        b = make_mapper(kind, config(), random_state=4)
        assert isinstance(b, Baseline) and b.kind == kind and b.random_state == 4
    with pytest.raises(ParameterError, match=r"unknown mapping method 'nope'; allowed: gated_mlp, "
                                             r"vq, linear, gmm_regression, mlp_large, tdnn, gru"):
        make_mapper("nope", config())


# The MappingConfig fields that are no estimator's hyper-parameter: they choose what is trained
# and on which data (the method, the splits, the features, the training copies and the visual
# source).
NOT_HYPER_PARAMETERS = {"method", "baselines", "splits", "train_fraction", "n_mfcc", "deltas",
                        "visual_source", "vtlp_range", "augment", "window_align",
                        "mel_fmax_hz", "workers",  # where the methods train: the speed only
                        "front_model"}  # folded into the recogniser (mapping.experiment)


def estimator_parameters(cls) -> set:
    """Hyper-parameters of an estimator class that a MappingConfig supplies."""
    return set(inspect.signature(cls).parameters) - {"kind", "n_utterance", "random_state"}


def test_make_mapper_passes_every_config_field():
    """Every estimator hyper-parameter comes from the MappingConfig field of the same name (all
    set away from their defaults here, so a parameter left at its default shows)."""
    train = TrainSettings(validation_fraction=0.3, max_epochs=7, patience=3, learning_rate=0.5,
                          weight_decay=0.25, batch_size=16)
    mcfg = dataclasses.replace(
        MappingConfig(), context_back=2, context_forward=1, n_classes=8, gate_components=3,
        gate_covariance="full", min_class_frames=11, hidden_min=4, hidden_max=9,
        expression_model="bank", cascade_hidden=12, cmvn="meanvar", cmvn_warmup_frames=7,
        gate_front_end="recogniser", mlp_input="phones", phone_training="labels",
        recogniser="hama", train=train)
    fields = {f.name for f in dataclasses.fields(MappingConfig)}
    gated = estimator_parameters(GatedMLP)
    assert fields - gated == NOT_HYPER_PARAMETERS  # every other field is a hyper-parameter
    assert estimator_parameters(Baseline) <= gated
    defaults = GatedMLP()
    g = make_mapper("gated_mlp", mcfg, n_utterance=5, random_state=2)
    for name in sorted(gated):
        assert getattr(g, name) == getattr(mcfg, name) != getattr(defaults, name), name
    assert g.train is train and (g.n_utterance, g.random_state) == (5, 2)
    for kind in BASELINES:
        b = make_mapper(kind, mcfg, random_state=4)
        for name in sorted(estimator_parameters(Baseline)):
            assert getattr(b, name) == getattr(mcfg, name) != getattr(Baseline(kind), name), name
        assert b.train is train and b.random_state == 4
    causal = make_mapper("gated_mlp", dataclasses.replace(mcfg, recogniser="causal",
                                                          front_model="f.npz"))
    assert causal.recogniser == "causal:f.npz"  # the front end's model file rides on the name
    assert make_mapper("gated_mlp", dataclasses.replace(mcfg, recogniser="causal")
                       ).recogniser == "causal"


# -- the saved model ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def corpus_model(small_corpus):
    """A quickly trained GatedMLP on the small corpus, wrapped as an AudioMapping."""
    units, _ = fit_corpus_units(small_corpus)
    data = build_dataset(small_corpus, units)
    masks = split_masks(data, "random_frames", seed=0)
    mcfg = config(n_classes=8, min_class_frames=20, train=dataclasses.replace(TRAIN, max_epochs=30))
    mapper = make_mapper("gated_mlp", mcfg, n_utterance=7, random_state=0)
    mapper.fit(data, masks)
    u = small_corpus.utterances[0]
    return AudioMapping(mapper, sample_rate=u.sample_rate, fps=u.fps, n_utterance=7,
                        rest_mups=rest_mups(units), metadata={"note": "unit test", "n_frames": 996})


def test_audio_mapping_matches_the_method(small_corpus, corpus_model):
    assert corpus_model.expressions == ("neutral", "sad", "smile")
    u = small_corpus.utterances[5]
    feats = audio_features(u.audio, sr=u.sample_rate, fps=u.fps)
    assert feats.shape == (int(np.ceil(len(u.audio) / (u.sample_rate // u.fps))), 10)
    np.testing.assert_array_equal(corpus_model.features(u.audio, u.sample_rate), feats)
    # the method's estimate, with the neutral mouth on the faint pauses at the utterance's ends
    levels = frame_rms_dbfs(u.audio, sr=u.sample_rate, fps=u.fps, n_frames=len(feats))
    quiet = levels < corpus_model.silence_dbfs
    assert quiet.any() and not quiet.all()
    est = corpus_model.mapper.predict(feats, "smile")
    expected = est.copy()
    expected[quiet, :7] = corpus_model.rest_mups
    np.testing.assert_array_equal(corpus_model.predict_audio(u.audio, u.sample_rate, "smile"),
                                  expected)


def test_save_load_round_trip(small_corpus, corpus_model, tmp_path):
    path = corpus_model.save(tmp_path / "models" / "m.tfmap")
    assert path.is_file()
    with np.load(path, allow_pickle=False) as z:  # numbers and a JSON record, nothing pickled
        record = json.loads(str(z["metadata"]))
    assert (KIND, VERSION) == ("audio_mapping", 4)
    assert (record["kind"], record["version"]) == (KIND, VERSION)
    assert record["method"] == "gated_mlp"
    assert record["rest_mups"] == corpus_model.rest_mups.tolist()
    assert record["silence_dbfs"] == corpus_model.silence_dbfs
    loaded = AudioMapping.load(path)
    assert (loaded.sample_rate, loaded.fps, loaded.n_mfcc, loaded.deltas, loaded.n_utterance) == (
        corpus_model.sample_rate, corpus_model.fps, 10, False, 7)
    assert loaded.metadata == corpus_model.metadata
    assert loaded.expressions == corpus_model.expressions
    for u in small_corpus.utterances[::4]:
        for e in loaded.expressions:
            a = corpus_model.predict_audio(u.audio, u.sample_rate, e)
            b = loaded.predict_audio(u.audio, u.sample_rate, e)
            assert a.shape == (u.n_frames, 9)  # one row per video frame
            np.testing.assert_array_equal(a, b)


def test_saved_baseline_round_trip(data, masks, tmp_path):
    """A baseline trained on raw features saves and loads too (predict from features)."""
    b = Baseline("vq", train=TRAIN, random_state=0).fit(data, masks)
    m = AudioMapping(b, sample_rate=22050, n_utterance=A0, rest_mups=np.zeros(A0))
    loaded = AudioMapping.load(m.save(tmp_path / "vq.tfmap"))
    assert loaded.expressions == ("neutral", "smile")
    np.testing.assert_array_equal(loaded.mapper.predict(data[5].features, "smile"),
                                  b.predict(data[5].features, "smile"))


def test_silence_settings_survive_saving_bit_for_bit(corpus_model, tmp_path):
    """rest_mups and silence_dbfs go through the JSON header and come back unchanged, down to
    the last bit (values with long binary expansions on purpose)."""
    rest = np.array([1 / 3, -2 / 7, np.pi, 1e-17, -0.0, 2.0**-40, -1e300])
    m = AudioMapping(corpus_model.mapper, sample_rate=corpus_model.sample_rate, n_utterance=7,
                     rest_mups=rest, silence_dbfs=-60.0 - 1 / 3)
    loaded = AudioMapping.load(m.save(tmp_path / "m.tfmap"))
    assert loaded.rest_mups.dtype == np.float64 and loaded.rest_mups.shape == (7,)
    assert loaded.rest_mups.tobytes() == m.rest_mups.tobytes()
    assert isinstance(loaded.silence_dbfs, float)
    assert np.float64(loaded.silence_dbfs).tobytes() == np.float64(-60.0 - 1 / 3).tobytes()


def test_rest_mups_of_the_wrong_shape_are_refused(corpus_model):
    for bad, shape in ((np.zeros(6), r"\(6,\)"), (np.zeros((1, 7)), r"\(1, 7\)"),
                       (0.0, r"\(\)")):
        with pytest.raises(ParameterError, match=r"rest_mups must have shape \(7,\), got " + shape):
            AudioMapping(corpus_model.mapper, sample_rate=22050, n_utterance=7, rest_mups=bad)
    with pytest.raises(ParameterError, match=r"rest_mups must have shape \(3,\), got \(7,\)"):
        AudioMapping(corpus_model.mapper, sample_rate=22050, n_utterance=3,
                     rest_mups=corpus_model.rest_mups)
    with pytest.raises(TypeError, match="rest_mups"):  # required: no silent default
        AudioMapping(corpus_model.mapper, sample_rate=22050)


def test_loading_other_files_is_refused(tmp_path):
    with pytest.raises(ParameterError, match="not found"):
        AudioMapping.load(tmp_path / "missing.tfmap")
    text = tmp_path / "notes.txt"
    text.write_text("hello\nworld\n")
    with pytest.raises(ParameterError, match="not a talkingface mapping model"):
        AudioMapping.load(text)
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"format": "someone.else/3"}) + "\n")
    with pytest.raises(ParameterError, match=r"not a talkingface mapping model .*someone\.else/3"):
        AudioMapping.load(other)
    old = tmp_path / "old.tfmap"  # formats /1 and /2 were a JSON line and a pickle
    old.write_text(json.dumps({"format": "talkingface.mapping/1"}) + "\n")
    with pytest.raises(ParameterError, match=r"saved by an older version that stored Python "
                                             r"objects \(format 'talkingface\.mapping/1'\); "
                                             r"re-train it"):
        AudioMapping.load(old)
    binary = tmp_path / "blob.bin"
    binary.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(ParameterError, match="not a talkingface mapping model"):
        AudioMapping.load(binary)


def test_sample_rates(small_corpus, corpus_model):
    u = small_corpus.utterances[0]
    for bad in (4000, 7999, 192001, 22050.0, "22050"):
        with pytest.raises(ParameterError, match="unsupported sample rate"):
            corpus_model.predict_audio(u.audio, bad)
    with pytest.raises(ParameterError, match="mono"):
        corpus_model.features(np.stack([u.audio, u.audio], 1), u.sample_rate)
    with pytest.raises(ParameterError, match="expression 'angry' is not known to this model"):
        corpus_model.predict_audio(u.audio, u.sample_rate, "angry")
    # The same sound at twice the rate: the same frames, nearly the same features and MUPs.
    base = corpus_model.features(u.audio, u.sample_rate)
    y44 = resample(u.audio, sr_in=u.sample_rate, sr_out=44100)
    f44 = corpus_model.features(y44, 44100)
    assert f44.shape == base.shape
    assert len(corpus_model.predict_audio(y44, 44100)) == len(base)
    assert np.corrcoef(f44.ravel(), base.ravel())[0, 1] > 0.99
    # 16 kHz has no integer hop at 30 fps: the MFCC refuse it, the model resamples it.
    y16 = resample(u.audio, sr_in=u.sample_rate, sr_out=16000)
    with pytest.raises(ParameterError, match="sample rate 16000 Hz has no integer hop"):
        mfcc(y16, sr=16000)
    assert abs(len(corpus_model.features(y16, 16000)) - len(base)) <= 1
