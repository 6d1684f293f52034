"""Statistics of the emotion-perception study (paper §VII-C) that the paper did not report.

Every function takes the validated judgments of :func:`analysis.study_data.load_study_data` (or
counts) and returns numbers in plain dicts or dataclasses; labels and ``method``/``reason``
strings only say which test produced a number.

Scoring (:func:`analysis.scoring.correct`). A response is *correct* when it equals the emotion of
the face's expression (``EMOTION_OF``) in visual-only and bimodal trials — "face-consistent" —
and the sentence's emotion (``AUDIO_EMOTION``) in audio-only trials. "Not sure" is never correct.

Synthetic vs real is a within-participant comparison (every participant judges both faces), so
the cell tests are paired (:func:`paired_cells`): exact and mid-p McNemar on correct-vs-not,
Stuart–Maxwell on the four response categories, and an exact paired permutation test.

Exact paired permutation (:func:`paired_permutation`). Participants whose two outcomes are equal
contribute a zero difference under every sign flip, so enumerating only the ``m`` participants
with unequal outcomes gives the same p value as all 2^n flips. ``scipy.stats.permutation_test``
enumerates when ``m <= max_exact_pairs`` (2^14 flips take a fraction of a second; 2^20 take ~7 s
here); beyond that, integer differences (correctness 0/1, capture counts) use the same exact
sign-flip distribution computed by convolution of the subset sums, and only non-integer
differences fall back to a seeded Monte Carlo permutation test.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import statsmodels.api as sm
import statsmodels.formula.api as smf
from scipy import stats
from statsmodels.stats.contingency_tables import SquareTable
from statsmodels.stats.proportion import proportion_confint
from statsmodels.tools.sm_exceptions import (ConvergenceWarning, PerfectSeparationError,
                                             PerfectSeparationWarning)

from analysis.crossover import crossover_tests
from analysis.scoring import check_frame, correct
from groundwork.errors import ParameterError
from study.design import (
    AUDIO,
    AUDIO_EMOTION,
    EMOTION_OF,
    EXPRESSIONS,
    FACES,
    RESPONSES,
    SEQUENCES,
)

CHANCE_AUDIO = 1 / 3  # three emotions; "not sure" is scored as not correct
_MAX_ABS_COEF = 10.0  # |log-odds| beyond this in a GEE fit signals (quasi-)separation
CELLS = ([("visual", e, "none") for e in EXPRESSIONS]
         + [("bimodal", e, a) for a in AUDIO for e in EXPRESSIONS])  # the paired comparisons
INCONGRUENT = [(e, a) for a in AUDIO for e in EXPRESSIONS if EMOTION_OF[e] != AUDIO_EMOTION[a]]


def wilson(k, n, alpha=0.05) -> tuple[float, float]:
    """Wilson score interval for ``k`` successes of ``n`` (``(nan, nan)`` when ``n`` is 0)."""
    if n < 0 or k < 0 or k > n:
        raise ParameterError(f"wilson needs 0 <= k <= n, got k={k!r}, n={n!r}")
    if not 0 < alpha < 1:
        raise ParameterError(f"alpha {alpha!r} must lie strictly between 0 and 1")
    if n == 0:
        return (math.nan, math.nan)
    lo, hi = proportion_confint(k, n, alpha=alpha, method="wilson")
    return (float(lo), float(hi))


def _pairs(df, block, expression, audio) -> pd.DataFrame:
    """participant × face (synthetic, real) responses of one cell; each face exactly once."""
    sub = df[(df["block"] == block) & (df["expression"] == expression) & (df["audio"] == audio)]
    counts = sub.groupby(["participant_id", "face"]).size().unstack(fill_value=0)
    counts = counts.reindex(index=sorted(df["participant_id"].unique()), columns=list(FACES),
                            fill_value=0)
    bad = counts[(counts != 1).any(axis=1)]
    if len(bad):
        pid = bad.index[0]
        raise ParameterError(f"cell {block}/{expression}/{audio}: participant {pid!r} has "
                             f"{bad.loc[pid].to_dict()} judgments per face; a paired test needs "
                             "exactly one per face")
    return sub.pivot(index="participant_id", columns="face", values="response")[list(FACES)]


def mcnemar_exact(b, c) -> dict:
    """Exact conditional and mid-p McNemar tests from the discordant counts ``b`` and ``c``.

    Given ``n = b + c``, min(b, c) ~ Binomial(n, 1/2) under the null. Exact p = min(1,
    2·P(X ≤ min)); mid-p = 2·P(X ≤ min) − P(X = min), and 1 − P(X = b)/2 when b = c, as defined
    by Fagerland, Lydersen & Laake (2013, BMC Med Res Methodol 13:91, supplement eqs. 1–2).
    No discordant pairs: both p values are 1.

    Parameters
    ----------
    b, c : int or array_like of int
        The discordant counts (e.g. pairs correct on the synthetic face only, and on the real
        face only). Arrays are tested elementwise (broadcast together), e.g. thousands of
        simulated studies at once (:func:`analysis.planning.power_visual_drop`).

    Returns
    -------
    dict
        ``b``, ``c``, ``n_discordant`` (``b + c``), ``p_exact``, ``p_midp``: Python numbers for
        scalar counts, arrays of the broadcast shape for arrays.

    Raises
    ------
    ParameterError
        A negative or non-integer count.
    """
    b_arr, c_arr = np.asarray(b), np.asarray(c)
    if b_arr.ndim == 0 and c_arr.ndim == 0:
        if min(b, c) < 0 or int(b) != b or int(c) != c:
            raise ParameterError(f"discordant counts must be non-negative integers, got b={b!r}, "
                                 f"c={c!r}")
        out = _mcnemar_p(np.asarray(int(b)), np.asarray(int(c)))
        return {"b": int(b), "c": int(c), "n_discordant": int(b + c),
                **{k: float(v) for k, v in out.items()}}
    if b_arr.dtype.kind not in "iu" or c_arr.dtype.kind not in "iu" or (b_arr < 0).any() \
            or (c_arr < 0).any():
        raise ParameterError(f"discordant counts must be non-negative integers, got arrays of "
                             f"{b_arr.dtype} (min {b_arr.min(initial=0)}) and {c_arr.dtype} "
                             f"(min {c_arr.min(initial=0)})")
    return {"b": b_arr, "c": c_arr, "n_discordant": b_arr + c_arr, **_mcnemar_p(b_arr, c_arr)}


def _mcnemar_p(b: np.ndarray, c: np.ndarray) -> dict:
    """``p_exact`` and ``p_midp`` of :func:`mcnemar_exact`, elementwise, for checked counts."""
    n, k = b + c, np.minimum(b, c)
    pmf = stats.binom.pmf(k, n, 0.5)
    cdf2 = 2.0 * stats.binom.cdf(k, n, 0.5)
    tie, none = b == c, n == 0
    exact = np.where(tie, 1.0, np.minimum(1.0, cdf2))
    mid = np.where(none, 1.0, np.where(tie, 1.0 - 0.5 * pmf, cdf2 - pmf))
    return {"p_exact": exact, "p_midp": mid}


def stuart_maxwell(table, labels=RESPONSES) -> dict:
    """Stuart–Maxwell marginal homogeneity of a square table (rows: synthetic, columns: real).

    Categories without discordant pairs (off-diagonal row and column sums 0) are dropped and
    listed in ``dropped``; statsmodels' ``SquareTable(t, shift_zeros=False).homogeneity()`` is
    run on the rest. If the remaining categories split into groups with no discordant pair
    between them (the covariance is then singular), the test is run per group and the
    statistics and degrees of freedom are added (``groups`` lists them). ``defined`` is False
    (statistic and p NaN, ``reason`` says why) without any discordant pair.
    """
    t = np.asarray(table, dtype=float)
    if t.ndim != 2 or t.shape[0] != t.shape[1] or t.shape[0] != len(labels) or (t < 0).any():
        raise ParameterError(f"Stuart–Maxwell needs a non-negative {len(labels)}×{len(labels)}"
                             f" table, got shape {t.shape}")
    off = t - np.diag(np.diag(t))
    keep = [i for i in range(len(t)) if off[i].sum() + off[:, i].sum() > 0]
    out = {"statistic": math.nan, "df": 0, "p": math.nan, "defined": False, "reason": "",
           "categories": tuple(str(labels[i]) for i in keep),
           "dropped": tuple(str(x) for i, x in enumerate(labels) if i not in keep), "groups": ()}
    if not keep:
        out["reason"] = "no discordant pairs"
        return out
    groups, todo = [], set(keep)
    while todo:  # connected groups of the graph "some pair discordant between i and j"
        group, stack = set(), [todo.pop()]
        while stack:
            i = stack.pop()
            group.add(i)
            new = {j for j in todo if off[i, j] + off[j, i] > 0}
            todo -= new
            stack.extend(new)
        groups.append(sorted(group))
    stat, df = 0.0, 0
    for g in groups:
        res = SquareTable(t[np.ix_(g, g)], shift_zeros=False).homogeneity()
        stat, df = stat + float(res.statistic), df + int(res.df)
    out.update(statistic=stat, df=df, p=float(stats.chi2.sf(stat, df)), defined=True,
               groups=tuple(tuple(str(labels[i]) for i in g) for g in groups))
    return out


def _signflip_exact_p(d: np.ndarray) -> float:
    """Two-sided exact sign-flip p value of Σd for non-zero integer differences ``d``."""
    a = np.abs(d).astype(np.int64)
    counts = np.zeros(int(a.sum()) + 1, dtype=np.float64)  # ways to reach each positive sum
    counts[0] = 1.0
    for ai in a:
        counts[ai:] += counts[:-ai].copy()
    probs = counts / counts.sum()
    u_obs = int(a[d > 0].sum())
    p_ge, p_le = probs[u_obs:].sum(), probs[:u_obs + 1].sum()
    return float(min(1.0, 2.0 * min(p_ge, p_le)))


def paired_permutation(x, y, *, seed=None, max_exact_pairs=14, n_resamples=99_999) -> dict:
    """Paired (sign-flip) permutation test of mean(x − y), two-sided (see the module text).

    Returns ``mean_difference`` (over all pairs), ``p``, ``n_pairs``, ``n_nonzero`` and
    ``method``: ``exact-scipy`` (enumeration), ``exact-convolution`` (integer differences) or
    ``monte-carlo`` (seeded by ``seed``; the only route that draws random numbers).
    """
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if x.shape != y.shape or x.ndim != 1 or len(x) == 0:
        raise ParameterError(f"paired samples must be two 1-D arrays of equal non-zero length, "
                             f"got shapes {x.shape} and {y.shape}")
    d = x - y
    nz = d != 0
    out = {"mean_difference": float(d.mean()), "n_pairs": len(d), "n_nonzero": int(nz.sum())}
    m = out["n_nonzero"]
    if m <= 1:  # 0 or 1 non-zero difference: every sign flip is as extreme as the data
        return {**out, "p": 1.0, "method": "exact (fewer than two non-zero differences)"}

    def stat(a, b, axis):
        return np.mean(a - b, axis=axis)

    if m <= max_exact_pairs:
        res = stats.permutation_test((x[nz], y[nz]), stat, permutation_type="samples",
                                     n_resamples=np.inf, vectorized=True)
        return {**out, "p": float(res.pvalue), "method": "exact-scipy"}
    if np.allclose(d, np.round(d)):
        return {**out, "p": _signflip_exact_p(np.round(d[nz]).astype(int)),
                "method": "exact-convolution"}
    res = stats.permutation_test((x[nz], y[nz]), stat, permutation_type="samples",
                                 n_resamples=n_resamples, vectorized=True,
                                 rng=np.random.default_rng(seed))
    return {**out, "p": float(res.pvalue), "method": "monte-carlo"}


def paired_cells(df: pd.DataFrame, *, seed=0, alpha=0.05) -> list[dict]:
    """Synthetic vs real in each visual-only expression and each bimodal (expression, audio).

    One dict per cell: ``n`` pairs, correct counts and Wilson intervals per face, McNemar
    (``b``: synthetic correct and real not; ``c``: the reverse; ``p_exact``, ``p_midp``), the
    Stuart–Maxwell result under ``sm_*`` (``sm_defined``, ``sm_reason``, ``sm_dropped``), and the
    exact paired permutation test of the difference in correctness under ``perm_*``.
    """
    check_frame(df)
    rows = []
    for block, expr, audio in CELLS:
        resp = _pairs(df, block, expr, audio)
        good = resp.eq(EMOTION_OF[expr])
        s, r = good["synthetic"].to_numpy(), good["real"].to_numpy()
        n, ks, kr = len(s), int(s.sum()), int(r.sum())
        row = {"block": block, "expression": expr, "audio": audio, "n": n,
               "correct_synthetic": ks, "correct_real": kr,
               "ci_synthetic": wilson(ks, n, alpha), "ci_real": wilson(kr, n, alpha),
               **mcnemar_exact(int((s & ~r).sum()), int((~s & r).sum()))}
        square = pd.crosstab(pd.Categorical(resp["synthetic"], RESPONSES),
                             pd.Categorical(resp["real"], RESPONSES), dropna=False)
        sm = stuart_maxwell(square.to_numpy())
        row.update({f"sm_{k}": v for k, v in sm.items()})
        perm = paired_permutation(s, r, seed=seed)
        row.update({f"perm_{k}": v for k, v in perm.items()})
        rows.append(row)
    return rows


def audio_vs_chance(df: pd.DataFrame, *, alternative="two-sided", alpha=0.05) -> list[dict]:
    """Binomial test per audio-only sentence of the correct count against ``chance`` = 1/3.

    Chance is a guess among the three emotions; "not sure" stays in ``n`` and counts as not
    correct (conservative for "above chance").
    """
    check_frame(df)
    if alternative not in ("two-sided", "greater", "less"):
        raise ParameterError(f"alternative {alternative!r}; allowed: two-sided, greater, less")
    aud = df[df["block"] == "audio"]
    ok = correct(aud)
    out = []
    for a in AUDIO:
        sel = (aud["audio"] == a).to_numpy()
        n, k = int(sel.sum()), int(ok[sel].sum())
        p = stats.binomtest(k, n, CHANCE_AUDIO, alternative=alternative).pvalue if n else math.nan
        out.append({"audio": a, "emotion": AUDIO_EMOTION[a], "n": n, "correct": k,
                    "not_sure": int((aud["response"][sel] == "not_sure").sum()),
                    "proportion": k / n if n else math.nan, "ci": wilson(k, n, alpha),
                    "chance": CHANCE_AUDIO, "not_sure_counts_as": "incorrect",
                    "alternative": alternative, "p": float(p)})
    return out


@dataclass
class GeeResult:
    """A GEE fit, or ``estimable=False`` with the ``reason`` in words (and no numbers)."""

    estimable: bool
    reason: str = ""
    formula: str = ""
    n_obs: int = 0
    n_clusters: int = 0
    coefficients: dict = field(default_factory=dict)  # name -> estimate, se, lo, hi, p
    face_wald: dict = field(default_factory=dict)  # chi2, df, p over every face term


def _cell_name(factors: list, key) -> str:
    """'real face, smile expression, sequence RS' for one cell of a groupby over factors."""
    words = {"face": "{} face", "expression": "{} expression", "sequence": "sequence {}"}
    values = key if isinstance(key, tuple) else (key,)
    return ", ".join(words[f].format(v) for f, v in zip(factors, values))


def _separation_reason(factors: list, rate: pd.Series, n_cells: int) -> str:
    """The separated cells (face-consistent rate 0 or 1) of a GEE design, in words."""
    cells = " × ".join(factors) + (" cells" if len(factors) > 1 else " levels")
    parts = []
    for value, word in ((1, "all"), (0, "none")):
        names = [_cell_name(factors, k) for k in rate.index[rate == value]]
        if names:
            where = f"{len(names)} of the {n_cells} {cells}" if not parts else len(names)
            parts.append(f"{word} face-consistent in {where} ({'; '.join(names)})")
    return "separation: the bimodal responses were " + ", and ".join(parts)


def gee_face_model(df: pd.DataFrame, *, interactions=True, working="exchangeable",
                   alpha=0.05) -> GeeResult:
    """Logistic GEE of face-consistent bimodal responses on face × expression × sequence.

    Reference levels: real face, neutral expression, SR, so ``face[T.synthetic]`` is the
    synthetic − real log-odds (at neutral/SR when ``interactions``). Clusters are participants,
    covariance ``bias_reduced`` (Mancl–DeRouen, for few clusters). ``face_wald`` jointly tests
    every coefficient involving face. Separation is not fitted: a cell (face × expression ×
    sequence, or a factor level without ``interactions``) whose responses are all correct or
    all not, a missing level, a non-converged fit or |coefficient| > 10 give
    ``estimable=False``.
    """
    check_frame(df)
    structs = {"exchangeable": sm.cov_struct.Exchangeable, "independence":
               sm.cov_struct.Independence}
    if working not in structs:
        raise ParameterError(f"working correlation {working!r}; allowed: {', '.join(structs)}")
    factors = {"face": ["real", "synthetic"], "expression": list(EXPRESSIONS),
               "sequence": list(SEQUENCES)}
    formula = "correct ~ " + (" * " if interactions else " + ").join(factors)
    bim = df[df["block"] == "bimodal"].copy()
    bim["correct"] = correct(bim).astype(float)
    for name, levels in factors.items():
        bim[name] = pd.Categorical(bim[name], categories=levels)
        absent = [v for v in levels if not (bim[name] == v).any()]
        if absent:
            return GeeResult(False, f"no bimodal trials with {name} {' or '.join(absent)}",
                             formula)
    groups = [list(factors)] if interactions else [[f] for f in factors]
    for g in groups:
        rate = bim.groupby(g, observed=True)["correct"].mean()
        sep = rate[(rate == 0) | (rate == 1)]
        if len(sep):
            n_cells = int(np.prod([len(factors[f]) for f in g]))
            return GeeResult(False, _separation_reason(g, sep, n_cells), formula)
    model = smf.gee(formula, groups="participant_id", data=bim, family=sm.families.Binomial(),
                    cov_struct=structs[working]())
    try:
        with warnings.catch_warnings():
            for w in (ConvergenceWarning, PerfectSeparationWarning):
                warnings.simplefilter("error", w)
            with np.errstate(all="ignore"):
                res = model.fit(cov_type="bias_reduced")
    except (ConvergenceWarning, PerfectSeparationWarning, PerfectSeparationError,
            np.linalg.LinAlgError) as exc:
        return GeeResult(False, f"fit failed: {type(exc).__name__}: {exc}", formula)
    params, bse = res.params, res.bse
    if not (np.all(np.isfinite(params)) and np.all(np.isfinite(bse))) or \
            np.abs(params).max() > _MAX_ABS_COEF or not getattr(res, "converged", True):
        return GeeResult(False, "coefficients diverge or are not finite (quasi-separation)",
                         formula)
    ci = res.conf_int(alpha=alpha)
    coefs = {k: {"estimate": float(params[k]), "se": float(bse[k]), "lo": float(ci.loc[k, 0]),
                 "hi": float(ci.loc[k, 1]), "p": float(res.pvalues[k])} for k in params.index}
    face_terms = [k for k in params.index if "face[" in k]
    contrast = np.array([[1.0 if k == t else 0.0 for k in params.index] for t in face_terms])
    wald = res.wald_test(contrast, scalar=True)
    return GeeResult(True, "", formula, int(res.nobs), int(bim["participant_id"].nunique()),
                     coefs, {"terms": face_terms, "chi2": float(wald.statistic),
                             "df": len(face_terms), "p": float(wald.pvalue)})


def visual_capture(df: pd.DataFrame, *, seed=0, alpha=0.05) -> dict:
    """Who wins when face and sentence disagree (the 6 incongruent bimodal cells per face).

    ``per_face[face]``: counts and proportions of responses following the face, following the
    audio, "not sure", and the third emotion, with a Wilson interval for following the face.
    ``paired``: per participant capture count (face-following responses of 6) synthetic − real,
    exact paired permutation (sign-flip; see :func:`paired_permutation`) — preferred to Wilcoxon
    because the differences are a few integers with many ties and zeros.
    """
    check_frame(df)
    cells = INCONGRUENT
    face_em = np.array([EMOTION_OF[e] for e, _ in cells])
    audio_em = np.array([AUDIO_EMOTION[a] for _, a in cells])
    per_face, capture = {}, {}
    for face in FACES:
        resp = pd.concat([_pairs(df, "bimodal", e, a)[face].rename((e, a)) for e, a in cells],
                         axis=1)
        v = resp.to_numpy()
        follows_face, n = v == face_em, v.size
        k = {"follows_face": int(follows_face.sum()), "follows_audio": int((v == audio_em).sum()),
             "not_sure": int((v == "not_sure").sum())}
        k["other_emotion"] = n - sum(k.values())
        per_face[face] = {"n": n, **k, **{f"p_{c}": k[c] / n for c in k},
                          "ci_follows_face": wilson(k["follows_face"], n, alpha)}
        capture[face] = pd.Series(follows_face.sum(1), index=resp.index)
    s, r = capture["synthetic"], capture["real"].reindex(capture["synthetic"].index)
    perm = paired_permutation(s.to_numpy(), r.to_numpy(), seed=seed)
    perm["mean_difference_rate"] = perm["mean_difference"] / len(cells)
    return {"cells": cells, "per_face": per_face, "paired": perm}


@dataclass(frozen=True)
class ConfusionMatrix:
    """Stimulus expression × response counts of one face (and one audio track, or pooled)."""

    face: str
    block: str
    audio: str | None
    counts: np.ndarray
    stimuli: tuple = EXPRESSIONS
    responses: tuple = RESPONSES

    def hit_rates(self) -> list[dict]:
        return unbiased_hit_rates(self.counts, self.stimuli, self.responses)


def confusion_matrices(df: pd.DataFrame, block="visual", audio=None) -> dict:
    """``{face: ConfusionMatrix}`` of the visual-only block, or of the bimodal block for one
    ``audio`` track (``None``: all three pooled)."""
    check_frame(df)
    if block not in ("visual", "bimodal"):
        raise ParameterError(f"block {block!r}; allowed: visual, bimodal")
    if audio is not None and (block != "bimodal" or audio not in AUDIO):
        raise ParameterError(f"audio {audio!r} only with block bimodal; allowed: {AUDIO}")
    sub = df[df["block"] == block]
    if audio is not None:
        sub = sub[sub["audio"] == audio]
    out = {}
    for face in FACES:
        f = sub[sub["face"] == face]
        tab = pd.crosstab(pd.Categorical(f["expression"], EXPRESSIONS),
                          pd.Categorical(f["response"], RESPONSES), dropna=False)
        out[face] = ConfusionMatrix(face, block, audio, tab.to_numpy().astype(int))
    return out


def unbiased_hit_rates(counts, stimuli=EXPRESSIONS, responses=RESPONSES, target=None) -> list:
    """Wagner's (1993) unbiased hit rate per stimulus: Hu = n_ii² / (row total × column total).

    ``counts[i, j]``: stimulus ``stimuli[i]`` answered ``responses[j]``; the hit of a stimulus
    is the response ``target[stimulus]`` (default ``EMOTION_OF``, else the same name). Hu = 0
    without hits, NaN for an unshown stimulus. ``chance`` = (row/N)(column/N), the proportion
    of the hit cell expected if stimulus and response were independent.
    """
    c = np.asarray(counts, dtype=float)
    if c.shape != (len(stimuli), len(responses)) or (c < 0).any():
        raise ParameterError(f"counts must be non-negative, shape {(len(stimuli), len(responses))}"
                             f" (stimuli × responses), got shape {c.shape}")
    target = target or {s: EMOTION_OF.get(s, s) for s in stimuli}
    big_n = c.sum()
    out = []
    for i, s in enumerate(stimuli):
        if target.get(s) not in responses:
            raise ParameterError(f"stimulus {s!r} has no hit response among {responses}")
        j = list(responses).index(target[s])
        hits, row, col = c[i, j], c[i].sum(), c[:, j].sum()
        out.append({"stimulus": s, "response": target[s], "hits": int(hits),
                    "row_total": int(row), "column_total": int(col),
                    "hit_rate": float(hits / row) if row else math.nan,
                    "hu": float(hits * hits / (row * col) if hits else 0.0) if row else math.nan,
                    "chance": float(row * col / big_n**2) if big_n else math.nan})
    return out


def summary(df: pd.DataFrame, seed: int) -> dict:
    """Everything above for a report, with the crossover tests of :mod:`analysis.crossover`.
    ``seed`` reaches the permutation tests; with complete study data every test is exact, so it
    changes nothing unless the Monte Carlo fallback runs."""
    check_frame(df)
    hu = {"visual": {f: m.hit_rates() for f, m in confusion_matrices(df, "visual").items()},
          "bimodal": {f: m.hit_rates() for f, m in confusion_matrices(df, "bimodal").items()}}
    return {"n_participants": int(df["participant_id"].nunique()),
            "sequences": {q: int((df.groupby("participant_id")["sequence"].first() == q).sum())
                          for q in SEQUENCES},
            "paired_cells": paired_cells(df, seed=seed),
            "audio_vs_chance": audio_vs_chance(df),
            "crossover": crossover_tests(df),
            "gee": gee_face_model(df),
            "visual_capture": visual_capture(df, seed=seed),
            "hit_rates": hu}
