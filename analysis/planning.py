"""Simulation from the fitted FLMP/WTAV models: model recovery and the planning of the next
study (:mod:`analysis.perception_models` fits the models).

:func:`simulate_counts` draws participants who answer each of a face's 15 cells once;
:func:`model_recovery` attributes data simulated from each model (default generators: the fits
to the paper's synthetic face) by BIC and by CV; :func:`power_visual_drop` simulates the
visual-only block (assumptions in its text), testing thousands of simulated studies at once
with :func:`analysis.stats.mcnemar_exact` on arrays of counts.
:func:`fit_study` gathers what the report shows of one study's models: the fits and their
comparison, bootstrap intervals and the power of the next study.
"""
from __future__ import annotations

import functools

import numpy as np
import pandas as pd
from scipy import optimize, special

from analysis.perception_models import (
    K,
    L,
    MODELS,
    OWN,
    TAGS,
    FaceCounts,
    FitResult,
    Params,
    bootstrap_intervals,
    check_count,
    check_lam,
    compare_models,
    face_counts,
    fit_model,
    predict,
    seeded_rng,
)
from analysis.stats import mcnemar_exact
from analysis.study_data import PAPER_TALLIES, trials_from_tallies
from groundwork.errors import ParameterError
from study.design import AUDIO, EXPRESSIONS, FACES, RESPONSES


def simulate_counts(model: str, params: Params, n_participants: int, seed) -> FaceCounts:
    """Participants answering one face's 15 cells once each, drawn from ``model``.

    Parameters
    ----------
    model : {"flmp", "wtav"}
    params : Params
        The model's supports (and weight, for WTAV).
    n_participants : int
    seed : int or SeedSequence

    Returns
    -------
    FaceCounts
        One-hot answers: visual (n, 3, 4), audio (n, 3, 4), bimodal (n, 3, 3, 4); participants
        ``S001`` ….
    """
    n = check_count("n_participants", n_participants)
    pred = predict(model, params)
    probs = np.concatenate([pred["visual"], pred["audio"], pred["bimodal"].reshape(-1, K)])
    cum = np.cumsum(probs, -1)
    cum[:, -1] = 1.0
    u = seeded_rng(seed, "sim").random((n, len(probs)))
    onehot = np.eye(K)[(u[..., None] > cum[None]).sum(-1)]
    return FaceCounts(onehot[:, :L], onehot[:, L:2 * L], onehot[:, 2 * L:].reshape(n, L, L, K),
                      tuple(f"S{i + 1:03d}" for i in range(n)))


@functools.lru_cache(maxsize=8)
def paper_fits(face: str = "synthetic", lam: float = 0.05) -> dict[str, FitResult]:
    """Both models fitted to the paper's tallies (Tables III–VII as 20 participants), for
    ``face`` (synthetic or real), with ``lam`` the L2 penalty on the logits; cached."""
    if face not in FACES:
        raise ParameterError(f"face {face!r}; allowed: {', '.join(FACES)}")
    counts = face_counts(trials_from_tallies(PAPER_TALLIES))[face]
    return {m: fit_model(m, counts, lam=lam) for m in MODELS}


def model_recovery(generators: dict | None = None, *, n_sims: int = 10,
                   n_participants: int = 20, lam: float = 0.05, cv: bool = True,
                   seed: int = 0) -> dict:
    """Simulate ``n_sims`` data sets from each model and attribute each by BIC (and LOPO-CV).

    Parameters
    ----------
    generators : dict of str to Params, optional
        The parameters each model simulates from (default: the fits to the paper's synthetic
        face).
    n_sims, n_participants : int
        Data sets per model, and participants per data set.
    lam : float
        The L2 penalty on the logits of every fit.
    cv : bool
        Attribute by leave-one-participant-out CV too (slower).
    seed : int

    Returns
    -------
    dict
        ``confusion[criterion][g][c]``: data from ``MODELS[g]`` attributed to ``MODELS[c]``;
        ``recovered[criterion][model]``: those attributed to the model that made them; and the
        settings.
    """
    n_sims = check_count("n_sims", n_sims)
    gens = generators or {m: f.params for m, f in paper_fits("synthetic", lam).items()}
    children = np.random.SeedSequence([int(seed), TAGS["recovery"]]).spawn(len(MODELS) * n_sims)
    crits = ("bic", "cv") if cv else ("bic",)
    conf = {c: np.zeros((len(MODELS), len(MODELS)), int) for c in crits}
    for g, model in enumerate(MODELS):
        for s in range(n_sims):
            data = simulate_counts(model, gens[model], n_participants, children[g * n_sims + s])
            _, comp = compare_models(data, lam=lam, cv=cv, seed=seed)
            for c in crits:
                conf[c][g, MODELS.index(comp[f"preferred_{c}"])] += 1
    return {"models": list(MODELS), "n_sims": n_sims, "n_participants": n_participants,
            "lam": lam, "seed": seed, "generators": {m: gens[m].to_dict() for m in MODELS},
            "confusion": {c: conf[c].tolist() for c in crits},
            "recovered": {c: {m: int(conf[c][i, i]) for i, m in enumerate(MODELS)}
                          for c in crits}}


def power_visual_drop(drop: float = 0.15, *, n_grid=tuple(range(5, 105, 5)),
                      n_sims: int = 2000, alpha: float = 0.05, target: float = 0.8,
                      base=None, unit: str = "participant", seed: int = 0) -> dict:
    """Power of the paired synthetic-vs-real test of visual-only recognition, by simulation.

    Assumptions: the real face recognises expression j with its fitted own-emotion support
    ``r_j`` (``base``: a FitResult, Params or (3, K) visual supports; default the FLMP fit to
    the paper's real face); the synthetic face has the same supports shrunk toward uniform —
    logits multiplied by one factor t in [0, 1] (t = 0: uniform) — with t chosen so mean
    recognition over the three expressions drops by ``drop``. Each participant sees each
    expression of each face once, independently (no participant differences: real
    participants who differ make S and R correlated and the paired test somewhat stronger).
    Test: ``unit='participant'`` — the exact sign test on participants whose number correct
    (of 3) differs between faces, McNemar's test generalised to three trials;
    ``unit='pair'`` — exact McNemar on (participant, expression) pairs, correct vs not. Two
    sided at ``alpha``. All n of the grid share the simulated participants (the first n of
    n_max).

    Parameters
    ----------
    drop : float
        The drop in mean recognition (a proportion, e.g. 0.15 for 15 points).
    n_grid : iterable of int
        Numbers of participants to compute the power at.
    n_sims : int
        Simulated studies.
    alpha, target : float
        The test's level, and the power wanted.
    base : FitResult, Params or array_like (3, K), optional
        The real face's visual supports.
    unit : {"participant", "pair"}
        What the exact test counts (see above).
    seed : int

    Returns
    -------
    dict
        ``power`` per grid n, ``n_required`` (the smallest grid n from which power stays
        >= ``target``, or None), the recognition rates of both faces, the shrink factor ``t``
        and the settings.

    Raises
    ------
    ParameterError
        An empty grid, an unknown unit, ``alpha`` or ``target`` outside (0, 1), or a drop the
        real face's recognition cannot make.
    """
    n_sims, grid = check_count("n_sims", n_sims), np.array(sorted(set(n_grid)), int)
    if grid.size == 0 or grid[0] < 1:
        raise ParameterError(f"n_grid must hold positive integers, got {n_grid!r}")
    if unit not in ("participant", "pair"):
        raise ParameterError(f"unit {unit!r}; allowed: participant, pair")
    if not (0 < alpha < 1 and 0 < target < 1):
        raise ParameterError(f"alpha and target must lie in (0, 1), got {alpha!r}, {target!r}")
    if base is None:
        base = paper_fits("real")["flmp"]
    v = base.params.visual if isinstance(base, FitResult) else \
        base.visual if isinstance(base, Params) else Params(np.ones((L, K)), base).visual
    log_v, r = np.log(np.maximum(v, 1e-300)), v[np.arange(L), OWN]

    def recog(t):  # own-emotion support with the logits multiplied by t
        return special.softmax(t * log_v, -1)[np.arange(L), OWN]

    if not 0 <= drop < r.mean() - 1 / K:
        raise ParameterError(f"drop must lie in [0, {r.mean() - 1 / K:.3f}) (the real face's "
                             f"mean recognition {r.mean():.3f} minus chance 1/{K}), got {drop!r}")
    t = 1.0 if drop == 0 else optimize.brentq(lambda t: recog(t).mean() - (r.mean() - drop),
                                              0.0, 1.0, xtol=1e-12)
    s = recog(t)
    u = seeded_rng(seed, "power").random((n_sims, int(grid[-1]), 2, L))
    c_s, c_r = u[:, :, 0] < s, u[:, :, 1] < r
    if unit == "participant":
        d = c_s.sum(-1) - c_r.sum(-1)
        worse, better = np.cumsum(d < 0, 1), np.cumsum(d > 0, 1)
    else:
        worse, better = np.cumsum((c_r & ~c_s).sum(-1), 1), np.cumsum((c_s & ~c_r).sum(-1), 1)
    p = mcnemar_exact(worse[:, grid - 1], better[:, grid - 1])["p_exact"]
    power = (p <= alpha).mean(0)
    reach = [i for i in range(grid.size) if (power[i:] >= target).all()]
    return {"drop": float(drop), "shrink_t": float(t), "recognition_real": r.tolist(),
            "recognition_synthetic": s.tolist(), "n_grid": grid.tolist(),
            "power": power.tolist(), "n_required": int(grid[reach[0]]) if reach else None,
            "target": target, "alpha": alpha, "unit": unit, "n_sims": n_sims, "seed": seed}


def fit_study(df: pd.DataFrame, *, lam: float = 0.05, bootstrap: int = 200,
              seed: int = 0) -> dict:
    """Both models for both faces with their comparison (LOPO-CV included), bootstrap
    intervals and the power of the 15-point visual drop from the data's real-face FLMP fit.

    Parameters
    ----------
    df : DataFrame
        Validated judgments (:func:`analysis.study_data.load_study_data`).
    lam : float
        The L2 penalty on the logits.
    bootstrap : int
        Bootstrap resamples of participants (0 skips the intervals).
    seed : int

    Returns
    -------
    dict
        JSON-ready: ``faces`` (each model's fit and their ``comparison``), ``bootstrap``,
        ``power`` (or its ``error``) and the settings.
    """
    lam = check_lam(lam)
    bootstrap = check_count("bootstrap", bootstrap, lo=0)
    counts = face_counts(df)
    fits, faces = {}, {}
    for f in FACES:
        fits[f], comp = compare_models(counts[f], lam=lam, cv=True, seed=seed)
        faces[f] = {**{m: fits[f][m].to_dict() for m in MODELS}, "comparison": comp}
    out = {"lam": lam, "seed": seed, "participants": counts[FACES[0]].n,
           "responses": list(RESPONSES), "audio_levels": list(AUDIO),
           "expressions": list(EXPRESSIONS), "faces": faces,
           "notes": "'not sure' is a 4th category with its own supports; the audio-only cells "
                    "enter both faces' fits (45 df each, the faces' fits are not independent)"}
    if bootstrap:
        out["bootstrap"] = bootstrap_intervals(counts, B=bootstrap, lam=lam, seed=seed,
                                               fits=fits)
    try:
        out["power"] = power_visual_drop(0.15, base=fits["real"]["flmp"], seed=seed)
    except ParameterError as err:  # the real face is recognised too rarely for a 15-point drop
        out["power"] = {"error": str(err)}
    return out
