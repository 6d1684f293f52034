"""The coarticulation model fitted on a real mouth (Cohen & Massaro, 1993, fitted to measured
articulation as in Beskow, 2004, "Trainable articulatory control models for visual speech
synthesis").

Two steps, both least squares, both on a speaker's **training sentences only**:

1. **Into the articulatory space** (:class:`FaceMap`, :func:`to_articulation`): the real
   speaker's tracked markers, aligned by the glasses markers into the layout's frame, are
   explained frame by frame by the generator's own articulation map
   (:func:`data_synth.face.articulate`, neutral, no brow) around the speaker's rest face (the
   median of its silence frames): the seven articulatory parameters (jaw, aperture, spread,
   protrusion, upper raise, lower tuck, closure), each within its bounds, that bring the lip
   and cheek markers closest to the tracked ones, with a small ridge toward rest.
2. **The coarticulation model** (:func:`fit_coarticulation`): per-phone targets of the seven
   parameters, two dominance magnitudes per phone (lips, jaw), the anticipation and carry-over
   rates and the power, so that :func:`data_synth.articulation.coarticulate` of the true
   (forced-aligned) phones comes closest to step 1's parameters over the valid frames. The
   hand table is the prior and the starting point: each target and log-dominance is pulled
   toward the table's with the weight of :data:`PRIOR_FRAMES` frames, so a phone the speaker
   never says keeps the table's values and a phone said in thousands of frames is the data's.

Both run in PyTorch (float64, full batch, from fixed starting points, a fixed number of steps,
two threads), so the same data give the same parameters.
"""
from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from data_synth.articulation import TARGET_BOUNDS, Articulation
from data_synth.face import displacement_fields
from face_model.layout import REGIONS
from face_model.phones import ARTIC_PARAMS, BILABIALS, N_ARTIC, PHONE_INDEX, check_phone
from groundwork.errors import ParameterError

# Fields in the order articulate() combines them.
_FIELDS = ("jaw_lips", "jaw_face", "aperture", "spread", "protrusion", "upper_raise",
           "lower_tuck", "press")
_P = {name: i for i, name in enumerate(ARTIC_PARAMS)}
JAW = _P["jaw"]
CLOSURE = _P["closure"]
# Per-frame bounds of each parameter (closure is a fraction; tuck as the face allows).
LOWER = np.zeros(N_ARTIC)
UPPER = np.array([1.5, 1.5, 1.5, 1.5, 1.5, 1.5, 1.0])
MARKERS = np.concatenate([np.asarray(REGIONS["lips"]), np.asarray(REGIONS["cheeks"])])
CHEEK_WEIGHT = 0.5  # the cheeks inform the jaw; the lips are what is fitted
PRIOR_FRAMES = 5.0  # the hand table's weight, in frames of data, per target and dominance
RATE_BOUNDS = (1.0, 200.0)  # 1/s
POWER_BOUNDS = (0.3, 3.0)
THREADS = 2
# Starting points of step 1's rounds (ARTIC_PARAMS order): lips open, closed, tucked.
STARTS = ((0, 0, 0, 0, 0, 0, 0), (0, 0, 0, 0, 0, 0, 1), (0, 0, 0, 0, 0, 1, 0))


@dataclass(frozen=True)
class FaceMap:
    """The generator's articulation map around one rest face (neutral, gains 1, no brow):
    ``markers = rest + scale · d(artic)`` (:func:`data_synth.face.articulate`).

    Attributes
    ----------
    rest : ndarray, shape (79, 2)
        The face at rest, pixels of the aligned (layout) frame.
    fields : ndarray, shape (8, 79, 2)
        The displacement fields of :data:`_FIELDS` at unit value, pixels.
    scale : float
        The face's size relative to the layout (glasses span / 172 px).
    """

    rest: np.ndarray
    fields: np.ndarray
    scale: float

    @classmethod
    def around(cls, rest: np.ndarray, synth_cfg, *, scale: float = 1.0) -> "FaceMap":
        """The map around ``rest``. A real face aligned by its glasses markers is in the
        layout's frame, so its ``scale`` is 1 (its glasses triangle need not be the drawn
        face's: the span of a tracked one says nothing of the face's size); a drawn speaker's
        is its glasses span / 172 px, as :func:`data_synth.face.articulate` takes it."""
        rest = np.asarray(rest, dtype=np.float64)
        if rest.shape != (79, 2) or not np.isfinite(rest).all():
            raise ParameterError(f"rest face must be finite (79, 2), got {rest.shape}")
        if not (np.isfinite(scale) and scale > 0):
            raise ParameterError(f"face map scale must be positive, got {scale}")
        f = displacement_fields(rest, synth_cfg)
        return cls(rest, np.stack([f[k] for k in _FIELDS]), float(scale))

    def markers(self, artic: np.ndarray) -> np.ndarray:
        """Markers (n, 79, 2) of articulatory parameters ``artic`` (n, 7) (numpy; equal to
        :func:`data_synth.face.articulate` of a neutral speaker with this rest face)."""
        torch = _torch()
        with torch.no_grad():
            d = _displacement(torch, torch.as_tensor(np.asarray(artic, np.float64)),
                              torch.as_tensor(self.fields))
        return self.rest[None] + d.numpy() * self.scale


def _torch():
    import torch
    return torch


@contextmanager
def _fit_threads(torch):
    """:data:`THREADS` torch threads for one fit (its reductions, hence its parameters, depend
    on the count), then the process's own count again: a test worker or a grid's worker keeps
    its share of the cores (:mod:`groundwork.threads`)."""
    before = torch.get_num_threads()
    torch.set_num_threads(THREADS)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _displacement(torch, a, fields):
    """``d(artic)``: (n, m, 2) from parameters (n, 7) and fields (8, m, 2), as articulate()."""
    col = lambda name: a[:, _P[name]][:, None, None]  # noqa: E731
    closure = col("closure").clamp(0.0, 1.0)
    tuck = col("lower_tuck").clamp(0.0, 1.5)
    opening = (1.0 - closure) * (1.0 - 0.7 * tuck.clamp(0.0, 1.0))
    jl, jf, ap, sp, pr, ur, lt, press = fields
    return (col("jaw") * (opening * jl + jf) + col("aperture") * opening * ap
            + col("spread") * sp + col("protrusion") * pr + col("upper_raise") * ur
            + tuck * lt + closure * press)


def rest_face(aligned: list, rest_frames: list) -> np.ndarray:
    """The rest face (79, 2): the per-coordinate median of the aligned markers over the frames
    marked in ``rest_frames`` (boolean per frame of each clip: valid silence)."""
    picked = [np.asarray(m, np.float64)[np.asarray(r, bool)] for m, r in zip(aligned, rest_frames)]
    picked = [p for p in picked if len(p)]
    if not picked:
        raise ParameterError("no rest frames (valid silence) to take the rest face from")
    return np.median(np.concatenate(picked), axis=0)


def to_articulation(face: FaceMap, aligned: np.ndarray, *, ridge: float = 1e-3,
                    rounds: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Step 1: the articulatory parameters that explain each frame's markers.

    The map is linear in the parameters once the lips' opening factor
    ``(1 − closure)(1 − 0.7 · min(tuck, 1))`` is known, so each of ``rounds`` rounds fixes that
    factor at the last round's parameters and solves every frame's box-bounded linear least
    squares (:func:`box_least_squares`) at once; the first round starts from the lips open.

    Parameters
    ----------
    face : FaceMap
        The articulation map around the speaker's rest face.
    aligned : ndarray, shape (n, 79, 2)
        The speaker's markers aligned into the layout's frame (pixels).
    ridge : float
        Weight of ``Σ artic²`` (toward rest) per frame, relative to the weighted mean squared
        pixel error over the fitted markers.
    rounds : int
        Rounds of the opening factor.

    Returns
    -------
    artic : ndarray, shape (n, 7)
        Within :data:`LOWER` – :data:`UPPER`.
    rms_px : ndarray, shape (n,)
        Root of the weighted mean squared residual per frame over the fitted markers (pixels).
    """
    aligned = np.asarray(aligned, np.float64)
    if aligned.ndim != 3 or aligned.shape[1:] != (79, 2) or not np.isfinite(aligned).all():
        raise ParameterError(f"aligned markers must be finite (n, 79, 2), got {aligned.shape}")
    y = ((aligned[:, MARKERS] - face.rest[MARKERS]) / face.scale).reshape(len(aligned), -1)
    f = face.fields[:, MARKERS].reshape(len(_FIELDS), -1)  # (8, m·2)
    w = np.repeat(np.where(np.isin(MARKERS, REGIONS["cheeks"]), CHEEK_WEIGHT, 1.0), 2)
    w = w / w.sum() * 2.0  # a mean over markers of dx² + dy²
    jl, jf, ap, sp, pr, ur, lt, press = f
    best, best_err = None, None
    for start in STARTS:  # the opening factor is not convex: keep each frame's best start
        a = np.tile(np.asarray(start, float), (len(y), 1))
        for _ in range(rounds):
            o = (1.0 - a[:, CLOSURE].clip(0, 1)) * (1.0 - 0.7 * a[:, _P["lower_tuck"]].clip(0, 1))
            x = np.stack([o[:, None] * jl + jf, o[:, None] * ap] + [np.broadcast_to(c, y.shape)
                          for c in (sp, pr, ur, lt, press)], axis=-1)  # (n, m·2, 7)
            xw = x * w[None, :, None]
            gram = np.einsum("nkp,nkq->npq", xw, x) + ridge * np.eye(N_ARTIC)
            a = box_least_squares(gram, np.einsum("nkp,nk->np", xw, y), LOWER, UPPER)
        err = (((_linear_map(a, f) - y) ** 2) * w).sum(1) + ridge * (a**2).sum(1)
        if best is None:
            best, best_err = a, err
        else:
            better = err < best_err
            best[better], best_err[better] = a[better], err[better]
    a = best
    resid = face.markers(a)[:, MARKERS] - aligned[:, MARKERS]
    rms = np.sqrt(((resid**2).sum(-1) * (w[::2] / 2.0)).sum(-1))
    return a, rms


def _linear_map(a: np.ndarray, f: np.ndarray) -> np.ndarray:
    """``d(artic)`` of :func:`_displacement` in numpy, flattened: (n, m·2) from (n, 7), (8, m·2)."""
    jl, jf, ap, sp, pr, ur, lt, press = f
    c = a[:, CLOSURE].clip(0, 1)[:, None]
    tuck = a[:, _P["lower_tuck"]].clip(0, 1.5)[:, None]
    o = (1.0 - c) * (1.0 - 0.7 * tuck.clip(0, 1))
    col = lambda name: a[:, _P[name]][:, None]  # noqa: E731
    return (col("jaw") * (o * jl + jf) + col("aperture") * o * ap + col("spread") * sp
            + col("protrusion") * pr + col("upper_raise") * ur + tuck * lt + c * press)


def box_least_squares(gram: np.ndarray, rhs: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                      *, iterations: int = 50) -> np.ndarray:
    """Minimise ``½ aᵀ G a − bᵀ a`` within ``lower ≤ a ≤ upper`` for every row at once
    (a projected Newton active-set iteration).

    Parameters
    ----------
    gram : ndarray, shape (n, p, p)
        Symmetric positive definite.
    rhs : ndarray, shape (n, p)
    lower, upper : ndarray, shape (p,)

    Returns
    -------
    ndarray, shape (n, p)
    """
    n, p = rhs.shape
    eye = np.eye(p, dtype=bool)
    a = np.clip(np.linalg.solve(gram, rhs[..., None])[..., 0], lower, upper)
    for _ in range(iterations):
        g = np.einsum("npq,nq->np", gram, a) - rhs
        fixed = ((a <= lower) & (g > 0)) | ((a >= upper) & (g < 0))
        free = ~fixed
        m = np.where(free[:, :, None] & free[:, None, :], gram, 0.0)
        m[:, eye] = np.where(free, m[:, eye], 1.0)
        b = rhs - np.einsum("npq,nq->np", gram, np.where(fixed, a, 0.0))
        b = np.where(free, b, a)
        new = np.clip(np.linalg.solve(m, b[..., None])[..., 0], lower, upper)
        if np.array_equal(new, a):
            break
        a = new
    return a


@dataclass(frozen=True)
class Sentence:
    """One sentence for :func:`fit_coarticulation`: its phone segments, frame times (s), the
    observed parameters (n, 7) and a weight per frame (0 leaves a frame out)."""

    segments: tuple
    times: np.ndarray
    observed: np.ndarray
    weight: np.ndarray


def _pack(sentences: list):
    """Padded arrays of the sentences: per segment (phone index, start, end, silence,
    bilabial, present) and per frame (time, observed, weight)."""
    n_seg = max(len(s.segments) for s in sentences)
    n_fr = max(len(s.times) for s in sentences)
    b = len(sentences)
    idx = np.zeros((b, n_seg), np.int64)
    start, end = np.zeros((b, n_seg)), np.zeros((b, n_seg))
    sil, bil, seg_ok = (np.zeros((b, n_seg), bool) for _ in range(3))
    times, weight = np.zeros((b, n_fr)), np.zeros((b, n_fr))
    obs = np.zeros((b, n_fr, N_ARTIC))
    for i, s in enumerate(sentences):
        k, n = len(s.segments), len(s.times)
        if n != len(s.observed) or n != len(s.weight):
            raise ParameterError(f"sentence {i}: {n} times, {len(s.observed)} observed frames, "
                                 f"{len(s.weight)} weights; they must agree")
        idx[i, :k] = [PHONE_INDEX[check_phone(g.phone, source=f"sentence {i}")]
                      for g in s.segments]
        start[i, :k] = [g.start_s for g in s.segments]
        end[i, :k] = [g.end_s for g in s.segments]
        sil[i, :k] = [g.phone == "sil" for g in s.segments]
        bil[i, :k] = [g.phone in BILABIALS for g in s.segments]
        seg_ok[i, :k] = True
        times[i, :n], obs[i, :n], weight[i, :n] = s.times, s.observed, s.weight
    return idx, start, end, sil, bil, seg_ok, times, obs, weight


def _trajectories(torch, packed, targets, log_alpha, log_rates):
    """Coarticulated parameters (b, n_fr, 7) of the packed sentences (torch, differentiable);
    the same model as :func:`data_synth.articulation.coarticulate`, with the two dominance
    groups (jaw; the six lip parameters) weighed once each."""
    idx, start, end, sil, bil, seg_ok, times = packed[:7]
    t = times[:, None, :]  # (b, 1, n)
    signed = t - (0.5 * (start + end))[:, :, None]
    edge = torch.maximum(start[:, :, None] - t, t - end[:, :, None]).clamp(min=0.0)
    dist = torch.where(sil[:, :, None], edge, signed.abs())
    theta_a, theta_c, power = log_rates.exp()
    theta = torch.where(signed < 0, theta_a, theta_c)
    log_decay = -theta * (dist**2 + 1e-12) ** (0.5 * power)  # |τ|^c, a gradient at τ = 0
    log_dom = log_alpha[idx][:, :, None, :] + log_decay[..., None]  # (b, s, n, 2): lips, jaw
    log_dom = torch.where(seg_ok[:, :, None, None], log_dom,
                          torch.tensor(-1e30, dtype=torch.float64))
    w = torch.softmax(log_dom, dim=1)  # over segments
    tg = targets[idx]  # (b, s, 7)
    lips = torch.einsum("bsn,bsp->bnp", w[..., 0], tg)
    jaw = torch.einsum("bsn,bs->bn", w[..., 1], tg[..., JAW])
    inside = ((t >= start[:, :, None]) & (t < end[:, :, None]) & bil[:, :, None]).any(1)
    closure = torch.where(inside, torch.ones_like(jaw), lips[..., CLOSURE])
    return torch.cat([jaw[..., None], lips[..., 1:CLOSURE], closure[..., None],
                      lips[..., CLOSURE + 1:]], dim=-1)


def fit_coarticulation(sentences: list, prior: Articulation, *, steps: int = 300,
                       prior_frames: float = PRIOR_FRAMES) -> tuple[Articulation, dict]:
    """Step 2: the coarticulation model that best draws the observed parameters from the phones.

    Parameters
    ----------
    sentences : list of Sentence
    prior : Articulation
        The starting point and the prior (the hand table): its targets, its lip and jaw
        dominance (its columns ``aperture`` and ``jaw``) and its rates.
    steps : int
        L-BFGS iterations (full batch, strong Wolfe line search). The rates and the power are
        fitted on a log scale and kept within :data:`RATE_BOUNDS` and :data:`POWER_BOUNDS`.
    prior_frames : float
        The prior's weight per target and log-dominance, in frames of data.

    Returns
    -------
    model : Articulation
        The fitted model (``name`` "fitted"; the caller writes it with its provenance).
    fit : dict
        ``frames`` (weighted frames used), ``loss_start`` and ``loss_end`` (mean squared error
        of the parameters per frame and parameter, at the prior and at the fit), ``phone_frames``
        (frames per phone class inside its own segments).
    """
    if not sentences:
        raise ParameterError("fit_coarticulation: no sentences")
    torch = _torch()
    with _fit_threads(torch):
        return _fit(torch, sentences, prior, steps, prior_frames)


def _fit(torch, sentences, prior, steps, prior_frames):
    packed = [torch.as_tensor(x) for x in _pack(sentences)]
    obs, weight = packed[7], packed[8]
    total = float(weight.sum())
    if total <= 0:
        raise ParameterError("fit_coarticulation: every frame has weight 0")
    t0 = torch.as_tensor(prior.targets.copy())
    a0 = torch.as_tensor(np.log(prior.dominance[:, [_P["aperture"], JAW]]))  # lips, jaw
    lo = np.log([RATE_BOUNDS[0], RATE_BOUNDS[0], POWER_BOUNDS[0]])
    hi = np.log([RATE_BOUNDS[1], RATE_BOUNDS[1], POWER_BOUNDS[1]])
    r0 = np.log([prior.theta_anticipation, prior.theta_carryover, prior.power]).clip(lo, hi)
    r0 = torch.as_tensor(r0)
    targets, log_alpha, log_rates = (x.clone().contiguous().requires_grad_(True)
                                     for x in (t0, a0, r0))
    lam = prior_frames / total
    lo_t, hi_t = torch.as_tensor(lo), torch.as_tensor(hi)

    def data_loss():
        traj = _trajectories(torch, packed, targets, log_alpha, log_rates)
        return (((traj - obs) ** 2).mean(-1) * weight).sum() / total

    def closure():
        opt.zero_grad()
        loss = data_loss() + lam * (((targets - t0) ** 2).sum() / N_ARTIC
                                    + ((log_alpha - a0) ** 2).sum() / 2)
        loss.backward()
        return loss

    opt = torch.optim.LBFGS([targets, log_alpha, log_rates], lr=1.0, max_iter=steps,
                            history_size=20, tolerance_grad=1e-10, tolerance_change=1e-14,
                            line_search_fn="strong_wolfe")
    with torch.no_grad():
        loss_start = float(data_loss())
    opt.step(closure)
    with torch.no_grad():
        loss_end = float(data_loss())
        log_rates.copy_(torch.maximum(torch.minimum(log_rates, hi_t), lo_t))
    la = log_alpha.detach().numpy()
    dominance = np.repeat(np.exp(la[:, :1]), N_ARTIC, axis=1)
    dominance[:, JAW] = np.exp(la[:, 1])
    rates = np.exp(log_rates.detach().numpy())
    model = Articulation(targets.detach().numpy().copy(), dominance, float(rates[0]),
                         float(rates[1]), float(rates[2]), name="fitted")
    return model, {"frames": total, "loss_start": loss_start, "loss_end": loss_end,
                   "iterations": int(opt.state[opt._params[0]].get("n_iter", 0)),
                   "phone_frames": _phone_frames(sentences)}


def _phone_frames(sentences: list) -> dict:
    """Weighted frames inside each phone class's own segments."""
    out: dict = {}
    for s in sentences:
        for g in s.segments:
            inside = (s.times >= g.start_s) & (s.times < g.end_s)
            n = float(np.asarray(s.weight)[inside].sum())
            if n:
                out[g.phone] = out.get(g.phone, 0.0) + n
    return dict(sorted(out.items()))
