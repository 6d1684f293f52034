"""Explaining measured marker positions by the Motion Units: Eq. 5, solved as in Appendix A.

With the expression state k known, the measurements ``ζ`` (79 points, image pixels) are
modelled by the face of Eq. 3 under a global 2D motion ``T_β``::

    ζ ≈ T_β( s_0 + m_00 + Σ_i c_0i m_0i + α_k (m_k0 + Σ_i c_ki m_ki) )          (Eq. 5)

``T_β`` is a similarity — rotation, isotropic scale, translation, the motion §V describes and
the synthetic head motion: ``T_β(p) = [[a, −b], [b, a]] p + t`` with ``a = s cos θ``,
``b = s sin θ``. It is reported in the paper's order ``β = [β_1 β_2 β_3 β_4 β_5 β_6] =
[a, −b, b, a, t_x, t_y]``, ``T_β(p) = [[β_1, β_2], [β_3, β_4]] p + [β_5, β_6]``.

:func:`fit_linear` follows Appendix A: with the products ``a·c_i`` and ``b·c_i`` as unknowns of
their own, Eq. 5 becomes the linear least squares of Eq. 12 in ``v = (a, b, t_x, t_y, a c_1 …,
b c_1 …)``. From ``v`` we take the rotation and scale ``(a, b)``; given them Eq. 5 is linear in
``(t, c)``, which a second least squares gives. (Dividing the products by ``a`` and ``b``
instead — ``c_i = (a·ac_i + b·bc_i)/(a² + b²)`` — is exact without noise, but several MUs are
close to a global translation of most markers, so the relaxed ``t`` and ``c`` trade off, and
with 0.3 px noise that recovery left the fitted markers 4× farther from the truth than the
second solve does.) :func:`fit_nonlinear` solves Eq. 5 directly with
``scipy.optimize.least_squares`` to cross-check it.

``s_0`` and the MUs live in the aligned model frame of :mod:`face_model.alignment` (pixels).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from face_model.layout import N_MARKERS, default_layout
from groundwork.errors import ParameterError
from groundwork.numerics import lstsq, one_blas_thread


def as_points(x, name: str, shape: tuple, *, stacked: bool | None = None) -> np.ndarray:
    """``x`` as a finite float64 array of points, checked.

    Parameters
    ----------
    x : array_like
        The points.
    name : str
        The parameter's name, for the message.
    shape : tuple of int
        The shape of one item, e.g. ``(79, 2)`` for a face or ``(2,)`` for a point.
    stacked : bool or None
        ``False``: ``x`` is one item of ``shape``; ``True``: a stack ``(n, *shape)``;
        ``None``: either.

    Returns
    -------
    ndarray of float64

    Raises
    ------
    ParameterError
        Naming ``name``: another shape, or NaN / inf values.
    """
    a = np.asarray(x, dtype=np.float64)
    ndims = {None: (len(shape), len(shape) + 1), False: (len(shape),),
             True: (len(shape) + 1,)}[stacked]
    if a.ndim not in ndims or a.shape[a.ndim - len(shape):] != shape:
        want = {None: f"{shape} or (n_frames, *{shape})", False: f"{shape}",
                True: f"(n_frames, *{shape})"}[stacked]
        raise ParameterError(f"{name} must have shape {want}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ParameterError(f"{name} hold NaN or inf values")
    return a


def check_units(units, expression: str) -> None:
    """Refuse (:class:`~groundwork.errors.ParameterError`) ``units`` that are not fitted
    MotionUnits, or an ``expression`` that is neither ``neutral`` nor one of their
    expressions."""
    if not hasattr(units, "components_"):
        raise ParameterError("units must be fitted MotionUnits (call fit() or "
                             "MotionUnits.load())")
    allowed = ("neutral", *units.expressions_)
    if expression not in allowed:
        raise ParameterError(f"expression {expression!r} has no MUs; allowed: "
                             f"{', '.join(allowed)}")


def model_basis(units, expression: str = "neutral", *, neutral=None):
    """The shape model of Eq. 3 in the aligned frame.

    Parameters
    ----------
    units : MotionUnits
        Fitted MUs.
    expression : str
        ``neutral`` (the utterance MUs only) or one of the units' expressions.
    neutral : array_like (79, 2), optional
        ``s_0``, pixels in the aligned frame; default: the canonical layout's neutral.

    Returns
    -------
    base : ndarray (79, 2)
        ``s_0 + m_00 (+ m_k0)``: the shape with every MUP zero.
    basis : ndarray (A_0 [+ A_k], 79, 2)
        The MUs ``m_0i`` (then ``m_ki``) as marker displacement fields.
    """
    check_units(units, expression)
    s0 = default_layout().neutral if neutral is None else \
        as_points(neutral, "neutral", (N_MARKERS, 2), stacked=False)
    base = s0 + units.mean_.reshape(N_MARKERS, 2)
    basis = [units.components_]
    if expression != "neutral":
        base = base + units.expression_mean_[expression].reshape(N_MARKERS, 2)
        basis.append(units.expression_components_[expression])
    return base, np.concatenate(basis).reshape(-1, N_MARKERS, 2)


def apply_beta(beta, points) -> np.ndarray:
    """``T_β(points)``, the global motion of Eq. 5, frame by frame.

    Parameters
    ----------
    beta : array_like, shape (n, 6)
        ``[β_1 … β_6]`` in the paper's order (the module text).
    points : array_like, shape (n, k, 2)
        Points in the model frame, pixels.

    Returns
    -------
    ndarray, shape (n, k, 2)
        The points in the image, pixels.
    """
    beta = np.asarray(beta, dtype=np.float64)
    A = beta[:, :4].reshape(-1, 2, 2)
    return np.einsum("nij,nkj->nki", A, points) + beta[:, None, 4:]


def similarity_beta(angle, scale, tx, ty) -> np.ndarray:
    """β of a similarity, in the paper's order.

    Parameters
    ----------
    angle : array_like, shape (n,)
        Rotation, radians.
    scale : array_like, shape (n,)
        Isotropic scale.
    tx, ty : array_like, shape (n,)
        Translation, pixels.

    Returns
    -------
    ndarray, shape (n, 6)
        ``[a, −b, b, a, t_x, t_y]`` with ``a = scale cos(angle)``, ``b = scale sin(angle)``.
    """
    a, b = scale * np.cos(angle), scale * np.sin(angle)
    return np.stack(np.broadcast_arrays(a, -b, b, a, tx, ty), axis=-1).astype(np.float64)


def beta_to_similarity(beta) -> np.ndarray:
    """The similarity nearest a β (the mean of its two estimates of ``a`` and of ``b``).

    Parameters
    ----------
    beta : array_like, shape (n, 6)
        ``[β_1 … β_6]`` in the paper's order.

    Returns
    -------
    ndarray, shape (n, 4)
        Angle (rad), scale, t_x, t_y (pixels).
    """
    beta = np.asarray(beta, dtype=np.float64)
    a = 0.5 * (beta[:, 0] + beta[:, 3])
    b = 0.5 * (beta[:, 2] - beta[:, 1])
    return np.stack([np.arctan2(b, a), np.hypot(a, b), beta[:, 4], beta[:, 5]], axis=1)


@dataclass(frozen=True)
class MUFit:
    """A solution of Eq. 5 for every frame.

    Attributes
    ----------
    mups : ndarray (n_frames, A_0 + A_k)
        ``c_0`` then ``c_k`` (zeros when neutral), as ``MotionUnits.transform`` orders them.
    beta : ndarray (n_frames, 6)
        ``[β_1 … β_6]``, model frame → image pixels.
    markers : ndarray (n_frames, 79, 2)
        The fitted shapes ``T_β(s_0 + d)``, image pixels.
    """

    mups: np.ndarray
    beta: np.ndarray
    markers: np.ndarray


def _rotation_scale(a, b) -> np.ndarray:
    """(n, 2, 2) ``[[a, −b], [b, a]]`` from arrays ``a = s cos θ``, ``b = s sin θ``."""
    return np.stack([a, -b, b, a], axis=1).reshape(-1, 2, 2)


def _design(base: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """The matrix ``B`` of Eq. 12 for the similarity (rows x_1, y_1, …, x_N, y_N)::

        x = a·bx − b·by + t_x + Σ_i (a c_i) ux_i − (b c_i) uy_i
        y = b·bx + a·by + t_y + Σ_i (a c_i) uy_i + (b c_i) ux_i
    """
    bx, by = base[:, 0], base[:, 1]
    ux, uy = basis[..., 0].T, basis[..., 1].T  # (79, m)
    one, zero = np.ones(N_MARKERS), np.zeros(N_MARKERS)
    rx = np.column_stack([bx, -by, one, zero, ux, -uy])
    ry = np.column_stack([by, bx, zero, one, uy, ux])
    return np.stack([rx, ry], axis=1).reshape(2 * N_MARKERS, -1)


def _translation_and_mups(A, z, w, base, basis):
    """Given ``A = [[β_1, β_2], [β_3, β_4]]`` (n, 2, 2), Eq. 5 is linear in ``t`` and ``c``:
    ``z − A·base = t + Σ_i c_i A·m_i``. Weighted least squares; returns t (n, 2), c (n, m)."""
    n = len(z)
    r = (z - np.einsum("nij,kj->nki", A, base)).reshape(n, -1)
    Au = np.einsum("nij,mkj->nkim", A, basis).reshape(n, 2 * N_MARKERS, -1)
    eye = np.broadcast_to(np.tile(np.eye(2), (N_MARKERS, 1)), (n, 2 * N_MARKERS, 2))
    M = np.concatenate([eye, Au], axis=2)
    Mw = M * np.repeat(w, 2, axis=1)[..., None]
    sol = np.linalg.solve(np.einsum("nri,nrj->nij", Mw, M),
                          np.einsum("nri,nr->ni", Mw, r)[..., None])[..., 0]
    return sol[:, :2], sol[:, 2:]


def _prepare(zeta, units, expression, neutral, weights, need: int):
    base, basis = model_basis(units, expression, neutral=neutral)
    z = as_points(zeta, "zeta", (N_MARKERS, 2))
    z = z[None] if z.ndim == 2 else z
    if weights is None:
        return base, basis, z, np.ones(z.shape[:2])
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != z.shape[:2] or not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ParameterError(f"weights must be finite, >= 0 and of shape {z.shape[:2]}, got "
                             f"shape {w.shape}")
    few = int((w > 0).sum(1).min())
    if few < need:
        raise ParameterError(f"every frame needs at least {need} markers of non-zero weight; "
                             f"got as few as {few}")
    return base, basis, z, w


def _n_active(units, expression: str) -> int:
    return units.n_utterance + (0 if expression == "neutral" else units.n_expression)


def min_markers(units, expression: str) -> int:
    """Fewest markers Eq. 12 needs for ``units`` in state ``expression``: its
    ``4 + 2 (A_0 [+ A_k])`` unknowns at two rows a marker, i.e. ``2 + A_0 [+ A_k]``."""
    return 2 + _n_active(units, expression)


def _finish(units, c, beta, base, basis) -> MUFit:
    mups = np.zeros((len(c), units.n_mups))
    mups[:, :c.shape[1]] = c
    shape = base[None] + np.einsum("nm,mkd->nkd", c, basis)
    return MUFit(mups, beta, apply_beta(beta, shape))


def fit_linear(zeta, units, expression: str = "neutral", *, neutral=None,
               weights=None) -> MUFit:
    """Solve Eq. 5 for every frame linearly (Appendix A, Eq. 12; see the module docstring).

    Parameters
    ----------
    zeta : array_like, shape (n_frames, 79, 2) or (79, 2)
        Measured marker positions ``ζ(t)``, image pixels.
    units : MotionUnits
        Fitted MUs.
    expression : str
        The known expression state k (``neutral``: the utterance MUs only).
    neutral : array_like (79, 2), optional
        ``s_0`` in the aligned model frame — the subject's neutral face, the one the MUs were
        learned against (:func:`face_model.alignment.speaker_neutrals`); default: the layout's.
    weights : array_like (n_frames, 79), optional
        Per-marker weights (0 drops a marker, e.g. one Lucas–Kanade lost).

    Returns
    -------
    MUFit

    Raises
    ------
    ParameterError
        Unfitted units or an unknown expression; ``zeta``, ``neutral`` or ``weights`` of the
        wrong shape, not finite or (weights) negative; a frame with fewer markers of non-zero
        weight than :func:`min_markers`.
    """
    check_units(units, expression)
    base, basis, z, w = _prepare(zeta, units, expression, neutral, weights,
                                 min_markers(units, expression))
    centre = base.mean(0)  # centring keeps the columns of Eq. 12 on comparable scales
    X = _design(base - centre, basis)
    Z = z.reshape(len(z), -1)
    if weights is None:
        v = lstsq(X, Z.T).T
    else:
        rw = np.sqrt(np.repeat(w, 2, axis=1))
        with one_blas_thread():
            v = np.stack([lstsq(X * r[:, None], zz * r) for r, zz in zip(rw, Z)])
    A = _rotation_scale(v[:, 0], v[:, 1])
    t, c = _translation_and_mups(A, z, w, base - centre, basis)
    beta = np.concatenate([A.reshape(-1, 4), t - A @ centre], axis=1)
    return _finish(units, c, beta, base, basis)


def _nonlinear_frame(z, w, base, basis, x0):
    """Levenberg–Marquardt on (a, b, t_x, t_y, c) with the analytic Jacobian."""
    sw = np.sqrt(np.repeat(w, 2))

    def shape(x):
        return base + np.tensordot(x[4:], basis, 1)

    def residual(x):
        a, b, tx, ty = x[:4]
        p = shape(x)
        q = np.column_stack([a * p[:, 0] - b * p[:, 1] + tx, b * p[:, 0] + a * p[:, 1] + ty])
        return (q - z).ravel() * sw

    def jac(x):
        a, b = x[:2]
        p = shape(x)
        J = np.zeros((N_MARKERS, 2, len(x)))
        J[:, :, 0] = p
        J[:, 0, 1], J[:, 1, 1] = -p[:, 1], p[:, 0]
        J[:, 0, 2] = J[:, 1, 3] = 1.0
        J[:, :, 4:] = np.einsum("ij,mkj->kim", [[a, -b], [b, a]], basis)
        return J.reshape(2 * N_MARKERS, -1) * sw[:, None]

    return least_squares(residual, x0, jac=jac, method="lm", xtol=1e-12, ftol=1e-12,
                         gtol=1e-12).x


def fit_nonlinear(zeta, units, expression: str = "neutral", *, neutral=None,
                  weights=None) -> MUFit:
    """Solve Eq. 5 directly by nonlinear least squares (the cross-check of :func:`fit_linear`).

    Independent of Eq. 12: each frame starts from ``c = 0`` and the similarity that best maps
    the base shape onto ``ζ``, then Levenberg–Marquardt with the analytic Jacobian. Same
    parameters, result type and errors as :func:`fit_linear` (a frame needs only
    ``(5 + A_0 [+ A_k]) // 2`` markers, two equations each for its ``4 + A_0 [+ A_k]``
    unknowns); about 1–2 ms per frame.
    """
    check_units(units, expression)
    base, basis, z, w = _prepare(zeta, units, expression, neutral, weights,
                                 (5 + _n_active(units, expression)) // 2)
    centre = base.mean(0)
    bc = base - centre
    xs = []
    for zz, ww in zip(z, w):
        # Start: weighted centroids and the complex-ratio similarity (Umeyama's in 2D).
        mb, mz = (ww @ bc) / ww.sum(), (ww @ zz) / ww.sum()
        pb, pz = (bc - mb) @ [1, 1j], (zz - mz) @ [1, 1j]
        k = (ww * np.conj(pb) * pz).sum() / (ww * np.abs(pb) ** 2).sum()
        t0 = mz - np.array([k.real * mb[0] - k.imag * mb[1], k.imag * mb[0] + k.real * mb[1]])
        xs.append(_nonlinear_frame(zz, ww, bc, basis,
                                   np.r_[k.real, k.imag, t0, np.zeros(len(basis))]))
    x = np.array(xs)
    A = _rotation_scale(x[:, 0], x[:, 1])
    beta = np.concatenate([A.reshape(-1, 4), x[:, 2:4] - A @ centre], axis=1)
    return _finish(units, x[:, 4:], beta, base, basis)
