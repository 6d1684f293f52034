"""The measurements of the real speaker's gap (analysis.real_ceiling): Eq. 6 against the
paper's truth and the markers, the normalisation by the largest absolute displacement, the
offset search on a pair with a known lag, the jitter floor and the nested learning-curve
subsets."""
from __future__ import annotations

import numpy as np
import pytest

from analysis.metrics import normalization_scale, pearson_r
from analysis.real_ceiling import (best_offset, curve_projection, nested_subsets, offset_scores,
                                   reconstruction_r, shifted, smoothing_floor, truth_r)
from groundwork.errors import ParameterError


def test_eq6_gives_1_for_a_scaled_copy_and_about_0_for_an_independent_signal():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(4000, 158))
    assert pearson_r(d, 3.0 * d + 2.0) == pytest.approx(1.0)
    assert abs(pearson_r(d, rng.normal(size=d.shape))) < 0.01
    assert pearson_r(d, -d) == pytest.approx(-1.0)


def test_the_normalisation_divides_each_coordinate_by_its_largest_absolute_displacement():
    d = np.array([[1.0, -4.0, 0.0], [-2.0, 2.0, 0.0], [0.5, 1.0, 0.0]])
    assert normalization_scale(d).tolist() == [2.0, 4.0, 1.0]  # a still coordinate: 1
    # so a coordinate that moves little weighs as much as one that moves much
    rng = np.random.default_rng(1)
    big, small = rng.normal(size=(500, 1)) * 50, rng.normal(size=(500, 1)) * 0.1
    truth = np.hstack([big, small])
    est = np.hstack([big, rng.normal(size=(500, 1)) * 0.1])  # the small one wrong
    scale = normalization_scale(truth)
    assert pearson_r(truth, est) > 0.99  # in pixels the small coordinate hardly counts
    assert pearson_r(truth / scale, est / scale) < 0.75  # normalised it counts half


def test_r_against_the_reconstruction_and_against_the_markers():
    rng = np.random.default_rng(2)
    recon = rng.normal(size=(600, 6))
    markers = recon + 0.5 * rng.normal(size=recon.shape)  # what the units do not keep
    out = truth_r(markers, recon, recon.copy())
    assert out["paper"] == pytest.approx(1.0)  # the reconstruction predicted exactly
    assert out["markers"] == pytest.approx(reconstruction_r(markers, recon))
    assert out["markers"] < 0.95
    with pytest.raises(ParameterError, match="must have one shape"):
        truth_r(markers, recon[:10], recon)


def test_shifted_pairs_the_sound_with_the_face_lag_frames_later():
    x = np.arange(10)[:, None].astype(float)
    f, t = shifted(x, x + 100, 2)
    assert f[:, 0].tolist() == list(range(8)) and t[:, 0].tolist() == list(range(102, 110))
    f, t = shifted(x, x + 100, -3)
    assert f[0, 0] == 3 and t[0, 0] == 100 and len(f) == 7
    assert len(shifted(x, x, 10)[0]) == 0


@pytest.mark.parametrize("true_lag", [-2, 0, 3])
def test_the_offset_search_recovers_a_lag_put_into_a_pair(true_lag):
    """The face is a fixed linear function of the audio features ``true_lag`` frames earlier
    (plus noise); the search over -5..5 on 12 sentences finds that lag."""
    rng = np.random.default_rng(7)
    mix = rng.normal(size=(8, 4))
    features, targets = [], []
    for _ in range(12):
        n = int(rng.integers(60, 90))
        x = rng.normal(size=(n, 8))
        y = np.zeros((n, 4))
        src = np.arange(n) - true_lag  # face at t driven by sound at t - lag
        ok = (src >= 0) & (src < n)
        y[ok] = x[src[ok]] @ mix
        features.append(x)
        targets.append(y + 0.3 * rng.normal(size=y.shape))
    scores = offset_scores(features, targets, range(-5, 6), context=0)
    assert best_offset(scores) == true_lag
    assert scores[true_lag] > 0.9 and max(v for k, v in scores.items() if k != true_lag) < 0.5


def test_best_offset_prefers_the_smallest_lag_of_equal_scores_and_refuses_none():
    assert best_offset({-1: 0.5, 0: 0.5, 1: 0.5}) == 0
    assert best_offset({-2: 0.7, 2: 0.7, 0: 0.1}) == -2
    with pytest.raises(ParameterError, match="no lag was scored"):
        best_offset({})


def test_the_smoothing_floor_is_1_for_smooth_motion_and_lower_with_jitter():
    t = np.linspace(0, 4 * np.pi, 400)
    smooth = np.stack([np.sin(t), np.cos(0.5 * t)], axis=1)
    assert smoothing_floor([smooth], 3) > 0.999
    assert smoothing_floor([smooth], 1) == pytest.approx(1.0)  # no smoothing
    rng = np.random.default_rng(3)
    noisy = smooth + 0.5 * rng.normal(size=smooth.shape)
    assert smoothing_floor([noisy], 3) < 0.9
    with pytest.raises(ParameterError, match="window 2: allowed: an odd whole number"):
        smoothing_floor([smooth], 2)


def test_learning_curve_subsets_are_nested_and_seeded():
    ids = [f"u{i:03d}" for i in range(40)]
    a = nested_subsets(ids, [5, 10, 20, 0], seed=11)
    assert [len(a[s]) for s in (5, 10, 20, 0)] == [5, 10, 20, 40]
    assert set(a[5]) <= set(a[10]) <= set(a[20]) <= set(a[0]) == set(ids)
    assert a[10] == sorted(a[10])  # ids keep their order
    assert nested_subsets(ids, [5, 10, 20, 0], seed=11) == a
    assert nested_subsets(ids, [10], seed=12)[10] != a[10]
    assert nested_subsets(ids, [100], seed=1)[100] == ids
    with pytest.raises(ParameterError, match=r"subset sizes \[-1\]"):
        nested_subsets(ids, [-1], seed=1)
    with pytest.raises(ParameterError, match="distinct"):
        nested_subsets(["a", "a"], [1], seed=1)


def test_the_oracle_input_is_one_hot_and_bad_indices_are_refused():
    from analysis.real_ceiling import phone_onehot

    x = phone_onehot(np.array([0, 2, 2, 1]), 3)
    assert x.tolist() == [[1, 0, 0], [0, 0, 1], [0, 0, 1], [0, 1, 0]]
    with pytest.raises(ParameterError, match=r"phone indices must be 1-D in 0..2"):
        phone_onehot(np.array([3]), 3)


def test_region_loadings_say_where_a_unit_moves():
    from analysis.real_ceiling import region_loadings

    c = np.zeros((2, 8))  # 4 markers: region a = markers 0, 1; b = 2, 3
    c[0, [0, 2]] = [0.6, 0.8]  # unit 0: x of markers 0 and 1 -> all in a, all sideways
    c[1, [5, 7]] = [1.0, 1.0]  # unit 1: y of markers 2 and 3 -> all in b, up and down
    rows = region_loadings(c, {"a": range(0, 2), "b": range(2, 4)})
    assert rows[0] == pytest.approx({"a": 1.0, "b": 0.0, "x": 1.0})
    assert rows[1] == pytest.approx({"a": 0.0, "b": 1.0, "x": 0.0})


def test_the_learning_curve_rises_with_data_and_is_seeded():
    """A noisy linear face of 8 features: with 2 sentences of 30 frames the 7-frame context's
    56 weights are poorly fitted, with 20 well; the same seed gives the same curve."""
    from analysis.real_ceiling import learning_curve

    rng = np.random.default_rng(5)
    mix = rng.normal(size=(8, 3))
    feats = [rng.normal(size=(30, 8)) for _ in range(40)]
    targets = [x @ mix + 1.5 * rng.normal(size=(30, 3)) for x in feats]
    curve = learning_curve(feats, targets, [2, 5, 0, 100], seed=3)
    assert list(curve) == [2, 5, 20]  # 0 and 100 mean a whole half: 20 sentences
    assert curve[2] < curve[5] < curve[20]
    assert learning_curve(feats, targets, [2, 5, 0], seed=3) == curve


def test_the_probe_scores_through_a_projection_and_against_given_truths():
    rng = np.random.default_rng(3)
    feats = [rng.normal(size=(60, 4)) for _ in range(6)]
    w = rng.normal(size=(4, 2))
    # two MUPs: the first follows the audio, the second (small) is noise the audio cannot tell
    mups = [np.column_stack([x @ w[:, 0], 0.05 * rng.normal(size=60)]) for x in feats]
    # orthonormal units (2, 6): the first moves coordinates 0-2, the second 3-5
    basis = np.kron(np.eye(2), np.full((1, 3), 3 ** -0.5))
    pixels = offset_scores(feats, mups, [0], project=lambda m: m @ basis)[0]
    # an orthonormal reconstruction keeps Eq. 6's trace: R in pixels is R on the MUPs
    assert pixels == pytest.approx(offset_scores(feats, mups, [0])[0], abs=1e-9)
    # dividing each coordinate by its largest displacement lets the small noisy unit weigh more
    scale = normalization_scale(np.concatenate([m @ basis for m in mups]))
    paper = offset_scores(feats, mups, [0], project=lambda m: m @ basis / scale)[0]
    only_second = offset_scores(feats, [m[:, 1:] for m in mups], [0])[0]
    assert only_second < 0.3 and pixels > 0.99 and 0.4 < paper < 0.6
    # given truths equal to the projected targets score the same as the default
    same = offset_scores(feats, mups, [0], project=lambda m: m @ basis / scale,
                         truths=[m @ basis / scale for m in mups])[0]
    assert same == pytest.approx(paper, abs=1e-12)
    with pytest.raises(ParameterError, match="need as many target sequences"):
        offset_scores(feats, mups, [0], truths=[mups[0]])


def test_the_projection_continues_a_straight_line_in_log_data():
    curve = {25: 0.30, 50: 0.32, 100: 0.34}  # +0.02 per doubling
    proj = curve_projection(curve, 400)
    assert proj["per_doubling"] == pytest.approx(0.02)
    assert proj["r"] == pytest.approx(0.38) and proj["sentences"] == 400
    assert curve_projection({"25": 0.3, "50": 0.32}, 100)["r"] == pytest.approx(0.34)
    with pytest.raises(ParameterError, match="more sentences than measured"):
        curve_projection(curve, 100)
    with pytest.raises(ParameterError, match="two or more sizes"):
        curve_projection({25: 0.3}, 50)
