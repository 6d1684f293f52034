"""The mapping's training database (paper §VI-A, §VII-A): per-utterance arrays and the splits."""
from __future__ import annotations

import numpy as np
import pytest

from face_model.motion_units import fit_corpus_units
from groundwork.errors import ParameterError
from mapping.dataset import SPLITS, UttData, build_dataset, split_masks
from mapping.features import audio_features


def _utt(utt_id, n, *, text="t0", expression="neutral", n_feat=3, n_mups=9):
    """A well-formed utterance of ``n`` frames (contents irrelevant to the splits)."""
    return UttData(utt_id, "s00", expression, text, np.zeros((n, n_feat), np.float32),
                   np.zeros((n, n_mups), np.float32), np.zeros(n, np.int64))


@pytest.fixture
def frame_data():
    """Four utterances of unequal length, 101 frames in all (0.8 · 101 = 80.8 → 81)."""
    return [_utt(f"u{i}", n, text=f"t{i}") for i, n in enumerate((13, 27, 40, 21))]


@pytest.fixture
def sentence_data():
    """Five sentence texts, each spoken in three expressions: 15 utterances."""
    return [_utt(f"{e}_{i}", 20 + 3 * i + j, text=f"sentence {i}", expression=e)
            for j, e in enumerate(("neutral", "smile", "sad")) for i in range(5)]


# -- random_frames ---------------------------------------------------------------------------

def test_random_frames_count_shapes_and_reproducibility(frame_data):
    masks = split_masks(frame_data, "random_frames", train_fraction=0.8, seed=4)
    assert [m.shape for m in masks] == [(d.n_frames,) for d in frame_data]
    assert all(m.dtype == bool for m in masks)
    assert sum(int(m.sum()) for m in masks) == 81  # round(0.8 · 101)
    # Other fractions: exactly round(f · N) frames.
    for f in (0.1, 0.5, 0.63):
        m = split_masks(frame_data, "random_frames", train_fraction=f, seed=4)
        assert sum(int(x.sum()) for x in m) == int(round(f * 101))
    again = split_masks(frame_data, "random_frames", train_fraction=0.8, seed=4)
    assert all(np.array_equal(a, b) for a, b in zip(masks, again))
    other = split_masks(frame_data, "random_frames", train_fraction=0.8, seed=5)
    assert not all(np.array_equal(a, b) for a, b in zip(masks, other))
    assert sum(int(x.sum()) for x in other) == 81


def test_random_frames_puts_neighbouring_frames_on_both_sides(frame_data):
    """The paper's split draws frames, not sentences: utterances hold train and test frames."""
    masks = split_masks(frame_data, "random_frames", train_fraction=0.8, seed=0)
    mixed = [m.any() and not m.all() for m in masks]
    assert sum(mixed) >= 3


# -- utterance (by sentence) -----------------------------------------------------------------

def test_utterance_split_keeps_each_sentence_on_one_side(sentence_data):
    masks = split_masks(sentence_data, "utterance", train_fraction=0.8, seed=1)
    assert [m.shape for m in masks] == [(d.n_frames,) for d in sentence_data]
    side = {}
    for d, m in zip(sentence_data, masks):
        assert m.all() or not m.any(), f"{d.utt_id} is split inside the utterance"
        side.setdefault(d.text, set()).add(bool(m[0]))
    assert all(len(s) == 1 for s in side.values()), side  # no sentence on both sides
    train_texts = [t for t, s in side.items() if s == {True}]
    assert len(train_texts) == 4  # round(0.8 · 5) sentences
    again = split_masks(sentence_data, "utterance", train_fraction=0.8, seed=1)
    assert all(np.array_equal(a, b) for a, b in zip(masks, again))


def test_utterance_split_depends_on_the_seed(sentence_data):
    chosen = {tuple(bool(m[0]) for m in split_masks(sentence_data, "utterance",
                                                    train_fraction=0.6, seed=s))
              for s in range(8)}
    assert len(chosen) > 1  # different seeds choose different sentences


def test_split_errors(frame_data):
    assert SPLITS == ("random_frames", "utterance")
    with pytest.raises(ParameterError, match=r"unknown split 'by_speaker'; allowed: "
                                             r"random_frames, utterance"):
        split_masks(frame_data, "by_speaker")
    for bad in (0.0, 1.0, -0.2, 1.5):
        with pytest.raises(ParameterError, match=r"train_fraction must be in \(0, 1\), got "
                                                 + str(bad)):
            split_masks(frame_data, "random_frames", train_fraction=bad)
        with pytest.raises(ParameterError, match=r"train_fraction must be in \(0, 1\)"):
            split_masks(frame_data, "utterance", train_fraction=bad)
    # One sentence cannot be split by sentence.
    one_text = [_utt(f"u{i}", 10, text="same") for i in range(3)]
    with pytest.raises(ParameterError, match="1 distinct sentences cannot be split"):
        split_masks(one_text, "utterance")


# -- UttData -----------------------------------------------------------------------------------

def test_uttdata_refuses_unequal_lengths():
    with pytest.raises(ParameterError, match=r"utterance u7: features \(10 frames\), MUPs \(9 "
                                             r"frames\) and phone labels \(10 frames\)"):
        UttData("u7", "s00", "neutral", "t", np.zeros((10, 3)), np.zeros((9, 9)),
                np.zeros(10, int))
    with pytest.raises(ParameterError, match=r"utterance u8: features \(10 frames\), MUPs \(10 "
                                             r"frames\) and phone labels \(12 frames\)"):
        UttData("u8", "s00", "neutral", "t", np.zeros((10, 3)), np.zeros((10, 9)),
                np.zeros(12, int))


def test_uttdata_refuses_non_finite_values():
    feats = np.zeros((5, 3))
    feats[2, 1] = np.nan
    with pytest.raises(ParameterError, match="utterance u9: features hold NaN or inf"):
        UttData("u9", "s00", "neutral", "t", feats, np.zeros((5, 9)), np.zeros(5, int))
    mups = np.zeros((5, 9))
    mups[0, 0] = np.inf
    with pytest.raises(ParameterError, match="utterance u9: MUPs hold NaN or inf"):
        UttData("u9", "s00", "neutral", "t", np.zeros((5, 3)), mups, np.zeros(5, int))
    assert _utt("ok", 5).n_frames == 5


# -- build_dataset on a synthetic corpus --------------------------------------------------------

@pytest.fixture(scope="module")
def units_and_defs(small_corpus):
    return fit_corpus_units(small_corpus)


def test_build_dataset_matches_markers_units_and_phones(small_corpus, units_and_defs):
    units, defs = units_and_defs
    data = build_dataset(small_corpus, units)
    assert len(data) == len(small_corpus.utterances) == 12
    for d, u in zip(data, small_corpus.utterances):
        assert (d.utt_id, d.speaker, d.expression, d.text) == (u.utt_id, u.speaker,
                                                               u.expression, u.text)
        n = u.n_frames  # the marker frames
        assert d.n_frames == n
        assert d.features.shape == (n, 10) and d.mups.shape == (n, units.n_mups)
        assert d.phones.shape == (n,)
        assert np.array_equal(d.phones, u.phone_per_frame())
        expected = units.transform(defs[u.utt_id], u.expression)
        np.testing.assert_allclose(d.mups, expected, rtol=1e-5, atol=1e-4 * np.abs(expected).max())
        np.testing.assert_array_equal(
            d.features, audio_features(u.audio, sr=u.sample_rate, fps=u.fps, n_frames=n))
        if u.expression == "neutral":
            assert np.all(d.mups[:, units.n_utterance:] == 0)
        else:
            assert np.abs(d.mups[:, units.n_utterance:]).max() > 0


def test_build_dataset_feature_options(small_corpus, units_and_defs):
    units, _ = units_and_defs
    plain = build_dataset(small_corpus, units)
    rich = build_dataset(small_corpus, units, n_mfcc=6, deltas=True)
    for p, r in zip(plain, rich):
        assert r.features.shape == (p.n_frames, 12)
        np.testing.assert_array_equal(r.features[:, :6], p.features[:, :6])
        np.testing.assert_array_equal(r.mups, p.mups)  # features do not change the targets
