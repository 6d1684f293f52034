"""The order effect of the study's SR/RS crossover (paper §VII-C: two groups of ten saw the
faces in opposite orders in the bimodal blocks): Mainland–Gart and Prescott tests of the face
and of the period effect, on a per-period outcome of every participant."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import stats

from analysis.scoring import check_frame, correct
from groundwork.errors import ParameterError
from study.design import AUDIO, EXPRESSIONS, SEQUENCES


def mainland_gart(table) -> dict:
    """Fisher's exact test (two-sided) on a 2×2 table sequence (SR, RS) × which period or face
    won, among participants whose outcomes differ."""
    t = np.asarray(table, dtype=int)
    if t.shape != (2, 2) or (t < 0).any():
        raise ParameterError(f"Mainland–Gart needs a non-negative 2×2 table, got {t.tolist()}")
    if t.sum() == 0:
        return {"table": t.tolist(), "odds_ratio": math.nan, "p": math.nan, "defined": False,
                "reason": "no participant with differing outcomes"}
    res = stats.fisher_exact(t)
    return {"table": t.tolist(), "odds_ratio": float(res.statistic), "p": float(res.pvalue),
            "defined": True, "reason": ""}


def prescott(table, scores=(1, 0, -1)) -> dict:
    """Prescott's test on a 2×3 table sequence × (first better, tie, second better).

    Exact conditional test: given both margins, the first row is multivariate hypergeometric;
    T = Σ scores × first-row counts; p = P(|T − E T| ≥ |t − E T|) (two-sided). The asymptotic
    trend chi-square (1 df) is returned as ``chi2`` and ``p_asymptotic``.
    """
    t = np.asarray(table, dtype=int)
    if t.shape != (2, 3) or (t < 0).any():
        raise ParameterError(f"Prescott's test needs a non-negative 2×3 table, got {t.tolist()}")
    s, col, n1, big_n = np.asarray(scores, float), t.sum(0), int(t[0].sum()), int(t.sum())
    out = {"table": t.tolist(), "statistic": float(t[0] @ s), "p": math.nan,
           "chi2": math.nan, "p_asymptotic": math.nan, "defined": False, "reason": ""}
    if n1 == 0 or n1 == big_n or (col > 0).sum() < 2:
        out["reason"] = "one sequence empty or a single outcome column"
        return out
    mean = n1 * (col @ s) / big_n
    var = n1 * (big_n - n1) / (big_n * (big_n - 1)) * (col @ s**2 - (col @ s) ** 2 / big_n)
    obs, total, p = abs(out["statistic"] - mean), math.comb(big_n, n1), 0.0
    for x0 in range(min(col[0], n1) + 1):
        for x1 in range(min(col[1], n1 - x0) + 1):
            x2 = n1 - x0 - x1
            if x2 > col[2]:
                continue
            if abs(x0 * s[0] + x1 * s[1] + x2 * s[2] - mean) >= obs - 1e-9:
                p += math.comb(col[0], x0) * math.comb(col[1], x1) * math.comb(col[2], x2)
    out.update(p=min(1.0, p / total), defined=True, chi2=float((out["statistic"] - mean) ** 2
               / var) if var > 0 else math.nan)
    out["p_asymptotic"] = float(stats.chi2.sf(out["chi2"], 1)) if var > 0 else math.nan
    return out


def crossover_tests(df: pd.DataFrame, cell=None) -> dict:
    """Order (SR/RS crossover) analysis of the bimodal blocks: face and period effects.

    Outcome per participant and period: the number of face-consistent responses over the 9
    bimodal trials of the period (``cell=None``), or the single trial of ``cell = (expression,
    audio)`` (then the classic binary outcome). The period with more correct responses "wins";
    equal counts are ties. Mainland–Gart: Fisher's exact test on sequence × winning period
    (face effect) and on sequence × winning face (period effect), ties excluded. Prescott: the
    same with the ties as a middle column, exact (see :func:`prescott`).
    """
    check_frame(df)
    bim = df[df["block"] == "bimodal"].copy()
    if cell is not None:
        if (len(cell) != 2 or cell[0] not in EXPRESSIONS or cell[1] not in AUDIO):
            raise ParameterError(f"cell {cell!r}: expected (expression, audio) with expression "
                                 f"in {EXPRESSIONS} and audio in {AUDIO}")
        bim = bim[(bim["expression"] == cell[0]) & (bim["audio"] == cell[1])]
    first = bim["sequence"].map({"SR": "synthetic", "RS": "real"})
    if ((bim["period"].astype(int) == 1) != (bim["face"] == first)).any():
        raise ParameterError("bimodal period 1 must show the sequence's first face (SR: "
                             "synthetic, RS: real); some rows do not")
    bim["correct"] = correct(bim)
    score = bim.pivot_table(index=["participant_id", "sequence"], columns="period",
                            values="correct", aggfunc=["sum", "size"], fill_value=0)
    sizes = score["size"].reindex(columns=[1, 2], fill_value=0)
    if (sizes[1] != sizes[2]).any() or (sizes[1] == 0).any():
        pid = sizes[(sizes[1] != sizes[2]) | (sizes[1] == 0)].index[0][0]
        raise ParameterError(f"participant {pid!r} has unequal or empty bimodal periods")
    diff = np.sign(score["sum"][1] - score["sum"][2]).astype(int)
    seq = diff.index.get_level_values("sequence")
    by_period = np.array([[int(((seq == q) & (diff == v)).sum()) for v in (1, 0, -1)]
                          for q in SEQUENCES])
    by_face = by_period.copy()
    by_face[1] = by_face[1, ::-1]  # RS: period 2 is the synthetic face
    return {"outcome": "correct in cell" if cell else "correct count over 9 trials",
            "cell": cell, "n": int(len(diff)),
            "table_period": by_period.tolist(),  # rows SR, RS; cols p1 better, tie, p2 better
            "table_face": by_face.tolist(),  # rows SR, RS; cols synthetic, tie, real better
            "synthetic_better": int(by_face[:, 0].sum()), "ties": int(by_face[:, 1].sum()),
            "real_better": int(by_face[:, 2].sum()),
            "mainland_gart_face": mainland_gart(by_period[:, [0, 2]]),
            "mainland_gart_period": mainland_gart(by_face[:, [0, 2]]),
            "prescott_face": prescott(by_period), "prescott_period": prescott(by_face)}
