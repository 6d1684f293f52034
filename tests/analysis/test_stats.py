"""analysis.stats against independent computations: scipy/statsmodels called here on the same
numbers, direct binomial and hypergeometric sums, hand-computed tables, and the worked McNemar
example of Fagerland, Lydersen & Laake (2013)."""
import math
from itertools import product

import numpy as np
import pandas as pd
import pytest
import statsmodels.api as sm
import statsmodels.formula.api as smf
from scipy import stats as sps
from statsmodels.stats.contingency_tables import SquareTable, Table, mcnemar
from statsmodels.stats.proportion import proportion_confint

from analysis import crossover, scoring, stats
from analysis.study_data import PAPER_TALLIES, trials_from_tallies
from groundwork.errors import ParameterError
from study.design import AUDIO, EMOTION_OF, EXPRESSIONS, FACES, RESPONSES


@pytest.fixture(scope="module")
def paper_df():
    return trials_from_tallies(PAPER_TALLIES, seed=0)


def _participant(pid, seq, k1, k2):
    """A complete session whose bimodal periods have k1 and k2 face-consistent responses (the
    first k trials of a period in the order audio × expression; the rest 'not_sure')."""
    rows = [("visual", 0, f, e, "none", EMOTION_OF[e]) for f in FACES for e in EXPRESSIONS]
    rows += [("audio", 0, "none", "none", a, r) for a, r in zip(AUDIO, ("neutral", "happy", "sad"))]
    first, second = ("synthetic", "real") if seq == "SR" else ("real", "synthetic")
    for period, face, k in ((1, first, k1), (2, second, k2)):
        for i, (a, e) in enumerate(product(AUDIO, EXPRESSIONS)):
            rows.append(("bimodal", period, face, e, a, EMOTION_OF[e] if i < k else "not_sure"))
    return pd.DataFrame([{"participant_id": pid, "sequence": seq, "block": b, "period": p,
                          "trial_index": i, "face": f, "expression": e, "audio": a,
                          "response": r} for i, (b, p, f, e, a, r) in enumerate(rows)])


def _crossover_df(spec):
    """spec: {sequence: [(k1, k2), ...]} one entry per participant."""
    parts = [_participant(f"{seq}{i}", seq, k1, k2)
             for seq, pairs in spec.items() for i, (k1, k2) in enumerate(pairs)]
    return pd.concat(parts, ignore_index=True)


# --- Wilson ---------------------------------------------------------------------------------

@pytest.mark.parametrize("k,n,alpha", [(0, 20, 0.05), (13, 20, 0.05), (20, 20, 0.05),
                                       (3, 7, 0.1), (50, 120, 0.01)])
def test_wilson_matches_statsmodels(k, n, alpha):
    ref = proportion_confint(k, n, alpha=alpha, method="wilson")
    assert stats.wilson(k, n, alpha) == pytest.approx(ref, abs=1e-14)


def test_wilson_empty_and_invalid():
    lo, hi = stats.wilson(0, 0)
    assert math.isnan(lo) and math.isnan(hi)
    with pytest.raises(ParameterError, match="k=5, n=3"):
        stats.wilson(5, 3)
    with pytest.raises(ParameterError, match="alpha"):
        stats.wilson(1, 3, alpha=1.5)


# --- McNemar --------------------------------------------------------------------------------

def test_mcnemar_fagerland_worked_example():
    """Fagerland, Lydersen & Laake (2013), BMC Med Res Methodol 13:91, Table 1 (Bentur et al.:
    airway hyper-responsiveness before/after stem cell transplantation, 21 children): the
    discordant pairs are 1 and 7. Their supplement's eqs. (1)–(2): exact p = 2·P(X ≤ 1) with
    X ~ Bin(8, 1/2) = 2·9/256 = 18/256; mid-p = 18/256 − P(X = 1) = 18/256 − 8/256 = 10/256."""
    r = stats.mcnemar_exact(1, 7)
    assert r["p_exact"] == pytest.approx(18 / 256, abs=1e-15)
    assert r["p_midp"] == pytest.approx(10 / 256, abs=1e-15)
    assert r["p_exact"] == pytest.approx(mcnemar(np.array([[1, 1], [7, 12]]), exact=True).pvalue)


@pytest.mark.parametrize("b,c", [(b, c) for b in range(0, 9) for c in range(0, 9)] + [(3, 17)])
def test_mcnemar_against_statsmodels_and_binomial_sums(b, c):
    r = stats.mcnemar_exact(b, c)
    assert r["p_exact"] == pytest.approx(mcnemar(np.array([[5, b], [c, 5]]), exact=True).pvalue,
                                         abs=1e-12)
    n, k = b + c, min(b, c)
    if n:
        assert r["p_exact"] == pytest.approx(sps.binomtest(k, n, 0.5).pvalue, abs=1e-12)
    point = math.comb(n, k) / 2**n
    below = sum(math.comb(n, i) for i in range(k + 1)) / 2**n
    expected_mid = 1.0 - 0.5 * point if b == c else 2 * below - point
    assert r["p_midp"] == pytest.approx(expected_mid if n else 1.0, abs=1e-12)
    assert 0 <= r["p_midp"] <= r["p_exact"] <= 1


def test_mcnemar_rejects_negative_counts():
    with pytest.raises(ParameterError, match="b=-1"):
        stats.mcnemar_exact(-1, 3)
    with pytest.raises(ParameterError, match="non-negative integers"):
        stats.mcnemar_exact(np.array([1, -1]), np.array([2, 2]))
    with pytest.raises(ParameterError, match="non-negative integers"):
        stats.mcnemar_exact(np.array([1.5]), np.array([2]))


def test_mcnemar_on_arrays_is_the_scalar_test_elementwise():
    """One test for both uses: a cell's counts (numbers) and thousands of simulated studies
    (arrays, analysis.planning); the arrays' exact p is the binomial sum it was computed with
    in planning, bit for bit."""
    b, c = np.meshgrid(np.arange(0, 30), np.arange(0, 30))
    r = stats.mcnemar_exact(b, c)
    assert r["p_exact"].shape == r["p_midp"].shape == b.shape
    np.testing.assert_array_equal(r["n_discordant"], b + c)
    for i, j in [(0, 0), (3, 3), (1, 7), (7, 1), (0, 29), (12, 17)]:
        one = stats.mcnemar_exact(int(b[i, j]), int(c[i, j]))
        assert (r["p_exact"][i, j], r["p_midp"][i, j]) == (one["p_exact"], one["p_midp"])
    binomial = np.minimum(1.0, 2 * sps.binom.cdf(np.minimum(b, c), b + c, 0.5))
    np.testing.assert_array_equal(r["p_exact"], binomial)


# --- Stuart–Maxwell ------------------------------------------------------------------------

def test_stuart_maxwell_matches_statsmodels_when_every_category_is_discordant():
    t = np.array([[5, 2, 1], [6, 3, 0], [1, 2, 2]])
    r = stats.stuart_maxwell(t, labels=("a", "b", "c"))
    ref = SquareTable(t, shift_zeros=False).homogeneity()
    assert r["defined"] and r["dropped"] == ()
    assert (r["statistic"], r["df"], r["p"]) == pytest.approx((ref.statistic, ref.df, ref.pvalue))


def test_stuart_maxwell_drops_categories_without_discordant_pairs():
    t = np.array([[5, 2, 1, 0], [6, 3, 0, 0], [1, 2, 2, 0], [0, 0, 0, 4]])
    r = stats.stuart_maxwell(t)
    ref = SquareTable(t[:3, :3], shift_zeros=False).homogeneity()
    assert r["dropped"] == ("not_sure",) and r["categories"] == ("neutral", "happy", "sad")
    assert (r["statistic"], r["p"]) == pytest.approx((ref.statistic, ref.pvalue))


def test_stuart_maxwell_on_two_categories_is_uncorrected_mcnemar():
    t = np.zeros((4, 4), int)
    t[0, 0], t[0, 1], t[1, 0], t[1, 1] = 9, 2, 7, 2
    r = stats.stuart_maxwell(t)
    ref = mcnemar(np.array([[9, 2], [7, 2]]), exact=False, correction=False)
    assert r["statistic"] == pytest.approx((7 - 2) ** 2 / 9) == pytest.approx(ref.statistic)
    assert r["p"] == pytest.approx(ref.pvalue)


def test_stuart_maxwell_adds_separate_groups_of_categories():
    """Discordance only neutral↔happy (2 vs 1) and sad↔not sure (3 vs 1): two independent
    McNemar statistics, (2−1)²/3 + (3−1)²/4 = 4/3 on 2 df, p = exp(−2/3) (chi-square, 2 df)."""
    t = np.array([[3, 2, 0, 0], [1, 4, 0, 0], [0, 0, 2, 3], [0, 0, 1, 1]])
    r = stats.stuart_maxwell(t)
    assert r["groups"] == (("neutral", "happy"), ("sad", "not_sure"))
    assert (r["statistic"], r["df"]) == (pytest.approx(4 / 3), 2)
    assert r["p"] == pytest.approx(math.exp(-2 / 3))


def test_stuart_maxwell_undefined_without_discordant_pairs():
    r = stats.stuart_maxwell(np.diag([5, 3, 0, 2]))
    assert not r["defined"] and math.isnan(r["p"]) and "no discordant" in r["reason"]
    with pytest.raises(ParameterError, match="4×4"):
        stats.stuart_maxwell(np.ones((3, 3)))


# --- paired permutation --------------------------------------------------------------------

def _scipy_perm(x, y, n_resamples=np.inf, rng=None):
    return sps.permutation_test((x, y), lambda a, b, axis: np.mean(a - b, axis=axis),
                                permutation_type="samples", n_resamples=n_resamples,
                                vectorized=True, rng=rng).pvalue


def test_permutation_over_discordant_pairs_equals_full_enumeration(rng):
    x = rng.integers(0, 2, 14).astype(float)
    y = rng.integers(0, 2, 14).astype(float)
    r = stats.paired_permutation(x, y)
    assert r["method"] == "exact-scipy" and r["n_nonzero"] < 14
    assert r["p"] == pytest.approx(_scipy_perm(x, y), abs=1e-12)  # all 2^14 flips
    b, c = int(((x == 1) & (y == 0)).sum()), int(((x == 0) & (y == 1)).sum())
    assert r["p"] == pytest.approx(stats.mcnemar_exact(b, c)["p_exact"], abs=1e-12)


def test_convolution_route_equals_scipy_enumeration(rng):
    x = rng.integers(0, 7, 13).astype(float)
    y = rng.integers(0, 7, 13).astype(float)
    y[x == y] += 1  # all differences non-zero integers
    r = stats.paired_permutation(x, y, max_exact_pairs=4)
    assert r["method"] == "exact-convolution"
    assert r["p"] == pytest.approx(_scipy_perm(x, y), abs=1e-12)


def test_monte_carlo_route_is_seeded_and_close_to_exact(rng):
    x, y = rng.normal(0.3, 1, 12), rng.normal(0, 1, 12)
    a = stats.paired_permutation(x, y, seed=7, max_exact_pairs=5, n_resamples=20000)
    b = stats.paired_permutation(x, y, seed=7, max_exact_pairs=5, n_resamples=20000)
    assert a["method"] == "monte-carlo" and a == b
    assert a["p"] == pytest.approx(_scipy_perm(x, y), abs=0.02)


def test_permutation_trivial_and_invalid():
    assert stats.paired_permutation([1, 0, 1], [1, 0, 1])["p"] == 1.0
    assert stats.paired_permutation([1, 0, 1], [0, 0, 1])["p"] == 1.0
    with pytest.raises(ParameterError, match="equal non-zero length"):
        stats.paired_permutation([1, 0], [1])


# --- paired cells on the paper's tallies ---------------------------------------------------

def test_paired_cells_on_paper_tallies(paper_df):
    rows = stats.paired_cells(paper_df, seed=0)
    assert len(rows) == 12
    cols = {"neutral": (0, 1), "smile": (2, 3), "sad": (4, 5)}
    table = {"normal": "V", "good": "VI", "bad": "VII", "none": "III"}
    for r in rows:
        t = PAPER_TALLIES[table[r["audio"]]]
        hit = RESPONSES.index(EMOTION_OF[r["expression"]])
        s_col, r_col = cols[r["expression"]]
        assert (r["n"], r["correct_synthetic"], r["correct_real"]) == \
            (20, t[hit, s_col], t[hit, r_col])
        assert r["b"] - r["c"] == r["correct_synthetic"] - r["correct_real"]
        for key in ("p_exact", "p_midp", "perm_p"):
            assert 0 <= r[key] <= 1
        assert r["perm_p"] == pytest.approx(r["p_exact"], abs=1e-12)  # binary: same test
        if r["n_discordant"]:  # discordant on correctness implies discordant categories
            assert r["sm_defined"]
        if r["sm_defined"]:
            assert 0 <= r["sm_p"] <= 1
            assert r["sm_df"] == len(r["sm_categories"]) - len(r["sm_groups"])
        else:
            assert np.isnan(r["sm_p"]) and r["sm_reason"]
    sad_good = next(r for r in rows if (r["expression"], r["audio"]) == ("sad", "good"))
    assert (sad_good["correct_synthetic"], sad_good["correct_real"]) == (12, 15)


def test_paired_cells_refuse_a_missing_face(paper_df):
    broken = paper_df.drop(paper_df[(paper_df["participant_id"] == "T03")
                                    & (paper_df["block"] == "visual")
                                    & (paper_df["face"] == "real")
                                    & (paper_df["expression"] == "smile")].index)
    with pytest.raises(ParameterError, match="T03"):
        stats.paired_cells(broken)


def test_unknown_codes_and_missing_columns_are_refused(paper_df):
    bad = paper_df.copy()
    bad.loc[0, "response"] = "angry"
    with pytest.raises(ParameterError, match="angry"):
        scoring.correct(bad)
    with pytest.raises(ParameterError, match="sequence"):
        stats.paired_cells(paper_df.drop(columns="sequence"))


# --- audio against chance ------------------------------------------------------------------

def test_audio_vs_chance_matches_scipy_binomtest(paper_df):
    out = stats.audio_vs_chance(paper_df)
    assert [(r["audio"], r["correct"], r["n"]) for r in out] == \
        [("normal", 20, 20), ("good", 13, 20), ("bad", 14, 20)]
    for r in out:
        assert r["chance"] == pytest.approx(1 / 3)
        assert r["p"] == pytest.approx(sps.binomtest(r["correct"], 20, 1 / 3).pvalue)
    greater = stats.audio_vs_chance(paper_df, alternative="greater")[1]
    assert greater["p"] == pytest.approx(sps.binomtest(13, 20, 1 / 3,
                                                       alternative="greater").pvalue)


def test_not_sure_is_not_correct(paper_df):
    df = paper_df.copy()
    i = df.index[(df["block"] == "audio") & (df["audio"] == "normal")][0]
    df.loc[i, "response"] = "not_sure"
    r = stats.audio_vs_chance(df)[0]
    assert (r["correct"], r["not_sure"], r["n"]) == (19, 1, 20)


# --- crossover: Mainland–Gart and Prescott -------------------------------------------------

def test_mainland_gart_on_a_hand_made_crossover():
    # SR: 5 better in period 1 (synthetic), 2 ties, 1 better in period 2 (real);
    # RS: 1 better in period 1 (real), 2 ties, 5 better in period 2 (synthetic).
    spec = {"SR": [(9, 5)] * 5 + [(7, 7)] * 2 + [(5, 9)],
            "RS": [(9, 5)] + [(7, 7)] * 2 + [(5, 9)] * 5}
    r = crossover.crossover_tests(_crossover_df(spec))
    assert r["table_period"] == [[5, 2, 1], [1, 2, 5]]
    assert r["table_face"] == [[5, 2, 1], [5, 2, 1]]
    assert (r["synthetic_better"], r["ties"], r["real_better"]) == (10, 4, 2)
    face = r["mainland_gart_face"]
    assert face["table"] == [[5, 1], [1, 5]]
    # by hand: margins 6/6/6/6 of 12; P(5) = C(6,5)C(6,1)/C(12,6) = 36/924, P(6) = 1/924, and
    # the two tails mirror: p = 2·37/924
    assert face["p"] == pytest.approx(74 / 924)
    assert face["p"] == pytest.approx(sps.fisher_exact([[5, 1], [1, 5]]).pvalue)
    assert r["mainland_gart_period"]["table"] == [[5, 1], [5, 1]]
    assert r["mainland_gart_period"]["p"] == pytest.approx(1.0)


def test_crossover_single_cell_is_binary():
    spec = {"SR": [(9, 0), (9, 0), (0, 9)], "RS": [(0, 9), (9, 9), (0, 0)]}
    r = crossover.crossover_tests(_crossover_df(spec), cell=("neutral", "normal"))
    assert r["table_period"] == [[2, 0, 1], [0, 2, 1]]
    with pytest.raises(ParameterError, match="expression"):
        crossover.crossover_tests(_crossover_df(spec), cell=("angry", "normal"))


def _prescott_reference(table, scores=(1, 0, -1)):
    """Exact conditional p by enumerating first rows with scipy's multivariate hypergeometric."""
    t = np.asarray(table)
    col, n1 = t.sum(0), t[0].sum()
    s = np.asarray(scores, float)
    mean = n1 * (col @ s) / t.sum()
    obs = abs(t[0] @ s - mean)
    p = 0.0
    for x in product(*(range(c + 1) for c in col)):
        if sum(x) == n1 and abs(np.asarray(x) @ s - mean) >= obs - 1e-9:
            p += sps.multivariate_hypergeom.pmf(x, m=col, n=n1)
    return p


@pytest.mark.parametrize("table", [[[5, 2, 1], [1, 2, 5]], [[1, 3, 6], [4, 3, 3]],
                                   [[3, 0, 4], [6, 0, 1]], [[2, 5, 3], [2, 5, 3]]])
def test_prescott_exact_matches_multivariate_hypergeometric(table):
    r = crossover.prescott(table)
    assert r["defined"] and r["p"] == pytest.approx(_prescott_reference(table), abs=1e-12)
    # asymptotic version = statsmodels' linear-by-linear association test, same scores
    ref = Table(np.asarray(table), shift_zeros=False).test_ordinal_association(
        row_scores=np.array([0, 1]), col_scores=np.array([1, 0, -1]))
    assert r["chi2"] == pytest.approx(ref.zscore**2)
    assert r["p_asymptotic"] == pytest.approx(ref.pvalue)


def test_prescott_without_ties_is_a_hypergeometric_test():
    # no ties: T = x − (7 − x) with x ~ Hypergeom(N=14, K=9 period-1 wins, n=7 SR)
    r = crossover.prescott([[3, 0, 4], [6, 0, 1]])
    h = sps.hypergeom(14, 9, 7)
    mean = 7 * 9 / 14
    ref = sum(h.pmf(x) for x in range(0, 8) if abs(x - mean) >= abs(3 - mean) - 1e-9)
    assert r["p"] == pytest.approx(ref, abs=1e-12)


def test_crossover_on_paper_tallies(paper_df):
    r = crossover.crossover_tests(paper_df)
    assert r["n"] == 20 and r["synthetic_better"] + r["ties"] + r["real_better"] == 20
    for key in ("mainland_gart_face", "mainland_gart_period", "prescott_face",
                "prescott_period"):
        assert 0 <= r[key]["p"] <= 1


# --- GEE -----------------------------------------------------------------------------------

def test_gee_matches_a_direct_statsmodels_fit(paper_df):
    res = stats.gee_face_model(paper_df)
    assert res.estimable and res.n_clusters == 20 and res.n_obs == 360
    bim = paper_df[paper_df["block"] == "bimodal"].copy()
    bim["correct"] = (bim["response"] == bim["expression"].map(EMOTION_OF)).astype(float)
    bim["face"] = pd.Categorical(bim["face"], ["real", "synthetic"])
    bim["expression"] = pd.Categorical(bim["expression"], list(EXPRESSIONS))
    bim["sequence"] = pd.Categorical(bim["sequence"], ["SR", "RS"])
    ref = smf.gee("correct ~ face * expression * sequence", groups="participant_id", data=bim,
                  family=sm.families.Binomial(), cov_struct=sm.cov_struct.Exchangeable()
                  ).fit(cov_type="bias_reduced")
    c = res.coefficients["face[T.synthetic]"]
    assert c["estimate"] == pytest.approx(ref.params["face[T.synthetic]"], rel=1e-6)
    assert c["se"] == pytest.approx(ref.bse["face[T.synthetic]"], rel=1e-6)
    assert c["lo"] < c["estimate"] < c["hi"]
    # saturated model: the face coefficient is the logit difference of the neutral/SR cells
    cell = bim[(bim["expression"] == "neutral") & (bim["sequence"] == "SR")]
    p = cell.groupby("face", observed=True)["correct"].mean()
    logit = lambda q: math.log(q / (1 - q))  # noqa: E731
    assert c["estimate"] == pytest.approx(logit(p["synthetic"]) - logit(p["real"]), abs=1e-5)
    assert res.face_wald["df"] == 6 and 0 <= res.face_wald["p"] <= 1


def test_gee_degenerate_designs_are_not_estimable(paper_df):
    everyone_right = paper_df.copy()
    everyone_right["response"] = np.where(everyone_right["block"] == "bimodal",
                                          everyone_right["expression"].map(EMOTION_OF),
                                          everyone_right["response"])
    res = stats.gee_face_model(everyone_right)
    assert not res.estimable and "separation" in res.reason and not res.coefficients
    one_face = paper_df.copy()
    sel = (one_face["block"] == "bimodal") & (one_face["face"] == "real")
    one_face.loc[sel, "response"] = one_face.loc[sel, "expression"].map(EMOTION_OF)
    res = stats.gee_face_model(one_face, interactions=False)
    assert not res.estimable
    assert res.reason == ("separation: the bimodal responses were all face-consistent in 1 of "
                          "the 2 face levels (real face)")
    only_sr = paper_df[paper_df["sequence"] == "SR"]
    res = stats.gee_face_model(only_sr)
    assert not res.estimable and res.reason == "no bimodal trials with sequence RS"
    with pytest.raises(ParameterError, match="ar1"):
        stats.gee_face_model(paper_df, working="ar1")


# --- visual capture ------------------------------------------------------------------------

def test_visual_capture_counts_and_paired_test(paper_df):
    out = stats.visual_capture(paper_df, seed=0)
    table = {"normal": "V", "good": "VI", "bad": "VII"}
    col = {("neutral", "synthetic"): 0, ("neutral", "real"): 1, ("smile", "synthetic"): 2,
           ("smile", "real"): 3, ("sad", "synthetic"): 4, ("sad", "real"): 5}
    audio_em = {"normal": "neutral", "good": "happy", "bad": "sad"}
    for face in FACES:
        face_n = audio_n = 0
        for e, a in out["cells"]:
            t = PAPER_TALLIES[table[a]][:, col[(e, face)]]
            face_n += t[RESPONSES.index(EMOTION_OF[e])]
            audio_n += t[RESPONSES.index(audio_em[a])]
        pf = out["per_face"][face]
        assert (pf["follows_face"], pf["follows_audio"], pf["n"]) == (face_n, audio_n, 120)
    bim = paper_df[paper_df["block"] == "bimodal"]
    inc = bim[bim["expression"].map(EMOTION_OF) != bim["audio"].map(audio_em)]
    follows = inc.assign(f=inc["response"] == inc["expression"].map(EMOTION_OF))
    per = follows.groupby(["participant_id", "face"])["f"].sum().unstack()
    s, r = per["synthetic"].to_numpy(float), per["real"].to_numpy(float)
    ref = _scipy_perm(s[s != r], r[s != r])  # zero differences dropped: see the test above
    assert out["paired"]["p"] == pytest.approx(ref, abs=1e-12)
    assert out["paired"]["mean_difference_rate"] == \
        pytest.approx((per["synthetic"] - per["real"]).mean() / 6)


# --- unbiased hit rate ---------------------------------------------------------------------

def test_unbiased_hit_rate_hand_computed():
    counts = np.array([[8, 1, 1, 0], [2, 6, 0, 2], [0, 0, 9, 1]])
    hu = stats.unbiased_hit_rates(counts)
    # neutral 8²/(10·10); smile→happy 6²/(10·7); sad 9²/(10·10)
    assert [r["hu"] for r in hu] == pytest.approx([0.64, 36 / 70, 0.81])
    assert [r["hit_rate"] for r in hu] == pytest.approx([0.8, 0.6, 0.9])
    assert hu[0]["chance"] == pytest.approx(10 * 10 / 30**2)
    none = stats.unbiased_hit_rates(np.array([[0, 5, 0, 0], [0, 5, 0, 0], [0, 0, 0, 0]]))
    assert none[0]["hu"] == 0.0 and math.isnan(none[2]["hu"])
    with pytest.raises(ParameterError, match="shape"):
        stats.unbiased_hit_rates(np.ones((3, 3)))


def test_confusion_matrices_reproduce_the_paper_tables(paper_df):
    vis = stats.confusion_matrices(paper_df, "visual")
    np.testing.assert_array_equal(vis["synthetic"].counts, PAPER_TALLIES["III"][:, [0, 2, 4]].T)
    np.testing.assert_array_equal(vis["real"].counts, PAPER_TALLIES["III"][:, [1, 3, 5]].T)
    pooled = stats.confusion_matrices(paper_df, "bimodal")["synthetic"].counts
    expected = sum(PAPER_TALLIES[k][:, [0, 2, 4]].T for k in ("V", "VI", "VII"))
    np.testing.assert_array_equal(pooled, expected)
    good = stats.confusion_matrices(paper_df, "bimodal", audio="good")["real"].counts
    np.testing.assert_array_equal(good, PAPER_TALLIES["VI"][:, [1, 3, 5]].T)
    assert vis["real"].hit_rates()[2]["hu"] == pytest.approx(1.0)
    with pytest.raises(ParameterError, match="audio"):
        stats.confusion_matrices(paper_df, "visual", audio="good")


# --- summary -------------------------------------------------------------------------------

def test_summary_runs_and_is_reproducible(paper_df):
    a, b = stats.summary(paper_df, seed=11), stats.summary(paper_df, seed=11)
    assert repr(a) == repr(b)
    assert a["n_participants"] == 20 and a["sequences"] == {"SR": 10, "RS": 10}
    assert len(a["paired_cells"]) == 12 and a["gee"].estimable
