"""The phone-class gate (paper §VI-A): class groupings, the small-class rule and the mixtures."""
from __future__ import annotations

import numpy as np
import pytest

from face_model.phones import PHONES, viseme
from groundwork.errors import NotFittedError, ParameterError
from mapping.phone_gate import PhoneGate, class_groups, confusion, merge_small_classes


# -- class groupings ---------------------------------------------------------------------------

def test_44_classes_are_the_phones():
    g, names, vis = class_groups(44)
    assert g.shape == (44,) and np.array_equal(g, np.arange(44))
    assert names == PHONES and len(vis) == 44
    assert all(v == viseme(p) for p, v in zip(PHONES, vis))


def test_8_groups_are_visemes_other_and_silence():
    g, names, vis = class_groups(8)
    assert g.shape == (44,) and len(names) == len(vis) == 8
    assert set(g.tolist()) == set(range(8))  # every group has phones, every phone a valid group
    assert names == ("i", "a", "o", "f", "u", "m", "other", "sil")
    for p, k in zip(PHONES, g):
        if p == "sil":
            assert names[k] == "sil"
        elif viseme(p) == "neutral":
            assert names[k] == "other"
        else:
            assert names[k] == viseme(p)
    assert names[g[PHONES.index("m")]] == names[g[PHONES.index("p")]] == "m"
    assert names[g[PHONES.index("f")]] == names[g[PHONES.index("v")]] == "f"
    assert names[g[PHONES.index("s")]] == "other"


def test_1_group_is_everything():
    g, names, vis = class_groups(1)
    assert g.shape == (44,) and np.all(g == 0)
    assert names == ("all",) and vis == ("all",)


@pytest.mark.parametrize("n", [0, 2, 7, 43, 45, "44"])
def test_invalid_class_count(n):
    with pytest.raises(ParameterError, match=r"n_classes must be one of \(1, 8, 44\), got "):
        class_groups(n)


# -- the small-class rule ----------------------------------------------------------------------

NAMES = ("a_big", "a_mid", "b_huge", "a_tiny", "c_tiny")
VISEMES = ("a", "a", "b", "a", "c")


def _labels(counts):
    return np.repeat(np.arange(len(counts)), counts)


def test_tiny_class_joins_largest_class_of_its_viseme():
    # b_huge is the largest overall, but a_tiny has big classes of its own viseme.
    target, merges = merge_small_classes(_labels([20, 10, 60, 2, 3]), NAMES, VISEMES, 5)
    assert target[3] == 0  # a_tiny → a_big (largest of viseme a), not b_huge
    assert merges["a_tiny"] == "a_big"


def test_tiny_class_without_big_viseme_mate_joins_largest_overall():
    target, merges = merge_small_classes(_labels([20, 10, 60, 2, 3]), NAMES, VISEMES, 5)
    assert target[4] == 2 and merges["c_tiny"] == "b_huge"
    # Big classes stay themselves and are not listed as merged.
    assert target.tolist() == [0, 1, 2, 0, 2]
    assert merges == {"a_tiny": "a_big", "c_tiny": "b_huge"}


def test_classes_without_frames_are_merged_too_and_ties_go_to_the_first():
    # a_big and a_mid tie at 30: the lower index wins; c_tiny has no frames at all.
    target, merges = merge_small_classes(_labels([30, 30, 0, 1, 0]), NAMES, VISEMES, 5)
    assert target.tolist() == [0, 1, 0, 0, 0]
    assert merges == {"b_huge": "a_big", "a_tiny": "a_big", "c_tiny": "a_big"}


def test_every_merge_target_is_big_enough():
    rng = np.random.default_rng(3)
    for _ in range(20):
        counts = rng.integers(0, 40, size=len(NAMES))
        counts[rng.integers(len(NAMES))] = 40
        labels = _labels(counts)
        target, merges = merge_small_classes(labels, NAMES, VISEMES, 25)
        assert np.all(counts[target] >= 25)
        assert set(merges) == {n for n, c in zip(NAMES, counts) if c < 25}


def test_without_a_big_class_everything_joins_the_largest():
    """A tiny corpus: no class reaches min_frames, so all classes share the largest one."""
    target, merges = merge_small_classes(_labels([20, 10, 60, 2, 3]), NAMES, VISEMES, 100)
    assert target.tolist() == [2, 2, 2, 2, 2]
    assert merges == {n: "b_huge" for n in NAMES if n != "b_huge"}
    target, _ = merge_small_classes(_labels([0, 7, 3, 7, 0]), NAMES, VISEMES, 100)
    assert target.tolist() == [1, 1, 1, 1, 1]  # a tie: the first largest


def test_no_frames_at_all_is_refused():
    with pytest.raises(ParameterError, match="the gate has no training frames at all"):
        merge_small_classes(np.zeros(0, int), NAMES, VISEMES, 5)


# -- the Gaussian-mixture gate ------------------------------------------------------------------

CLASSES = (3, 7, 11)  # labels need not be 0..n-1


def _clusters(rng, n_per_class, centres):
    X = np.concatenate([c + rng.standard_normal((n_per_class, centres.shape[1]))
                        for c in centres])
    y = np.repeat(np.array(CLASSES), n_per_class)
    return X, y


@pytest.fixture
def centres(rng):
    return rng.normal(0, 4, (len(CLASSES), 5))  # ≥ several sd apart in 5-D


def test_gate_recovers_separated_clusters(rng, centres):
    X, y = _clusters(rng, 150, centres)
    gate = PhoneGate(n_components=2, random_state=0).fit(X, y, CLASSES)
    assert list(gate.classes_) == list(CLASSES)
    Xt, yt = _clusters(rng, 100, centres)  # fresh frames
    pred = gate.predict(Xt)
    assert set(np.unique(pred)) <= set(CLASSES)
    assert np.mean(pred == yt) > 0.95
    ll = gate.log_likelihood(Xt)
    assert ll.shape == (len(Xt), len(CLASSES)) and np.all(np.isfinite(ll))
    assert np.array_equal(np.array(CLASSES)[ll.argmax(1)], pred)
    # Each column is the class mixture's own log-density (scikit-learn's score_samples).
    ref = np.stack([g.score_samples(Xt) for g in gate.mixtures_], axis=1)
    np.testing.assert_allclose(ll, ref, rtol=1e-9, atol=1e-8)
    idx = np.searchsorted(CLASSES, yt)
    assert np.array_equal(confusion(idx, np.searchsorted(CLASSES, pred), 3).sum(1),
                          np.bincount(idx, minlength=3))
    assert np.trace(confusion(idx, np.searchsorted(CLASSES, pred), 3)) == np.sum(pred == yt)


@pytest.mark.parametrize("covariance", ["full", "spherical"])
def test_gate_with_other_covariances(rng, centres, covariance):
    X, y = _clusters(rng, 120, centres)
    gate = PhoneGate(n_components=2, covariance_type=covariance).fit(X, y, CLASSES)
    Xt, yt = _clusters(rng, 60, centres)
    ll = gate.log_likelihood(Xt)
    np.testing.assert_allclose(ll, np.stack([g.score_samples(Xt) for g in gate.mixtures_], 1),
                               rtol=1e-9, atol=1e-8)
    assert np.mean(gate.predict(Xt) == yt) > 0.95


def test_gate_is_reproducible(rng, centres):
    X, y = _clusters(rng, 80, centres)
    a = PhoneGate(random_state=5).fit(X, y, CLASSES).log_likelihood(X)
    b = PhoneGate(random_state=5).fit(X, y, CLASSES).log_likelihood(X)
    assert np.array_equal(a, b)


def test_a_single_frame_class_still_gets_a_mixture(rng, centres):
    X, y = _clusters(rng, 60, centres)
    lone = centres.mean(0) + 20.0  # far from everything
    X = np.vstack([X, lone])
    y = np.append(y, 42)
    gate = PhoneGate().fit(X, y, (*CLASSES, 42))
    assert gate.predict(lone[None])[0] == 42
    assert np.mean(gate.predict(X[:-1]) == y[:-1]) > 0.95


def test_unfitted_gate_raises_not_fitted(rng, centres):
    X, _ = _clusters(rng, 10, centres)
    with pytest.raises(NotFittedError, match="PhoneGate is not fitted yet"):
        PhoneGate().log_likelihood(X)
    with pytest.raises(NotFittedError, match="PhoneGate is not fitted yet"):
        PhoneGate().predict(X)


def test_gate_errors(rng, centres):
    X, y = _clusters(rng, 30, centres)
    with pytest.raises(ParameterError, match=r"phone class .*20.* has no frames"):
        PhoneGate().fit(X, y, (*CLASSES, 20))
    bad = X.copy()
    bad[4, 2] = np.nan
    with pytest.raises(ParameterError, match="features hold NaN or inf values"):
        PhoneGate().fit(bad, y, CLASSES)
    gate = PhoneGate().fit(X, y, CLASSES)
    with pytest.raises(ParameterError, match="features hold NaN or inf values"):
        gate.predict(bad)
    with pytest.raises(ParameterError, match="must have the same number of frames"):
        PhoneGate().fit(X, y[:-1], CLASSES)
