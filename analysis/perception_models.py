"""Models of the emotion judgments (paper §VII-C, Tables III–VII): FLMP and WTAV, per face.

Data of one face: the visual-only judgments of its three expressions (Table III), the
audio-only judgments of the three sentences (Table IV) and its bimodal judgments,
sentence × expression (Tables V–VII) — 15 cells.

Choices
-------
* **"Not sure" is a fourth response category** (K = 4: neutral, happy, sad, not sure) with its
  own support at every audio and visual level, in both models alike. Neither model has a way
  to say "not sure" only when the sources disagree (Tables VI–VII), so those answers are a
  misfit both models share (it raises the G² and RMSD of both).
* **The audio-only cells enter each face's fit in full.** They are shared by the faces, so
  each fit has 15 cells × (K − 1) = 45 df against 18 (FLMP) or 19 (WTAV) parameters; the
  two faces' log-likelihoods are therefore not independent and are never added.
* **Supports are normalised per level** (each row sums to 1), so a unimodal prediction is the
  support itself: ``P(k|A_i) = a_ik``, ``P(k|V_j) = v_jk``. Bimodal cells:

  - FLMP: ``P(k|A_i, V_j) = a_ik v_jk / Σ_m a_im v_jm``;
  - WTAV: ``P(k|A_i, V_j) = w a_ik + (1 − w) v_jk`` (``w`` the weight of the audio).

* **Fitting**: multinomial maximum likelihood with a Normal(0, 1/λ) prior on every logit:
  ``a_i = softmax(α_i)``, ``v_j = softmax(β_j)`` (K logits per level), ``w = logistic(η)``;
  maximise ``Σ n log p − (λ/2)(‖α‖² + ‖β‖² + η²)`` with L-BFGS-B and analytic gradients.
  The penalty (default λ = 0.05, a prior sd of 4.5 logits) keeps the support of a response
  nobody chose finite — unpenalised, its logit runs to −∞ and a held-out participant who does
  choose it gets log-likelihood −∞, which makes cross-validation pick the wrong model — and
  fixes the centred logits among the shift-equivalent ones, so K − 1 parameters per level are
  counted. The FLMP is log-linear (strictly concave objective, one optimum); the WTAV is a
  mixture, so several deterministic starts are tried (the empirical unimodal proportions,
  then seeded perturbations with spread-out weights) and the best kept.
* **Statistics**: log-likelihoods are the multinomial kernel ``Σ n log p`` (no multinomial
  coefficient; it is the same for both models); ``G² = 2 Σ n log(n / (N p))`` against the
  saturated model; RMSD over all cells × K proportions; ``BIC = k log N − 2 log L`` with N the
  judgments of the face's fit (300 for 20 participants); df = cells × (K − 1) − k.
* **Comparison**: RMSD, G², BIC and leave-one-participant-out cross-validation (the held-out
  participant's log-likelihood under the fit to the others, summed). ``preferred`` is the
  cross-validation's choice; BIC's is reported beside it.
* **Bootstrap**: participants resampled with replacement (the same draw for both faces, so
  the synthetic − real difference keeps the pairing); percentile intervals of the visual
  supports, of the WTAV weight, and of the difference synthetic − real of each expression's
  own-emotion visual support — the model-based form of the paper's "comparable". A cell in
  which every participant gave the same answer does not vary under resampling: its interval
  reflects λ only and is too narrow.
* **Simulation and planning**: :mod:`analysis.planning` (model recovery, power, and
  :func:`~analysis.planning.fit_study`, the models of one study for the report).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import optimize, special

from groundwork.errors import ParameterError
from groundwork.numerics import one_blas_thread
from study.design import AUDIO, EMOTION_OF, EXPRESSIONS, FACES, RESPONSES

MODELS = ("flmp", "wtav")
K = len(RESPONSES)
L = 3  # levels of each source: sentences AUDIO, expressions EXPRESSIONS
OWN = np.array([RESPONSES.index(EMOTION_OF[e]) for e in EXPRESSIONS])  # own emotion per expr.
N_PARAMS = {"flmp": 2 * L * (K - 1), "wtav": 2 * L * (K - 1) + 1}
BOUND = 30.0  # |logit| bound (only reached without a penalty)
TAGS = {"start": 11, "boot": 12, "sim": 13, "recovery": 14, "power": 15}
_BLOCKS = ("visual", "audio", "bimodal")
# These problems are tiny: OpenBLAS threads inside L-BFGS-B make a fit ~100x slower on a
# busy machine, so every optimisation runs with BLAS limited to one thread.


def seeded_rng(seed, tag: str) -> np.random.Generator:
    if isinstance(seed, np.random.SeedSequence):
        return np.random.default_rng(seed)
    return np.random.default_rng(np.random.SeedSequence([int(seed), TAGS[tag]]))


def _check_model(model) -> str:
    if model not in MODELS:
        raise ParameterError(f"model {model!r} is not known; allowed: {', '.join(MODELS)}")
    return model


def check_lam(lam) -> float:
    if isinstance(lam, bool) or not isinstance(lam, (int, float, np.integer, np.floating)) \
            or not np.isfinite(lam) or lam < 0:
        raise ParameterError(f"lam (the L2 penalty on the logits) must be a finite number "
                             f">= 0, got {lam!r}")
    return float(lam)


def check_count(name, value, lo=1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo:
        raise ParameterError(f"{name} must be an integer >= {lo}, got {value!r}")
    return int(value)


@dataclass(frozen=True)
class Params:
    """Supports ``audio[i, k]`` (sentences AUDIO), ``visual[j, k]`` (expressions EXPRESSIONS),
    responses RESPONSES, each row normalised to 1; ``w`` the WTAV audio weight (None: FLMP)."""

    audio: np.ndarray
    visual: np.ndarray
    w: float | None = None

    def __post_init__(self):
        for name in ("audio", "visual"):
            s = np.array(getattr(self, name), float)
            if s.shape != (L, K) or not np.isfinite(s).all() or (s < 0).any() \
                    or (s.sum(1) <= 0).any():
                raise ParameterError(f"{name} supports must be a {L}x{K} array of finite "
                                     f"values >= 0 with positive row sums, got {s.tolist()}")
            object.__setattr__(self, name, s / s.sum(1, keepdims=True))
        if self.w is not None and not 0 <= float(self.w) <= 1:
            raise ParameterError(f"the WTAV weight w must lie in [0, 1], got {self.w!r}")

    def own_visual(self) -> np.ndarray:
        """Each expression's support of its own emotion (= predicted visual-only recognition)."""
        return self.visual[np.arange(L), OWN]

    def to_dict(self) -> dict:
        return {"audio": self.audio.tolist(), "visual": self.visual.tolist(),
                "w": None if self.w is None else float(self.w)}


@dataclass(frozen=True)
class FaceCounts:
    """One face's judgments per participant: ``visual[p, j, k]``, ``audio[p, i, k]``,
    ``bimodal[p, i, j, k]`` (i sentence, j expression, k response)."""

    visual: np.ndarray
    audio: np.ndarray
    bimodal: np.ndarray
    participants: tuple = ()

    @property
    def n(self) -> int:
        return self.visual.shape[0]

    def cells(self, weights=None) -> tuple:
        """Pooled counts (visual, audio, bimodal); ``weights`` multiplies each participant."""
        arrays = (self.visual, self.audio, self.bimodal)
        if weights is None:
            return tuple(a.sum(0) for a in arrays)
        return tuple(np.tensordot(np.asarray(weights, float), a, 1) for a in arrays)

    def participant(self, p: int) -> tuple:
        return self.visual[p], self.audio[p], self.bimodal[p]


def face_counts(df: pd.DataFrame) -> dict[str, FaceCounts]:
    """Per-participant counts of each face (``FACES``) from judgments (one row each)."""
    need = ("participant_id", "block", "face", "expression", "audio", "response")
    if not isinstance(df, pd.DataFrame):
        raise ParameterError(f"study data must be a pandas DataFrame, got {type(df).__name__}")
    missing = [c for c in need if c not in df.columns]
    if missing or len(df) == 0:
        raise ParameterError(f"study data need rows and the columns {list(need)}; "
                             + (f"missing {missing}" if missing else "the table is empty"))
    code = {}
    for col, allowed in (("block", _BLOCKS), ("face", (*FACES, "none")),
                         ("expression", (*EXPRESSIONS, "none")), ("audio", (*AUDIO, "none")),
                         ("response", RESPONSES)):
        idx = df[col].map({v: i for i, v in enumerate(allowed)})
        if idx.isna().any():
            raise ParameterError(f"column {col!r}: unknown code {df.loc[idx.isna(), col].iloc[0]!r}"
                                 f"; allowed: {', '.join(allowed)}")
        code[col] = idx.to_numpy(int)
    b, f, e, a, r = (code[c] for c in ("block", "face", "expression", "audio", "response"))
    bad = ((b == 0) & ((f == 2) | (e == 3) | (a != 3))) | ((b == 1) & ((f != 2) | (a == 3))) \
        | ((b == 2) & ((f == 2) | (e == 3) | (a == 3)))
    if bad.any():
        row = df.iloc[int(np.argmax(bad))]
        raise ParameterError(f"a {row['block']} judgment with face {row['face']!r}, "
                             f"expression {row['expression']!r}, audio {row['audio']!r} "
                             "contradicts the design")
    pids, p = np.unique(df["participant_id"].astype(str).to_numpy(), return_inverse=True)
    n = len(pids)
    vis, aud, bim = np.zeros((n, 2, L, K)), np.zeros((n, L, K)), np.zeros((n, 2, L, L, K))
    for m, arr, idx in ((b == 0, vis, (f, e)), (b == 1, aud, (a,)), (b == 2, bim, (f, a, e))):
        np.add.at(arr, (p[m], *(i[m] for i in idx), r[m]), 1)
    if aud.sum() == 0:
        raise ParameterError("study data without audio-only judgments: the audio supports of "
                             "FLMP and WTAV cannot be fitted")
    out = {}
    for fi, face in enumerate(FACES):
        for name, arr in (("visual-only", vis[:, fi]), ("bimodal", bim[:, fi])):
            if arr.sum() == 0:
                raise ParameterError(f"study data without {name} judgments of the {face} face: "
                                     "FLMP and WTAV need visual-only, audio-only and bimodal "
                                     "judgments of each face")
        out[face] = FaceCounts(vis[:, fi], aud, bim[:, fi], tuple(pids))
    return out


def predict(model: str, params: Params) -> dict[str, np.ndarray]:
    """Predicted response probabilities: ``visual`` (3, K), ``audio`` (3, K), ``bimodal``
    (sentence, expression, K)."""
    _check_model(model)
    a, v = params.audio, params.visual
    if model == "flmp":
        prod = a[:, None, :] * v[None, :, :]
        tot = prod.sum(-1, keepdims=True)
        if (tot <= 0).any():
            raise ParameterError("FLMP: a sentence and an expression share no response with "
                                 "positive support, so their bimodal cell is undefined")
        bim = prod / tot
    else:
        if params.w is None:
            raise ParameterError("WTAV needs the weight w (Params.w is None)")
        bim = params.w * a[:, None, :] + (1 - params.w) * v[None, :, :]
    return {"visual": v.copy(), "audio": a.copy(), "bimodal": bim}


def _cells(counts) -> tuple:
    cells = counts.cells() if isinstance(counts, FaceCounts) else counts
    if len(cells) != 3 or [np.shape(c) for c in cells] != [(L, K), (L, K), (L, L, K)]:
        raise ParameterError("counts must be a FaceCounts or pooled (visual (3, 4), audio "
                             "(3, 4), bimodal (3, 3, 4)) arrays")
    cells = tuple(np.asarray(c, float) for c in cells)
    if any((c < 0).any() for c in cells) or cells[2].sum() <= 0:
        raise ParameterError("counts must be >= 0, with bimodal judgments (no bimodal "
                             "judgments: FLMP and WTAV are fitted to bimodal cells)")
    return cells


def loglik(cells, predicted: dict) -> float:
    """Multinomial kernel ``Σ n log p`` of pooled counts (visual, audio, bimodal)."""
    return float(sum(np.sum(np.where(np.asarray(n) > 0, n * np.log(np.maximum(predicted[k],
                                                                             1e-300)), 0.0))
                     for n, k in zip(cells, _BLOCKS)))


def g_squared(cells, predicted: dict) -> float:
    """Deviance ``2 Σ n log(n / (N p))`` against the saturated model."""
    observed = {key: np.divide(n, np.maximum(np.sum(n, -1, keepdims=True), 1e-300))
                for n, key in zip(cells, _BLOCKS)}
    return max(0.0, 2 * (loglik(cells, observed) - loglik(cells, predicted)))


def _objective(theta, model, cells, lam):
    """Penalised negative log-likelihood and its gradient (theta: α (3K), β (3K), [η])."""
    n_v, n_a, n_b = cells
    alpha, beta = theta[:L * K].reshape(L, K), theta[L * K:2 * L * K].reshape(L, K)
    la, lv = special.log_softmax(alpha, -1), special.log_softmax(beta, -1)
    pa, pv = np.exp(la), np.exp(lv)
    ll = np.sum(n_a * la) + np.sum(n_v * lv)
    ga = n_a - n_a.sum(-1, keepdims=True) * pa
    gv = n_v - n_v.sum(-1, keepdims=True) * pv
    grad = np.empty_like(theta)
    if model == "flmp":
        lb = special.log_softmax(alpha[:, None, :] + beta[None, :, :], -1)
        ll += np.sum(n_b * lb)
        resid = n_b - n_b.sum(-1, keepdims=True) * np.exp(lb)
        ga += resid.sum(1)
        gv += resid.sum(0)
    else:
        w = special.expit(theta[-1])
        p = np.maximum(w * pa[:, None, :] + (1 - w) * pv[None, :, :], 1e-300)
        ll += np.sum(n_b * np.log(p))
        r = n_b / p  # d ll / d p
        da, dv = w * r.sum(1), (1 - w) * r.sum(0)
        ga += pa * (da - np.sum(da * pa, -1, keepdims=True))
        gv += pv * (dv - np.sum(dv * pv, -1, keepdims=True))
        grad[-1] = np.sum(r * (pa[:, None, :] - pv[None, :, :])) * w * (1 - w)
    grad[:L * K], grad[L * K:2 * L * K] = ga.ravel(), gv.ravel()
    return -ll + 0.5 * lam * theta @ theta, -grad + lam * theta


def _logits(counts_or_support, empirical: bool) -> np.ndarray:
    x = np.asarray(counts_or_support, float)
    z = np.log((x + 0.5) / (x.sum(-1, keepdims=True) + 0.5 * K)) if empirical \
        else np.log(np.maximum(x, 1e-12))
    return np.clip(z - z.mean(-1, keepdims=True), -BOUND, BOUND).ravel()


def _theta(model, init) -> np.ndarray:
    params = init.params if isinstance(init, FitResult) else init
    if not isinstance(params, Params):
        raise ParameterError(f"init must be a FitResult or Params, got {type(init).__name__}")
    theta = np.concatenate([_logits(params.audio, False), _logits(params.visual, False)])
    if model == "wtav":
        w = 0.5 if params.w is None else float(np.clip(params.w, 1e-6, 1 - 1e-6))
        theta = np.append(theta, special.logit(w))
    return theta


@dataclass(frozen=True)
class FitResult:
    """One model fitted to one face's counts (see the module text for the statistics)."""

    model: str
    params: Params
    predicted: dict
    loglik: float
    g2: float
    rmsd: float
    bic: float
    n_params: int
    df: int
    n_judgments: int
    lam: float
    objective: float
    converged: bool
    theta: np.ndarray

    def to_dict(self) -> dict:
        return {"model": self.model, "params": self.params.to_dict(),
                "predicted": {k: v.tolist() for k, v in self.predicted.items()},
                **{k: getattr(self, k) for k in ("loglik", "g2", "rmsd", "bic", "n_params",
                                                 "df", "n_judgments", "lam", "converged")}}


def fit_model(model: str, counts, *, lam: float = 0.05, n_starts: int = 3, seed: int = 0,
              init=None) -> FitResult:
    """Fit ``model`` to one face's counts (a FaceCounts or pooled arrays). Starts: ``init``
    (a FitResult or Params) if given, the empirical unimodal proportions, then seeded
    perturbations — ``n_starts`` in all; the best penalised likelihood is kept."""
    _check_model(model)
    lam, n_starts = check_lam(lam), check_count("n_starts", n_starts)
    cells = _cells(counts)
    wtav = model == "wtav"
    base = np.concatenate([_logits(cells[1], True), _logits(cells[0], True)]
                          + ([[0.0]] if wtav else []))
    starts = ([_theta(model, init)] if init is not None else []) + [base]
    rng = seeded_rng(seed, "start")
    weights = special.logit([0.25, 0.75, 0.1, 0.9])
    while len(starts) < n_starts:
        t = base + rng.normal(0.0, 1.0, base.size)
        if wtav:
            t[-1] = weights[len(starts) % len(weights)]
        starts.append(t)
    with one_blas_thread():
        runs = [optimize.minimize(_objective, np.clip(t0, -BOUND, BOUND), jac=True,
                                  args=(model, cells, lam), method="L-BFGS-B",
                                  bounds=[(-BOUND, BOUND)] * base.size, options={"maxiter": 5000})
                for t0 in starts[:n_starts]]
    best = min(runs, key=lambda res: res.fun)
    theta = best.x
    params = Params(special.softmax(theta[:L * K].reshape(L, K), -1),
                    special.softmax(theta[L * K:2 * L * K].reshape(L, K), -1),
                    float(special.expit(theta[-1])) if wtav else None)
    pred = predict(model, params)
    ll = loglik(cells, pred)
    n_judg = int(round(sum(c.sum() for c in cells)))
    seen = [c.sum(-1) > 0 for c in cells]
    sq = [((n / np.maximum(n.sum(-1, keepdims=True), 1e-300) - pred[key])[s]) ** 2
          for n, key, s in zip(cells, _BLOCKS, seen)]
    k = N_PARAMS[model]
    return FitResult(model, params, pred, ll, g_squared(cells, pred),
                     float(np.sqrt(np.concatenate([x.ravel() for x in sq]).mean())),
                     float(k * np.log(n_judg) - 2 * ll), k,
                     int(sum(s.sum() for s in seen) * (K - 1) - k), n_judg, lam,
                     float(best.fun), bool(best.success), theta)


def lopo_cv(model: str, counts: FaceCounts, *, lam: float = 0.05, init=None,
            seed: int = 0) -> float:
    """Leave-one-participant-out: Σ over participants of their log-likelihood under the model
    fitted to the others (starts: ``init`` and the empirical proportions)."""
    if not isinstance(counts, FaceCounts) or counts.n < 2:
        raise ParameterError("cross-validation needs a FaceCounts of at least 2 participants")
    total, out = counts.cells(), 0.0
    for p in range(counts.n):
        held = counts.participant(p)
        rest = tuple(t - h for t, h in zip(total, held))
        fit = fit_model(model, rest, lam=lam, n_starts=2, seed=seed, init=init)
        out += loglik(held, fit.predicted)
    return out


def compare_models(counts: FaceCounts, *, lam: float = 0.05, cv: bool = True,
                   seed: int = 0) -> tuple[dict, dict]:
    """Both models fitted to one face; returns (fits by model, comparison)."""
    fits = {m: fit_model(m, counts, lam=lam, seed=seed) for m in MODELS}
    comp = {s: {m: float(getattr(fits[m], s)) for m in MODELS}
            for s in ("rmsd", "g2", "bic", "loglik")}
    comp["preferred_bic"] = min(MODELS, key=lambda m: fits[m].bic)
    if cv:
        comp["cv_loglik"] = {m: lopo_cv(m, counts, lam=lam, init=fits[m], seed=seed)
                             for m in MODELS}
        comp["preferred_cv"] = max(MODELS, key=lambda m: comp["cv_loglik"][m])
    comp["preferred"] = comp.get("preferred_cv", comp["preferred_bic"])
    return fits, comp


def _interval(samples, estimate, level) -> dict:
    lo, hi = np.quantile(samples, [(1 - level) / 2, (1 + level) / 2], axis=0)
    return {"estimate": np.asarray(estimate).tolist(), "lo": lo.tolist(), "hi": hi.tolist()}


def bootstrap_intervals(counts: dict, *, B: int = 200, lam: float = 0.05, seed: int = 0,
                        fits: dict | None = None, level: float = 0.95) -> dict:
    """Percentile intervals from ``B`` participant resamples (the same for both faces):
    ``visual[face][model]`` supports, ``w[face]``, and ``own_difference[model][expression]``
    (synthetic − real support of the expression's own emotion; ``mean`` over expressions).
    ``fits[face][model]`` (full-data fits) give the estimates and the first start."""
    B, lam = check_count("B", B), check_lam(lam)
    if set(counts) != set(FACES) or len({c.n for c in counts.values()}) != 1:
        raise ParameterError("bootstrap needs FaceCounts of both faces for the same participants")
    fits = fits or {f: {m: fit_model(m, counts[f], lam=lam, seed=seed) for m in MODELS}
                    for f in FACES}
    n, rng = counts[FACES[0]].n, seeded_rng(seed, "boot")
    vis = {f: {m: np.empty((B, L, K)) for m in MODELS} for f in FACES}
    w = {f: np.empty(B) for f in FACES}
    for b in range(B):
        mult = np.bincount(rng.integers(0, n, n), minlength=n)
        for f in FACES:
            cells = counts[f].cells(mult)
            for m in MODELS:
                r = fit_model(m, cells, lam=lam, n_starts=2, seed=seed, init=fits[f][m])
                vis[f][m][b] = r.params.visual
                if m == "wtav":
                    w[f][b] = r.params.w
    diff, own = {}, (slice(None), np.arange(L), OWN)
    for m in MODELS:
        d = vis["synthetic"][m][own] - vis["real"][m][own]
        d_hat = fits["synthetic"][m].params.own_visual() - fits["real"][m].params.own_visual()
        diff[m] = {e: _interval(d[:, j], d_hat[j], level) for j, e in enumerate(EXPRESSIONS)}
        diff[m]["mean"] = _interval(d.mean(1), d_hat.mean(), level)
    return {"B": B, "seed": seed, "level": level, "lam": lam,
            "visual": {f: {m: _interval(vis[f][m], fits[f][m].params.visual, level)
                           for m in MODELS} for f in FACES},
            "w": {f: _interval(w[f], fits[f]["wtav"].params.w, level) for f in FACES},
            "own_difference": diff}
