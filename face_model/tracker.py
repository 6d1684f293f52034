"""MU-constrained facial motion tracking (paper §V; Eq. 5 solved as in Appendix A).

The paper's tracker, frame by frame:

1. on the first frame (neutral, frontal) the neutral mesh is placed by the two mouth corners
   (:func:`init_from_mouth_corners`: translation, scale, rotation);
2. every marker is tracked on its own from the previous frame's tracked position by pyramidal
   Lucas–Kanade (the paper's [58], Shi & Tomasi's tracker; OpenCV ``calcOpticalFlowPyrLK``) —
   the noisy measurements ``ζ(t)``;
3. ``ζ(t)`` is explained by Eq. 5 — the MU face of the known expression state under a global
   similarity ``T_β`` (:mod:`face_model.mu_fit`) — and the fitted shape is the frame's tracked
   position, which seeds step 2 for the next frame.

Two additions, each switched off by ``None`` (both off = the paper's plain scheme):

* ``anchor_px`` — as [58] monitors each feature against its first-frame appearance, each point
  is also tracked from the first frame (starting at its frame-to-frame estimate), and that
  estimate is taken when the two agree within ``anchor_px``. Frame-to-frame tracking alone has
  nothing pulling it back: a lip measurement biased by a window that also sees the skin moves
  the MUPs, and the error stays.
* ``outlier_px`` — gross errors are left out of the fit (a point whose step departs from the
  median step by more than 2 ``outlier_px``; a point farther than ``outlier_px`` from the fit,
  refitted up to three times). Least squares otherwise lets the edge of a passing occluder
  drag the whole face (measured: 10 px off for the rest of the sentence, against 0.3 px).

On six rendered corpus sentences (485 frames, sensor noise sd 0–40 grey levels) the plain
scheme tracked the markers to 0.54–1.2 px, with both additions to 0.27–0.34 px; raw
Lucas–Kanade to 0.50–3.1 px.

:func:`track_points_lk` is step 2 alone, chained through the sequence (the unconstrained
baseline). Positions are image pixels, OpenCV's convention (pixel centres on integers).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from face_model.layout import LEFT_OUTER_CORNER, N_MARKERS, RIGHT_OUTER_CORNER
from face_model.mu_fit import (
    MUFit,
    apply_beta,
    as_points,
    beta_to_similarity,
    check_units,
    fit_linear,
    fit_nonlinear,
    min_markers,
    model_basis,
)
from groundwork.errors import ParameterError

__all__ = ["MUTracker", "TrackResult", "init_from_mouth_corners", "track_points_lk",
           "fit_linear", "fit_nonlinear", "MUFit", "apply_beta", "beta_to_similarity",
           "model_basis"]
SOLVERS = ("linear", "nonlinear")


def init_from_mouth_corners(neutral, left_corner, right_corner) -> np.ndarray:
    """Fit the neutral mesh to the first frame by its two mouth corners (paper §V).

    The similarity (translation, scale, rotation) taking the neutral's outer lip corners
    (markers 46 and 55) onto the selected image points is applied to the whole neutral face.

    Parameters
    ----------
    neutral : array_like, shape (79, 2)
        The neutral face ``s_0`` (model frame, pixels).
    left_corner, right_corner : array_like, shape (2,)
        The mouth corners selected in the first image (x, y), pixels.

    Returns
    -------
    ndarray, shape (79, 2)
        Marker positions in the image, pixels.

    Raises
    ------
    ParameterError
        Points of the wrong shape or not finite, or corners less than a pixel apart.
    """
    s0 = as_points(neutral, "neutral", (N_MARKERS, 2), stacked=False)
    left = as_points(left_corner, "left_corner", (2,), stacked=False)
    right = as_points(right_corner, "right_corner", (2,), stacked=False)
    if np.hypot(*(right - left)) < 1.0:
        raise ParameterError(f"the mouth corners {left.tolist()} and {right.tolist()} are less "
                             "than a pixel apart")
    z = complex(*(right - left)) / complex(*(s0[RIGHT_OUTER_CORNER] - s0[LEFT_OUTER_CORNER]))
    A = np.array([[z.real, -z.imag], [z.imag, z.real]])  # scale · rotation
    return (s0 - s0[LEFT_OUTER_CORNER]) @ A.T + left


# -- low-level tracking: pyramidal Lucas–Kanade [58] ---------------------------------------------
def _check_frames(frames, min_frames: int = 2) -> np.ndarray:
    f = np.asarray(frames)
    if f.dtype != np.uint8:
        raise ParameterError(f"frames must be uint8 images, got dtype {f.dtype}")
    if f.ndim == 4 and f.shape[-1] == 3:
        f = np.stack([cv2.cvtColor(x, cv2.COLOR_RGB2GRAY) for x in f])
    if f.ndim != 3 or min(f.shape[1:]) < 8:
        raise ParameterError("frames must have shape (n_frames, height, width) (grayscale) or "
                             f"(n_frames, height, width, 3) (RGB), got {np.shape(frames)}")
    if len(f) < min_frames:
        raise ParameterError(f"tracking needs at least {min_frames} frames, got {len(f)}")
    return np.ascontiguousarray(f)


def _lk_step(prev, nxt, pts, lk: dict, guess=None):
    """Track ``pts`` (79, 2) from ``prev`` to ``nxt`` (starting from ``guess`` if given): new
    points and a found mask."""
    p0 = pts.astype(np.float32).reshape(-1, 1, 2)
    if guess is None:
        p1, status, _ = cv2.calcOpticalFlowPyrLK(prev, nxt, p0, None, **lk)
    else:
        p1, status, _ = cv2.calcOpticalFlowPyrLK(prev, nxt, p0,
                                                 guess.astype(np.float32).reshape(-1, 1, 2),
                                                 flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
    p1 = p1.reshape(-1, 2).astype(np.float64)
    h, w = prev.shape
    found = (status.ravel() == 1) & np.all(np.isfinite(p1), axis=1) \
        & (p1[:, 0] >= 0) & (p1[:, 0] <= w - 1) & (p1[:, 1] >= 0) & (p1[:, 1] <= h - 1)
    return np.where(found[:, None], p1, pts), found


def _lk_params(win_size: int, max_level: int, iterations: int, epsilon: float) -> dict:
    for name, v, lo in (("win_size", win_size, 3), ("max_level", max_level, 0),
                        ("lk_iterations", iterations, 1)):
        if not isinstance(v, (int, np.integer)) or v < lo:
            raise ParameterError(f"{name} must be an integer >= {lo}, got {v!r}")
    if not epsilon > 0:
        raise ParameterError(f"lk_epsilon must be > 0, got {epsilon!r}")
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, int(iterations), float(epsilon))
    return {"winSize": (int(win_size), int(win_size)), "maxLevel": int(max_level),
            "criteria": crit}


def track_points_lk(frames, init_points, *, win_size: int = 13, max_level: int = 3,
                    lk_iterations: int = 30, lk_epsilon: float = 0.01):
    """Raw per-point tracking: pyramidal Lucas–Kanade chained frame to frame, no model.

    Parameters
    ----------
    frames : ndarray of uint8, shape (n_frames, H, W) or (n_frames, H, W, 3)
        Grey or RGB frames, n_frames >= 2.
    init_points : array_like, shape (79, 2)
        Positions in the first frame, image pixels.
    win_size, max_level, lk_iterations, lk_epsilon
        Lucas–Kanade's window (pixels), pyramid levels and stopping rule, as for
        :class:`MUTracker`.

    Returns
    -------
    tracks : ndarray (n_frames, 79, 2)
        Image pixels; a lost point keeps its last position.
    found : ndarray of bool (n_frames, 79)
        Lucas–Kanade found the point in that frame (all True in the first).

    Raises
    ------
    ParameterError
        Frames that are not uint8, of another shape or fewer than two; points of the wrong
        shape; out-of-range Lucas–Kanade settings.
    """
    f = _check_frames(frames)
    p = as_points(init_points, "init_points", (N_MARKERS, 2), stacked=False)
    lk = _lk_params(win_size, max_level, lk_iterations, lk_epsilon)
    tracks = np.empty((len(f), N_MARKERS, 2))
    found = np.ones((len(f), N_MARKERS), bool)
    tracks[0] = p
    for t in range(1, len(f)):
        tracks[t], found[t] = _lk_step(f[t - 1], f[t], tracks[t - 1], lk)
    return tracks, found


# -- the tracker ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class TrackResult:
    """Output of :meth:`MUTracker.track`, one row per frame.

    Attributes
    ----------
    markers : ndarray (n_frames, 79, 2)
        Tracked (MU-constrained) positions, image pixels.
    measured : ndarray (n_frames, 79, 2)
        The Lucas–Kanade measurements ``ζ(t)``, image pixels.
    used : ndarray of bool (n_frames, 79)
        Found by Lucas–Kanade and kept by the fit (all False in a frame that held the last
        fit for want of points).
    mups : ndarray (n_frames, A_0 + A_k)
        ``c_0`` then ``c_k`` (``MotionUnits.transform`` order).
    beta : ndarray (n_frames, 6)
        ``[β_1 … β_6]`` of Eq. 5, model frame → image pixels.
    residual_px : ndarray (n_frames,)
        RMS distance of the used ``ζ(t)`` from the fit, pixels (NaN in a frame that held the
        last fit).
    """

    markers: np.ndarray
    measured: np.ndarray
    used: np.ndarray
    mups: np.ndarray
    beta: np.ndarray
    residual_px: np.ndarray

    @property
    def head_motion(self) -> np.ndarray:
        """(n_frames, 4): angle (rad), scale, t_x, t_y (pixels) of ``T_β``."""
        return beta_to_similarity(self.beta)


class MUTracker:
    """The MU-constrained tracker of §V: Lucas–Kanade per point, then Eq. 5 per frame.

    Parameters
    ----------
    solver : {"linear", "nonlinear"}
        Appendix A's linear least squares (:func:`fit_linear`) or the direct fit
        (:func:`fit_nonlinear`, slower).
    win_size : int
        Lucas–Kanade window side, pixels. 13 tracked rendered sentences best (11–21 tried): a
        larger window also sees the skin around a lip marker, which moves less, and
        under-estimates lip motion (by 37 % at 21).
    max_level : int
        Pyramid levels above the full image.
    lk_iterations, lk_epsilon
        Lucas–Kanade stopping rule: at most this many iterations or a step below epsilon px.
    outlier_px : float or None
        Gross-error rejection threshold, pixels (see the module docstring); ``None``: every
        found point enters the least squares.
    anchor_px : float or None
        Agreement needed to take the first-frame (anchored) estimate of a point, pixels;
        ``None``: frame-to-frame tracking only.
    """

    def __init__(self, *, solver: str = "linear", win_size: int = 13, max_level: int = 3,
                 lk_iterations: int = 30, lk_epsilon: float = 0.01,
                 outlier_px: float | None = 3.0, anchor_px: float | None = 2.0):
        self.solver = solver
        self.win_size = win_size
        self.max_level = max_level
        self.lk_iterations = lk_iterations
        self.lk_epsilon = lk_epsilon
        self.outlier_px = outlier_px
        self.anchor_px = anchor_px

    def _check_params(self) -> dict:
        if self.solver not in SOLVERS:
            raise ParameterError(f"solver {self.solver!r}; allowed: {', '.join(SOLVERS)}")
        for name in ("outlier_px", "anchor_px"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float, np.number)) and np.isfinite(v)
                                      and v > 0):
                raise ParameterError(f"{name} must be a number > 0 or None, got {v!r}")
        return _lk_params(self.win_size, self.max_level, self.lk_iterations, self.lk_epsilon)

    def _fit_frame(self, zeta, found, prev, units, expression, neutral, need):
        """Eq. 5 on the found points, made robust (None if too few points).

        A point whose step from ``prev`` (the last tracked shape) differs from the median step
        by more than ``2 · outlier_px`` is a gross error (an occluder's edge, a jump to another
        dot) and is left out from the start; then points farther than ``outlier_px`` from the
        fit are dropped and the frame refitted, up to three times.
        """
        fit = fit_linear if self.solver == "linear" else fit_nonlinear
        used = found.copy()
        if self.outlier_px is not None and prev is not None and used.sum() >= need:
            step = zeta - prev
            dev = np.linalg.norm(step - np.median(step[used], axis=0), axis=1)
            if (used & (dev <= 2 * self.outlier_px)).sum() >= need:
                used &= dev <= 2 * self.outlier_px
        if used.sum() < need:
            return None, used
        res = fit(zeta, units, expression, neutral=neutral, weights=used[None] * 1.0)
        for _ in range(3 if self.outlier_px is not None else 0):
            keep = found & (np.linalg.norm(res.markers[0] - zeta, axis=1) <= self.outlier_px)
            if np.array_equal(keep, used) or keep.sum() < need:
                break
            used = keep
            res = fit(zeta, units, expression, neutral=neutral, weights=used[None] * 1.0)
        return res, used

    def _initial(self, f, neutral, init_markers, corners) -> np.ndarray:
        if (init_markers is None) == (corners is None):
            raise ParameterError("give exactly one of init_markers (79, 2) and corners "
                                 "(left (2,), right (2,))")
        if corners is not None:
            if len(corners) != 2:
                raise ParameterError(f"corners must be (left, right), got {corners!r}")
            p0 = init_from_mouth_corners(neutral, corners[0], corners[1])
        else:
            p0 = as_points(init_markers, "init_markers", (N_MARKERS, 2), stacked=False)
        h, w = f.shape[1:]
        if np.any(p0 < 0) or np.any(p0 > [w - 1, h - 1]):
            raise ParameterError(f"the initial markers fall outside the {w}x{h} frames")
        return p0

    def track(self, frames, units, expression: str = "neutral", *, neutral,
              init_markers=None, corners=None) -> TrackResult:
        """Track a face through ``frames``.

        Parameters
        ----------
        frames : ndarray of uint8, (n_frames, H, W) gray or (n_frames, H, W, 3) RGB
            A 30 fps sequence, n_frames >= 2, whose first frame shows the face neutral and
            frontal.
        units : MotionUnits
            Fitted MUs, the tracker's knowledge model.
        expression : str
            The known expression state of the sequence (``neutral`` or one the MUs know).
        neutral : array_like (79, 2)
            ``s_0``: the subject's neutral face in the aligned model frame, the one the MUs
            were learned against (:func:`face_model.alignment.speaker_neutrals`). Required: a
            neutral of another face shape biases every frame (the canonical layout instead of
            the corpus speaker's: 2 px error from true initial markers, 10 px from corners).
        init_markers : array_like (79, 2), optional
            Marker positions in the first frame, image pixels; or
        corners : (left (2,), right (2,)), optional
            the two mouth corners in the first frame (the paper's manual initialisation).

        Returns
        -------
        TrackResult

        Raises
        ------
        ParameterError
            Invalid tracker settings, frames, units, expression or ``neutral``; both or
            neither of ``init_markers`` and ``corners``; initial markers outside the frames;
            a first frame with too few markers to fit.
        """
        lk = self._check_params()
        f = _check_frames(frames)
        check_units(units, expression)
        if neutral is None:
            raise ParameterError("neutral (79, 2) is required: the subject's neutral face in "
                                 "the aligned frame, e.g. speaker_neutrals(corpus)[speaker]")
        model_basis(units, expression, neutral=neutral)  # validates ``neutral``
        p0 = self._initial(f, neutral, init_markers, corners)
        n, need = len(f), min_markers(units, expression)
        out = {"markers": np.empty((n, N_MARKERS, 2)), "measured": np.empty((n, N_MARKERS, 2)),
               "used": np.ones((n, N_MARKERS), bool), "mups": np.zeros((n, units.n_mups)),
               "beta": np.zeros((n, 6)), "residual_px": np.full(n, np.nan)}
        zeta, found = p0, np.ones(N_MARKERS, bool)
        for t in range(n):
            if t > 0:
                zeta, found = _lk_step(f[t - 1], f[t], out["markers"][t - 1], lk)
                if self.anchor_px is not None:
                    za, fa = _lk_step(f[0], f[t], p0, lk, guess=zeta)
                    ok = fa & (np.linalg.norm(za - zeta, axis=1) <= self.anchor_px)
                    zeta, found = np.where(ok[:, None], za, zeta), found | ok
            prev = out["markers"][t - 1] if t > 0 else None
            res, used = self._fit_frame(zeta, found, prev, units, expression, neutral, need)
            if res is None:
                if t == 0:
                    raise ParameterError("the first frame leaves too few markers to fit")
                for k in ("markers", "mups", "beta"):  # too few points: hold the last fit
                    out[k][t] = out[k][t - 1]
                used = np.zeros(N_MARKERS, bool)
            else:
                out["markers"][t], out["mups"][t], out["beta"][t] = (
                    res.markers[0], res.mups[0], res.beta[0])
                d = np.linalg.norm(res.markers[0] - zeta, axis=1)[used]
                out["residual_px"][t] = np.sqrt((d**2).mean())
            out["measured"][t], out["used"][t] = zeta, used
        return TrackResult(**out)
