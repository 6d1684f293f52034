"""FLMP and WTAV per face (analysis/perception_models.py, analysis/planning.py): the formulas
against hand computations, the fit statistics against direct computations, recovery of the
generating model and of its parameters, seeded bootstrap and power, and refusals of bad input."""
import json

import numpy as np
import pytest
from scipy import stats

from analysis.perception_models import (
    MODELS,
    FaceCounts,
    Params,
    bootstrap_intervals,
    face_counts,
    fit_model,
    g_squared,
    loglik,
    predict,
)
from analysis.planning import (
    fit_study,
    model_recovery,
    paper_fits,
    power_visual_drop,
    simulate_counts,
)
from analysis.stats import mcnemar_exact
from analysis.study_data import PAPER_TALLIES, trials_from_tallies
from groundwork.errors import ParameterError

# A tiny example: rows are the three levels, columns neutral, happy, sad, not sure.
A = np.array([[0.6, 0.2, 0.1, 0.1], [0.25, 0.25, 0.25, 0.25], [0.1, 0.1, 0.7, 0.1]])
V = np.array([[0.5, 0.3, 0.1, 0.1], [0.1, 0.8, 0.05, 0.05], [0.2, 0.2, 0.5, 0.1]])


@pytest.fixture(scope="module")
def paper_df():
    return trials_from_tallies(PAPER_TALLIES)


@pytest.fixture(scope="module")
def paper_counts(paper_df):
    return face_counts(paper_df)


def test_counts_reproduce_the_papers_tables(paper_counts):
    s, r = paper_counts["synthetic"], paper_counts["real"]
    assert s.n == r.n == 20 and s.participants == r.participants
    vis_s, aud, bim_s = s.cells()
    # Table III, S columns (expression × response) and Table IV (sentence × response)
    np.testing.assert_array_equal(vis_s, PAPER_TALLIES["III"][:, 0::2].T)
    np.testing.assert_array_equal(aud, PAPER_TALLIES["IV"].T)
    np.testing.assert_array_equal(r.cells()[1], aud)  # the audio-only cells are shared
    # Table VI: audio "good" with the sad face — 8 (S) and 5 (R) "not sure"
    assert bim_s[1, 2, 3] == 8 and r.cells()[2][1, 2, 3] == 5
    # every participant answers each of the 15 cells once
    assert (s.visual.sum(-1) == 1).all() and (s.bimodal.sum(-1) == 1).all()


def test_flmp_prediction_by_hand():
    p = predict("flmp", Params(A, V))
    # audio 1 with expression 2: a*v = .06, .16, .005, .005; sum .23
    np.testing.assert_allclose(p["bimodal"][0, 1], [0.06 / 0.23, 0.16 / 0.23, 0.005 / 0.23,
                                                    0.005 / 0.23])
    # audio 3 with expression 3: .02, .02, .35, .01; sum .40
    np.testing.assert_allclose(p["bimodal"][2, 2], [0.05, 0.05, 0.875, 0.025])
    # unimodal cells are the normalised supports; a uniform source leaves the other unchanged
    np.testing.assert_allclose(p["visual"], V)
    np.testing.assert_allclose(p["audio"], A)
    np.testing.assert_allclose(p["bimodal"][1], V)
    # supports are only defined up to a factor per level
    np.testing.assert_allclose(predict("flmp", Params(3 * A, 0.5 * V))["bimodal"], p["bimodal"])


def test_wtav_prediction_by_hand():
    p = predict("wtav", Params(A, V, w=0.3))
    # 0.3 * (.6, .2, .1, .1) + 0.7 * (.1, .8, .05, .05)
    np.testing.assert_allclose(p["bimodal"][0, 1], [0.25, 0.62, 0.065, 0.065])
    np.testing.assert_allclose(p["bimodal"].sum(-1), 1.0)
    np.testing.assert_allclose(predict("wtav", Params(A, V, w=1.0))["bimodal"][:, 2], A)
    np.testing.assert_allclose(predict("wtav", Params(A, V, w=0.0))["bimodal"][2], V)


def test_g2_of_a_saturated_model_is_zero():
    rng = np.random.default_rng(np.random.SeedSequence(5))
    cells = (rng.integers(0, 6, (3, 4)), rng.integers(0, 6, (3, 4)), rng.integers(0, 6, (3, 3, 4)))
    cells[2][0, 0] = [0, 0, 0, 7]  # zero counts in a cell
    observed = {k: c / c.sum(-1, keepdims=True) for k, c in zip(("visual", "audio", "bimodal"),
                                                                 cells)}
    assert g_squared(cells, observed) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("model", MODELS)
def test_fit_statistics_match_direct_computations(paper_counts, model):
    fit = fit_model(model, paper_counts["synthetic"])
    cells = paper_counts["synthetic"].cells()
    n = np.concatenate([c.reshape(-1, 4) for c in cells])
    p = np.concatenate([fit.predicted[k].reshape(-1, 4) for k in ("visual", "audio", "bimodal")])
    N = n.sum(1, keepdims=True)
    pos = n > 0
    ll = float(np.sum(n[pos] * np.log(p[pos])))
    assert fit.loglik == pytest.approx(ll, rel=1e-12)
    assert fit.g2 == pytest.approx(2 * np.sum(n[pos] * np.log(n[pos] / (N * p)[pos])), rel=1e-10)
    assert fit.rmsd == pytest.approx(np.sqrt(np.mean((n / N - p) ** 2)), rel=1e-12)
    k = {"flmp": 18, "wtav": 19}[model]
    assert (fit.n_params, fit.df, fit.n_judgments) == (k, 45 - k, 300)
    assert fit.bic == pytest.approx(k * np.log(300) - 2 * ll, rel=1e-12)
    assert fit.converged and np.allclose(p.sum(1), 1.0)


def test_the_penalty_keeps_never_chosen_supports_off_zero(paper_counts):
    loose = fit_model("flmp", paper_counts["real"], lam=0.0)
    tight = fit_model("flmp", paper_counts["real"], lam=5.0)
    # nobody said "happy" to the sad face: without a penalty that support runs to ~0
    assert loose.params.visual[2, 1] < 1e-6 < tight.params.visual[2, 1]
    assert loose.loglik >= tight.loglik


def test_simulated_participants_answer_every_cell_once_and_are_seeded():
    params = Params(A, V, w=0.4)
    a = simulate_counts("wtav", params, 7, seed=3)
    b = simulate_counts("wtav", params, 7, seed=3)
    c = simulate_counts("wtav", params, 7, seed=4)
    assert isinstance(a, FaceCounts) and a.n == 7 and a.bimodal.shape == (7, 3, 3, 4)
    assert all((x.sum(-1) == 1).all() for x in (a.visual, a.audio, a.bimodal))
    np.testing.assert_array_equal(a.bimodal, b.bimodal)
    assert not np.array_equal(a.bimodal, c.bimodal)
    big = simulate_counts("wtav", params, 4000, seed=1).cells()
    np.testing.assert_allclose(big[2] / 4000, predict("wtav", params)["bimodal"], atol=0.03)


def test_model_recovery_attributes_data_to_their_generator():
    """Acceptance: 20 participants like the paper (one judgment per cell each), generators the
    fits to the paper's synthetic face; each model recovered in >= 9 of 10 data sets by BIC and
    by leave-one-participant-out CV (penalised, lam = 0.05)."""
    rec = model_recovery(n_sims=10, n_participants=20, seed=0)
    for crit in ("bic", "cv"):
        conf = np.array(rec["confusion"][crit])
        assert conf.sum(1).tolist() == [10, 10]
        assert rec["recovered"][crit]["flmp"] >= 9 and rec["recovered"][crit]["wtav"] >= 9, \
            (crit, conf)


@pytest.mark.parametrize("model", MODELS)
def test_parameters_come_back_with_many_participants(model):
    truth = paper_fits("synthetic")[model].params
    fit = fit_model(model, simulate_counts(model, truth, 3000, seed=11))
    assert np.abs(fit.params.visual - truth.visual).max() < 0.03
    assert np.abs(fit.params.audio - truth.audio).max() < 0.03
    if model == "wtav":
        assert fit.params.w == pytest.approx(truth.w, abs=0.02)


def test_bootstrap_is_seeded(paper_counts):
    one = bootstrap_intervals(paper_counts, B=4, seed=1)
    again = bootstrap_intervals(paper_counts, B=4, seed=1)
    other = bootstrap_intervals(paper_counts, B=4, seed=2)
    assert json.dumps(one) == json.dumps(again)
    assert json.dumps(one["own_difference"]) != json.dumps(other["own_difference"])
    for m in MODELS:
        d = one["own_difference"][m]["mean"]
        assert d["lo"] <= d["hi"]
    w = one["w"]["synthetic"]
    assert 0 <= w["lo"] <= w["hi"] <= 1


def test_power_is_seeded():
    kw = dict(n_grid=(10, 20, 30), n_sims=300)
    one, again = power_visual_drop(0.15, seed=1, **kw), power_visual_drop(0.15, seed=1, **kw)
    assert one == again
    assert one["power"] != power_visual_drop(0.15, seed=2, **kw)["power"]


def test_power_grows_with_n_and_with_the_drop():
    grid = (10, 20, 40, 80)
    curves = {d: power_visual_drop(d, n_grid=grid, n_sims=1000, seed=0)["power"]
              for d in (0.05, 0.15, 0.3)}
    for power in curves.values():
        assert all(b >= a - 0.03 for a, b in zip(power, power[1:])), power
    for i in range(len(grid)):
        assert curves[0.05][i] <= curves[0.15][i] + 0.03 <= curves[0.3][i] + 0.06
    assert curves[0.3][-1] > 0.95 and curves[0.05][0] < 0.2
    res = power_visual_drop(0.15, n_grid=grid, n_sims=1000, seed=0)
    drop = np.mean(res["recognition_real"]) - np.mean(res["recognition_synthetic"])
    assert drop == pytest.approx(0.15, abs=1e-9)
    assert res["n_required"] == 40  # 20 is too few (power about one half), 40 enough
    null = power_visual_drop(0.0, n_grid=grid, n_sims=1000, seed=0)["power"]
    assert max(null) <= 0.05 + 0.02  # the exact test keeps its level


def test_exact_mcnemar_on_arrays_equals_the_binomial_test():
    """The power simulation tests arrays of counts at once (analysis.stats.mcnemar_exact)."""
    d = np.repeat(np.arange(1, 26), np.arange(2, 27))
    b = np.concatenate([np.arange(k + 1) for k in range(1, 26)])
    p = mcnemar_exact(b, d - b)["p_exact"]
    assert p.shape == b.shape
    for pi, bi, di in zip(p, b, d):
        assert pi == pytest.approx(stats.binomtest(int(bi), int(di), 0.5).pvalue, rel=1e-9,
                                   abs=1e-15)
    assert mcnemar_exact(np.zeros(3, int), np.zeros(3, int))["p_exact"].tolist() == [1.0] * 3


def test_fit_study_for_the_report(paper_df):
    out = fit_study(paper_df, bootstrap=3, seed=0)
    json.dumps(out)  # JSON-ready for analysis.json
    for face in ("synthetic", "real"):
        comp = out["faces"][face]["comparison"]
        assert comp["preferred"] in MODELS and comp["preferred_bic"] in MODELS
        assert set(comp["cv_loglik"]) == set(MODELS)
        assert out["faces"][face]["wtav"]["params"]["w"] is not None
    assert out["bootstrap"]["B"] == 3 and out["power"]["n_required"] is not None


def test_bad_input_is_refused(paper_df, paper_counts):
    with pytest.raises(ParameterError, match="bimodal"):
        fit_study(paper_df[paper_df["block"] != "bimodal"])
    with pytest.raises(ParameterError, match="bimodal judgments of the real face"):
        face_counts(paper_df[~((paper_df["block"] == "bimodal") & (paper_df["face"] == "real"))])
    with pytest.raises(ParameterError, match="audio-only"):
        face_counts(paper_df[paper_df["block"] != "audio"])
    with pytest.raises(ParameterError, match="lam"):
        fit_model("flmp", paper_counts["synthetic"], lam=-0.05)
    with pytest.raises(ParameterError, match="lam"):
        fit_study(paper_df, lam=-1)
    with pytest.raises(ParameterError, match="model 'fuzzy'"):
        fit_model("fuzzy", paper_counts["synthetic"])
    with pytest.raises(ParameterError, match="missing \\['response'\\]"):
        face_counts(paper_df.drop(columns="response"))
    bad = paper_df.copy()
    bad.loc[3, "response"] = "angry"
    with pytest.raises(ParameterError, match="unknown code 'angry'"):
        face_counts(bad)
    with pytest.raises(ParameterError, match="drop"):
        power_visual_drop(0.9)
    with pytest.raises(ParameterError, match="w"):
        predict("wtav", Params(A, V))
    with pytest.raises(ParameterError, match="supports"):
        Params(-A, V)
    with pytest.raises(ParameterError, match="B"):
        bootstrap_intervals(paper_counts, B=0)
    with pytest.raises(ParameterError, match="no bimodal"):
        cells = paper_counts["synthetic"].cells()
        fit_model("wtav", (cells[0], cells[1], np.zeros((3, 3, 4))))
    assert loglik(paper_counts["real"].cells(), predict("flmp", Params(A, V))) < 0
