"""Eqs. 6-8 against independent calculations."""
import numpy as np
import pytest

from analysis.metrics import (
    PAPER_TABLES,
    average_std,
    mse,
    normalization_scale,
    paper_metrics,
    pearson_r,
)
from groundwork.errors import ParameterError


def test_identical_signals_give_r_one_and_zero_mse(rng):
    d = rng.standard_normal((50, 158))
    m = paper_metrics(d, d)
    assert m.R == pytest.approx(1.0, abs=1e-12) and m.MSE == 0.0 and m.nu_d == m.nu_d_est


def test_r_is_invariant_to_a_common_scale_and_offset(rng):
    d = rng.standard_normal((40, 6))
    e = d + 0.5 * rng.standard_normal((40, 6))
    assert pearson_r(3.0 * d + 2.0, 3.0 * e - 1.0) == pytest.approx(pearson_r(d, e), abs=1e-12)
    assert pearson_r(d, -d) == pytest.approx(-1.0, abs=1e-12)


def test_one_dimension_reduces_to_numpy_corrcoef(rng):
    x, y = rng.standard_normal(30), rng.standard_normal(30)
    assert pearson_r(x[:, None], y[:, None]) == pytest.approx(np.corrcoef(x, y)[0, 1], abs=1e-12)


def test_hand_computed_example():
    # d = [[0, 0], [2, 4]], d' = [[1, 0], [1, 2]]  (two frames, two dimensions)
    # centred: d -> ±[1, 2], d' -> ±[0, 1]; trace Cov_dd' = 1*0 + 2*1 = 2 (the same product in
    # both frames); trace Cov_dd = 1 + 4 = 5; trace Cov_d'd' = 0 + 1 = 1
    d = np.array([[0.0, 0.0], [2.0, 4.0]])
    e = np.array([[1.0, 0.0], [1.0, 2.0]])
    assert pearson_r(d, e) == pytest.approx(2 / np.sqrt(5 * 1))
    # nu: std of d's columns = [1, 2] -> 1.5; of d' = [0, 1] -> 0.5
    assert average_std(d) == pytest.approx(1.5) and average_std(e) == pytest.approx(0.5)
    # MSE: frame errors [-1, 0] and [1, 2] -> squared norms 1 and 5, /gamma=2 -> 0.5, 2.5 -> 1.5
    assert mse(d, e) == pytest.approx(1.5)


def test_normalisation_maps_into_unit_range(rng):
    d = rng.standard_normal((100, 158)) * rng.uniform(0.1, 20, 158)
    d[:, 5] = 0.0  # a marker coordinate that never moves
    scale = normalization_scale(d)
    assert np.abs(d / scale).max(0)[np.arange(158) != 5] == pytest.approx(1.0)
    assert scale[5] == 1.0
    m = paper_metrics(d, d * 0.9, scale)
    assert m.R == pytest.approx(1.0) and m.nu_d_est == pytest.approx(0.9 * m.nu_d)


def test_paper_tables_are_transcribed():
    assert PAPER_TABLES["test"]["neutral"][0] == 0.968  # Table II, R, neutral
    assert PAPER_TABLES["train"]["sad"][3] == 0.0033  # Table I, MSE, sad


@pytest.mark.parametrize("d, e, message", [
    (np.zeros((5, 3)), np.zeros((4, 3)), r"one shape .* got \(5, 3\) and \(4, 3\)"),
    (np.zeros((1, 3)), np.zeros((1, 3)), "at least 2 frames"),
    (np.array([[np.nan, 1], [1, 2]]), np.ones((2, 2)), "NaN or inf"),
    (np.ones((3, 2)), np.ones((3, 2)), "R is undefined"),
])
def test_bad_input(d, e, message):
    with pytest.raises(ParameterError, match=message):
        pearson_r(d, e)
