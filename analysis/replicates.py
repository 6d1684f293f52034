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
        ``{setting: {"diff", "diff_ci95", "n", "p", "p_holm", "differs"}}`` for every other
        setting with at least two paired seeds: the mean difference (setting − reference), the
        half-width of its 95 % t-interval over the pairs, the number of pairs, the raw and the
        Holm-corrected p-value, and whether it is below ``alpha``.
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
        out[name] = {"diff": float(np.mean(a[ok] - b[ok])),
                     "diff_ci95": interval(a[ok] - b[ok])[1], "n": int(ok.sum()),
                     "p": _paired_p(a[ok], b[ok])}
    if out:
        names = list(out)
        reject, p_holm, _, _ = multipletests([out[n]["p"] for n in names], alpha=alpha,
                                             method="holm")
        for n, r, p in zip(names, reject, p_holm):
            out[n].update(p_holm=float(p), differs=bool(r))
    return out


INTERVAL_FIGURES = ("R", "MSE", "LVE", "closure")  # per split: the figures given with intervals


def summarise_replicates(reps: list[dict], *, reference: str, key: str = "setting") -> list[dict]:
    """One row per setting (column ``key``) from its replicate rows (one per setting and seed,
    with a ``seed`` column and figures ``<split>_<figure>``).

    A row has the setting's own columns, the mean of every figure over its seeds, ``n_seeds``,
    and for each split the setting was evaluated on: ``<split>_<figure>_ci95``, the half-width of
    the 95 % t-interval of each figure of :data:`INTERVAL_FIGURES` (:func:`interval`), and the
    paired test of R against ``reference`` over their common seeds (:func:`paired_tests`,
    Holm-corrected over the settings of that split): ``<split>_R_diff``, ``<split>_R_diff_ci95``
    (the half-width of the difference's 95 % interval), ``<split>_R_p_holm`` and
    ``<split>_R_differs`` (``True``/``False``, ``reference`` on the reference's row, empty
    when there is nothing to pair with). Settings may differ in their splits and columns.
    """
    names = list(dict.fromkeys(r[key] for r in reps))
    mine = {n: [r for r in reps if r[key] == n] for n in names}
    splits = {n: [k[:-2] for k in rs[0] if k.endswith("_R") and not k.startswith("in_domain")]
              for n, rs in mine.items()}
    tests = {s: paired_tests({n: {r["seed"]: float(r[f"{s}_R"]) for r in mine[n]}
                              for n in names if s in splits[n]}, reference)
             for s in dict.fromkeys(s for ss in splits.values() for s in ss)}
    rows = []
    for n in names:
        row = {k: v for k, v in mine[n][0].items() if k not in ("replicate", "seed")}
        for k, v in row.items():
            if isinstance(v, float):
                vals = np.array([float(r.get(k, np.nan)) for r in mine[n]])
                row[k] = float(vals[np.isfinite(vals)].mean()) if np.isfinite(vals).any() \
                    else float("nan")
        row["n_seeds"] = len(mine[n])
        for s in splits[n]:
            for fig in INTERVAL_FIGURES:
                if f"{s}_{fig}" in row:
                    _, row[f"{s}_{fig}_ci95"] = interval(
                        [float(r.get(f"{s}_{fig}", np.nan)) for r in mine[n]])
            t = tests[s].get(n, {})
            row[f"{s}_R_diff"] = t.get("diff", float("nan"))
            row[f"{s}_R_diff_ci95"] = t.get("diff_ci95", float("nan"))
            row[f"{s}_R_p_holm"] = t.get("p_holm", float("nan"))
            row[f"{s}_R_differs"] = ("reference" if n == reference else
                                     t["differs"] if t else "")
        rows.append(row)
    return rows
