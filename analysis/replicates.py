"""Seed replicates of an ablation: means, 95 % intervals and paired tests against a reference.

Every setting of an ablation grid is trained with the same seeds (replicate ``k`` of every
setting uses the same split and initialisation seed), so the settings' figures are paired by
seed. :func:`interval` gives a setting's mean and the half-width of its Student-t 95 % interval
over seeds; :func:`paired_tests` compares each setting with the reference setting by a paired
t-test over seeds (scipy's ``ttest_rel``) and corrects the p-values for the number of settings
compared (Holm's step-down method, statsmodels' ``multipletests``).
"""
from __future__ import annotations

import numpy as np
from scipy import stats
from statsmodels.stats.multitest import multipletests


def interval(values, level: float = 0.95) -> tuple[float, float]:
    """``(mean, half-width)`` of the Student-t interval of ``values`` at ``level``; the half-
    width is NaN for fewer than two finite values."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float("nan"), float("nan")
    if v.size < 2:
        return float(v.mean()), float("nan")
    sem = v.std(ddof=1) / np.sqrt(v.size)
    return float(v.mean()), float(stats.t.ppf(0.5 + level / 2, v.size - 1) * sem)


def _paired_p(a: np.ndarray, b: np.ndarray) -> float:
    """Two-sided p of the paired t-test of ``a`` against ``b``; a constant difference is
    certain (p 0 when non-zero, 1 when zero), as the t statistic's limit."""
    d = a - b
    if np.allclose(d, d[0], rtol=0, atol=1e-12):
        return 0.0 if abs(d[0]) > 1e-12 else 1.0
    return float(stats.ttest_rel(a, b).pvalue)


def paired_tests(by_setting: dict, reference: str, *, alpha: float = 0.05) -> dict:
    """Each setting against ``reference``, paired by seed.

    Parameters
    ----------
    by_setting : dict
        ``{setting: {seed: value}}``; only seeds both settings have are paired.
    reference : str
        The setting the others are compared with (the paper's).
    alpha : float
        Family-wise error rate of the Holm correction.

    Returns
    -------
    dict
        ``{setting: {"diff", "n", "p", "p_holm", "differs"}}`` for every other setting with at
        least two paired seeds: the mean difference (setting − reference), the number of pairs,
        the raw and the Holm-corrected p-value, and whether it is below ``alpha``.
    """
    if reference not in by_setting:
        return {}
    ref = by_setting[reference]
    out = {}
    for name, values in by_setting.items():
        common = sorted(set(values) & set(ref))
        a = np.array([values[s] for s in common], dtype=float)
        b = np.array([ref[s] for s in common], dtype=float)
        ok = np.isfinite(a) & np.isfinite(b)
        if name == reference or ok.sum() < 2:
            continue
        out[name] = {"diff": float(np.mean(a[ok] - b[ok])), "n": int(ok.sum()),
                     "p": _paired_p(a[ok], b[ok])}
    if out:
        names = list(out)
        reject, p_holm, _, _ = multipletests([out[n]["p"] for n in names], alpha=alpha,
                                             method="holm")
        for n, r, p in zip(names, reject, p_holm):
            out[n].update(p_holm=float(p), differs=bool(r))
    return out
