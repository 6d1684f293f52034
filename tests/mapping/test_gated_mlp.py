"""The paper's mapping (§VI): gate → one MLP per phone class → expression cascade, on synthetic
data whose true mapping is known."""
from __future__ import annotations

import dataclasses
import inspect

import numpy as np
import pytest

from face_model.phones import PHONES
from groundwork.errors import NotFittedError, ParameterError
from mapping.config import TrainSettings
from mapping.dataset import UttData, split_masks
from mapping.gated_mlp import GatedMLP, hidden_units

A0, AK, N_FEAT = 3, 2, 4
# Phone classes of the synthetic speech and how often each is spoken (unequal on purpose, so the
# MLP subsets differ in size). "ih" is rare and shares the viseme of "iy".
SPOKEN = ("iy", "aa", "m", "sil")
FREQ = (0.45, 0.3, 0.15, 0.1)
RARE = "ih"
OFFSET = {"smile": np.array([1.5, -1.0]), "sad": np.array([-1.2, 0.8])}
# Short training of every network: the synthetic mapping is easy.
TRAIN = TrainSettings(max_epochs=200, patience=30)


def synthetic_data(seed: int = 0, n_utt: int = 4, expressions=("neutral", "smile"),
                   n_seg: int = 12, seg_len: int = 7) -> list:
    """Utterances of runs of phones; each phone has its own feature cluster. True MUPs: a known
    nonlinear function of the current frame's features (utterance part), plus an
    expression-dependent offset and a share of the utterance part (expression part)."""
    rng = np.random.default_rng(seed)
    centres = np.random.default_rng(99).normal(0, 3, (len(SPOKEN), N_FEAT))
    W = np.random.default_rng(98).normal(0, 0.6, (N_FEAT, A0))
    data = []
    for e in expressions:
        for i in range(n_utt):
            runs = rng.choice(len(SPOKEN), size=n_seg, p=FREQ)
            k = np.repeat(runs, seg_len)
            feats = centres[k] + rng.standard_normal((len(k), N_FEAT))
            c0 = np.tanh(feats @ W)
            ck = np.zeros((len(k), AK)) if e == "neutral" else OFFSET[e] + 0.5 * c0[:, :AK]
            phones = np.array([PHONES.index(SPOKEN[j]) for j in k])
            if i == 0:  # a few frames of the rare phone, spoken like its viseme mate
                phones[np.flatnonzero(k == 0)[:3]] = PHONES.index(RARE)
            data.append(UttData(f"s0_{e}_{i}", "s0", e, f"sentence {i}", feats.astype(np.float32),
                                np.concatenate([c0, ck], 1).astype(np.float32), phones))
    return data


def gated_mlp(**changes) -> GatedMLP:
    """An untrained GatedMLP for the small synthetic data (A0 utterance MUPs, few gate
    components, small classes allowed), with some hyper-parameters changed."""
    params = dict(n_utterance=A0, min_class_frames=15, gate_components=2, train=TRAIN)
    params.update(changes)
    return GatedMLP(**params)


def predict_all(m, data) -> list:
    return [m.predict(d.features, d.expression) for d in data]


def column_r(data, preds, masks) -> np.ndarray:
    """Pearson R per MUP between predicted and true MUPs over the given frames."""
    t = np.concatenate([d.mups[mk] for d, mk in zip(data, masks)]).astype(np.float64)
    p = np.concatenate([q[mk] for q, mk in zip(preds, masks)]).astype(np.float64)
    return np.array([np.corrcoef(t[:, j], p[:, j])[0, 1] for j in range(t.shape[1])])


@pytest.fixture(scope="module")
def data():
    return synthetic_data()


@pytest.fixture(scope="module")
def masks(data):
    return split_masks(data, "random_frames", train_fraction=0.8, seed=0)


@pytest.fixture(scope="module")
def fitted(data, masks):
    return gated_mlp(random_state=3).fit(data, masks)


# -- recovery -----------------------------------------------------------------------------------

def test_recovers_the_known_mapping_on_training_frames(data, masks, fitted):
    r = column_r(data, predict_all(fitted, data), masks)
    assert r.shape == (A0 + AK,)
    assert np.all(r > 0.9), r


def test_learns_more_than_the_phone_class(data, masks, fitted):
    """Within a phone class the MUPs still vary with the features: the MLPs must model that, so
    they beat even the oracle that outputs each true phone's mean training MUPs."""
    P = np.concatenate([d.phones[mk] for d, mk in zip(data, masks)])
    Y = np.concatenate([d.mups[mk] for d, mk in zip(data, masks)])
    means = {p: Y[P == p].mean(0) for p in np.unique(P)}
    oracle = [np.stack([means[p] for p in d.phones]) for d in data]

    def mse(preds):
        return np.mean(np.concatenate([(q - d.mups)[mk][:, :A0]
                                       for q, d, mk in zip(preds, data, masks)]) ** 2)

    assert mse(predict_all(fitted, data)) < 0.5 * mse(oracle)


def test_recovers_on_held_out_frames(data, masks, fitted):
    test = [~mk for mk in masks]
    r = column_r(data, predict_all(fitted, data), test)
    assert np.all(r > 0.8), r


def test_gate_learns_the_phone_clusters(data, masks, fitted):
    """Frames inside a run of one phone are gated to that phone's class."""
    g = fitted.group_of_phone_
    hits = total = 0
    for d in data:
        gated = fitted.gate_classes(d.features)
        inner = np.ones(d.n_frames, bool)
        inner[1:] &= d.phones[1:] == d.phones[:-1]
        inner[:-1] &= d.phones[:-1] == d.phones[1:]
        hits += np.sum(gated[inner] == g[d.phones[inner]])
        total += inner.sum()
    assert hits / total > 0.9


# -- structure --------------------------------------------------------------------------------

def test_each_frame_is_routed_to_exactly_one_mlp(data, fitted):
    bank = fitted.bank_
    assert set(bank.nets_) == set(fitted.gate_.classes_)
    used = set()
    for d in data[:3]:  # neutral utterances
        classes = fitted.gate_classes(d.features)
        X = fitted.context_.transform(d.features)
        pred = fitted.predict(d.features, "neutral")[:, :A0]
        for c in np.unique(classes):
            rows = classes == c
            used.add(c)
            np.testing.assert_array_equal(pred[rows], bank.nets_[c].predict(X[rows]))
            for other in set(bank.nets_) - {c}:  # any other MLP would give other MUPs
                assert not np.allclose(pred[rows], bank.nets_[other].predict(X[rows]),
                                       atol=1e-3)
    assert len(used) >= 3


def test_neutral_has_zero_expression_mups(data, fitted):
    for d in data:
        p = fitted.predict(d.features, "neutral")
        assert p.shape == (d.n_frames, A0 + AK)
        assert np.all(p[:, A0:] == 0)
    smile = fitted.predict(data[0].features, "smile")
    assert np.abs(smile[:, A0:]).min() > 0.1  # the offset is learnt, not zeroed


def test_rare_class_merges_into_its_viseme_mate(fitted):
    iy, ih = PHONES.index("iy"), PHONES.index("ih")
    assert fitted.merges_[RARE] == "iy"
    assert fitted.group_of_phone_[ih] == iy
    for p in SPOKEN:  # the classes with enough frames stay themselves
        assert p not in fitted.merges_
        assert fitted.group_of_phone_[PHONES.index(p)] == PHONES.index(p)
    assert sorted(fitted.bank_.nets_) == sorted(PHONES.index(p) for p in SPOKEN)
    assert fitted.expressions_ == ("smile",)


def test_hidden_units_grow_with_subset_size():
    assert hidden_units(50, 50, 5000) == 15
    assert hidden_units(5000, 50, 5000) == 25
    sizes = np.unique(np.geomspace(50, 5000, 40).astype(int))
    h = [hidden_units(n, 50, 5000) for n in sizes]
    assert all(a <= b for a, b in zip(h, h[1:]))
    assert all(15 <= x <= 25 for x in h)
    assert hidden_units(500, 50, 5000) == 20  # the log-midpoint
    assert hidden_units(10, 50, 5000) == 15 and hidden_units(10**6, 50, 5000) == 25  # clipped
    assert hidden_units(80, 80, 80) == 25  # one size only
    assert hidden_units(50, 50, 5000, lo=4, hi=9) == 4
    assert hidden_units(5000, 50, 5000, lo=4, hi=9) == 9


def test_bank_hidden_sizes_follow_the_hyper_parameters(data, masks):
    m = gated_mlp(hidden_min=5, hidden_max=12, train=dataclasses.replace(TRAIN, max_epochs=20),
                  random_state=0).fit(data, masks)
    h = m.bank_.hidden_
    assert all(5 <= v <= 12 for v in h.values())
    assert min(h.values()) == 5 and max(h.values()) == 12  # smallest and largest subset
    for c, net in m.bank_.nets_.items():
        assert net.module.net[0].out_features == h[c]
    assert m.experts_["smile"].module.net[0].out_features == m.cascade_hidden


# -- errors -------------------------------------------------------------------------------------

def test_unknown_expression_at_predict(data, fitted):
    with pytest.raises(ParameterError, match=r"expression 'angry' was not trained; allowed: "
                                             r"neutral, smile"):
        fitted.predict(data[0].features, "angry")


def test_untrained_model_refuses(data):
    m = gated_mlp()
    with pytest.raises(NotFittedError, match="GatedMLP is not trained yet"):
        m.predict(data[0].features)
    with pytest.raises(NotFittedError, match="GatedMLP is not trained yet"):
        m.gate_classes(data[0].features)


def test_no_neutral_training_frames(data, masks):
    with pytest.raises(ParameterError, match="needs neutral training frames"):
        gated_mlp().fit(data, [mk & (d.expression != "neutral") for d, mk in zip(data, masks)])
    smile_only = [d for d in data if d.expression == "smile"]
    with pytest.raises(ParameterError, match="needs neutral training frames"):
        gated_mlp().fit(smile_only, [np.ones(d.n_frames, bool) for d in smile_only])


def test_too_few_frames_for_any_class_gives_one_mlp(data, masks):
    """No class reaches min_class_frames: every phone joins the largest class, one MLP."""
    m = gated_mlp(min_class_frames=100000, train=dataclasses.replace(TRAIN, max_epochs=20)).fit(
        data, masks)
    iy = PHONES.index("iy")  # the most frequent phone
    assert np.all(m.group_of_phone_ == iy)
    assert list(m.bank_.nets_) == [iy]
    assert np.all(m.gate_classes(data[0].features) == iy)


# -- the estimator contract (scikit-learn style): store in __init__, check in fit --------------

def test_constructor_stores_its_arguments_verbatim():
    params = dict(n_utterance=5, context_back=2, context_forward=1, n_classes=8,
                  gate_components=3, gate_covariance="full", min_class_frames=11, hidden_min=4,
                  hidden_max=9, expression_model="bank", cascade_hidden=12, cmvn="meanvar",
                  cmvn_warmup_frames=12, gate_front_end="recogniser", mlp_input="phones",
                  phone_training="labels", recogniser="hama",
                  train=TrainSettings(max_epochs=7, patience=3), random_state=42)
    m = GatedMLP(**params)
    for name, value in params.items():
        assert getattr(m, name) is value, name
    assert set(params) == set(inspect.signature(GatedMLP).parameters)  # every parameter checked
    assert not hasattr(m, "bank_")  # nothing learnt before fit


BAD_VALUES = [
    (dict(expression_model="tree"),
     r"expression_model must be one of \('cascade', 'bank'\), got 'tree'"),
    (dict(hidden_min=30, hidden_max=20), r"hidden_min \(30\) must not exceed hidden_max \(20\)"),
    (dict(cascade_hidden=0), r"cascade_hidden must be a positive integer, got 0"),
    (dict(n_utterance=2.5), r"n_utterance must be a positive integer, got 2\.5"),
    (dict(gate_components=True), r"gate_components must be a positive integer, got True"),
    (dict(min_class_frames=-3), r"min_class_frames must be a positive integer, got -3"),
    (dict(n_classes=7), r"n_classes must be one of \(1, 8, 44\), got 7"),
    (dict(mlp_input="lpc"), r"mlp_input must be one of \('mfcc', 'phones'\), got 'lpc'"),
    (dict(phone_training="guess"),
     r"phone_training must be one of \('recognised', 'labels'\), got 'guess'"),
    (dict(mlp_input="phones"),
     r"mlp_input 'phones' needs gate_front_end 'recogniser' \(the phones are the recogniser's\), "
     r"got 'mfcc'"),
]


@pytest.mark.parametrize("changes, message", BAD_VALUES,
                         ids=[",".join(c) for c, _ in BAD_VALUES])
def test_bad_hyper_parameters_are_refused_in_fit(data, masks, changes, message):
    m = gated_mlp(**changes)  # accepted as given ...
    for name, value in changes.items():
        assert getattr(m, name) is value
    with pytest.raises(ParameterError, match=message):  # ... and refused when training starts
        m.fit(data, masks)
    with pytest.raises(NotFittedError, match="GatedMLP is not trained yet"):
        m.predict(data[0].features)


# -- reproducibility and the alternative expression model ---------------------------------------

def test_same_seed_gives_identical_predictions(data, masks, fitted):
    again = gated_mlp(random_state=3).fit(data, masks)
    for d in data:
        np.testing.assert_array_equal(again.predict(d.features, d.expression),
                                      fitted.predict(d.features, d.expression))
    other = gated_mlp(random_state=4).fit(data, masks)
    assert not np.array_equal(other.predict(data[0].features), fitted.predict(data[0].features))


def test_bank_expression_model(data, masks):
    m = gated_mlp(expression_model="bank", random_state=1).fit(data, masks)
    expert = m.experts_["smile"]
    assert set(expert.nets_) == set(m.bank_.nets_)  # the gate and its classes are shared
    r = column_r(data, predict_all(m, data), masks)
    assert np.all(r > 0.9), r
    d = data[-1]  # a smile utterance: estimated by the smile bank, one MLP per gated class
    X, classes = m.context_.transform(d.features), m.gate_classes(d.features)
    pred = m.predict(d.features, "smile")
    assert pred.shape == (d.n_frames, A0 + AK)
    for c in np.unique(classes):
        rows = classes == c
        np.testing.assert_array_equal(pred[rows], expert.nets_[c].predict(X[rows]))
    assert np.all(m.predict(d.features, "neutral")[:, A0:] == 0)
