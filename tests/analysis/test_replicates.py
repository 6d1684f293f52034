"""Means, intervals and paired tests over seed replicates, against hand-computed values."""
import math

import pytest

from analysis.replicates import interval, paired_tests, summarise_replicates


def test_interval_is_the_student_t_interval():
    # [1, 2, 3]: mean 2, sd 1. On 2 df the t CDF is 1/2 + t / (2 sqrt(t^2 + 2)), so its 0.975
    # quantile solves t / sqrt(t^2 + 2) = 0.95: t^2 = 2 * 0.95^2 / (1 - 0.95^2) (≈ 4.3027)
    t = math.sqrt(2 * 0.95**2 / (1 - 0.95**2))
    mean, half = interval([1.0, 2.0, 3.0])
    assert mean == 2.0
    assert half == pytest.approx(t / math.sqrt(3), rel=1e-12)
    # NaNs are dropped; one value has no interval
    mean, half = interval([5.0, float("nan")])
    assert mean == 5.0 and math.isnan(half)
    assert math.isnan(interval([])[0])


def test_paired_tests_pair_by_seed_and_correct_by_holm():
    ref = {1: 0.5, 2: 0.6, 3: 0.7}
    by = {"paper": ref,
          # differences 0.1, 0.2, 0.2: t = 5 on 2 df, two-sided p = 1 - 5 / sqrt(27)
          "a": {1: 0.6, 2: 0.8, 3: 0.9},
          "same": dict(ref),                      # no difference: p = 1
          "shifted": {s: v + 0.1 for s, v in ref.items()},  # a constant difference: p = 0
          "one-seed": {1: 0.9},                   # fewer than two pairs: not tested
          }
    out = paired_tests(by, "paper")
    assert set(out) == {"a", "same", "shifted"}
    p_a = 1 - 5 / math.sqrt(27)
    assert out["a"]["p"] == pytest.approx(p_a, rel=1e-9)
    assert out["a"]["diff"] == pytest.approx(0.5 / 3)
    assert out["same"]["p"] == 1.0 and out["shifted"]["p"] == 0.0
    # Holm: the p-values in order 0, p_a, 1 are multiplied by 3, 2, 1 (kept monotone)
    assert out["shifted"]["p_holm"] == 0.0 and out["shifted"]["differs"]
    assert out["a"]["p_holm"] == pytest.approx(2 * p_a) and not out["a"]["differs"]
    assert out["same"]["p_holm"] == 1.0 and not out["same"]["differs"]
    # seeds pair by their number, not by position
    swapped = paired_tests({"paper": ref, "b": {3: 0.9, 1: 0.6, 2: 0.8}}, "paper")
    assert swapped["b"]["p"] == pytest.approx(p_a, rel=1e-9)
    assert paired_tests(by, "missing") == {}


def test_summary_rows_give_every_figure_its_interval_and_test_r_against_the_reference():
    def rep(setting, seed, r, mse, splits=("utterance",)):
        row = {"setting": setting, "method": "gated_mlp"}
        for s in splits:
            row.update({f"{s}_R": r, f"{s}_MSE": mse})
        return {**row, "replicate": (seed - 2002) // 1000, "seed": seed}

    seeds = (2002, 3002, 4002)
    reps = ([rep("wide", s, r, m) for s, r, m in zip(seeds, (0.6, 0.8, 0.9), (1.0, 2.0, 3.0))]
            # the reference is not the first setting: the tests still compare with it
            + [rep("paper", s, r, 0.5) for s, r in zip(seeds, (0.5, 0.6, 0.7))]
            # a setting evaluated on a second split as well, which the others lack
            + [rep("both", s, 0.5, 0.5, ("utterance", "random_frames")) for s in seeds])
    rows = {r["setting"]: r for r in summarise_replicates(reps, reference="paper")}
    assert list(rows) == ["wide", "paper", "both"]
    wide = rows["wide"]
    assert wide["n_seeds"] == 3 and "seed" not in wide and "replicate" not in wide
    assert wide["utterance_R"] == pytest.approx(2.3 / 3)
    assert wide["utterance_MSE"] == 2.0
    assert wide["utterance_MSE_ci95"] == pytest.approx(interval([1.0, 2.0, 3.0])[1])
    assert wide["utterance_R_ci95"] == pytest.approx(interval([0.6, 0.8, 0.9])[1])
    tests = paired_tests({"paper": {2002: 0.5, 3002: 0.6, 4002: 0.7},
                          "wide": {2002: 0.6, 3002: 0.8, 4002: 0.9},
                          "both": {s: 0.5 for s in seeds}}, "paper")
    assert wide["utterance_R_p_holm"] == pytest.approx(tests["wide"]["p_holm"])
    assert wide["utterance_R_differs"] is tests["wide"]["differs"] is False
    assert rows["paper"]["utterance_R_differs"] == "reference"
    # the split only "both" has: its interval, and no reference to pair with there
    assert rows["both"]["random_frames_R_ci95"] == 0.0
    assert rows["both"]["random_frames_R_differs"] == ""
    assert "random_frames_R_ci95" not in wide
