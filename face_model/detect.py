"""Finding the face in the tracker's first image: marker dots, mouth corners, the initial mesh.

The paper starts its tracker (§V) by fitting the mesh to the first, neutral and frontal frame
from the two mouth corners, which a person selects. :func:`initial_markers_from_image` does the
selection itself, in three steps:

1. :func:`detect_marker_dots` — the markers are small bright dots: a Gaussian matched filter
   (σ = the dot size) then a white top-hat (the image minus its grey opening, which removes
   anything wider than a dot: shading, lips, background), local maxima above
   ``min_contrast`` grey levels, and a sub-pixel peak by a parabola through the 3 × 3
   neighbourhood. At rest the inner-lip dots are closer than a dot width and merge into one peak
   (as they do on a real face); that is expected and handled below.
2. :func:`register_layout` — the subject's neutral face (79 points) is registered to the dots
   by a trimmed similarity ICP started from the dots' centroid and spread, with small rotations
   only (the first frame is frontal). The mouth corners are the dots matched to markers 46 and
   55.
3. The neutral mesh is placed by those two corners
   (:func:`face_model.tracker.init_from_mouth_corners`, the paper's step); the similarity is
   re-fitted to all the dots from there (two points fix it loosely: a corner one pixel off tilts
   the forehead by three), then refined by the MU model: each marker takes the strongest
   confident dot within a radius (``radii``, shrinking; a dot two markers claim goes to neither)
   and Eq. 5 is fitted to the matches (:func:`face_model.mu_fit.fit_linear`), a few times. This
   also handles a first frame that is not neutral (a sentence spoken smiling from its start). A
   marker that owns a dot alone starts on the dot's centre; markers sharing a merged dot, or
   with none, start on the fitted face.

Everything is in image pixels, OpenCV's convention (pixel centres on integers).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from face_model.layout import LEFT_OUTER_CORNER, N_MARKERS, RIGHT_OUTER_CORNER
from face_model.mu_fit import as_points, fit_linear
from face_model.tracker import init_from_mouth_corners
from groundwork.errors import ParameterError

__all__ = ["dot_response", "detect_marker_dots", "register_layout", "find_mouth_corners",
           "initial_markers_from_image", "DotResponse", "LayoutMatch"]


def _gray(image, name: str = "image") -> np.ndarray:
    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] in (3, 4):
        a = cv2.cvtColor(np.ascontiguousarray(a[..., :3]).astype(np.float32), cv2.COLOR_RGB2GRAY)
    if a.ndim != 2 or min(a.shape) < 16:
        raise ParameterError(f"{name} must be a grey (H, W) or colour (H, W, 3) image of at "
                             f"least 16 x 16 pixels, got shape {np.shape(image)}")
    a = a.astype(np.float32)
    if not np.all(np.isfinite(a)):
        raise ParameterError(f"{name} holds NaN or inf values")
    return a


@dataclass(frozen=True)
class DotResponse:
    """The matched-filter response of an image and its local maxima (:func:`dot_response`).

    Attributes
    ----------
    response : ndarray of float32, shape (H, W)
        The top-hat of the Gaussian-filtered image, grey levels.
    noise : float
        A robust standard deviation (1.4826 · MAD) of the filtered image's fine detail
        (sensor noise plus skin texture), grey levels.
    peaks : ndarray, shape (n, 2)
        Sub-pixel (x, y) of every local maximum above 3 ``noise``, image pixels, strongest
        first.
    strength : ndarray, shape (n,)
        The response at each peak, grey levels.
    """

    response: np.ndarray
    noise: float
    peaks: np.ndarray
    strength: np.ndarray

    def dots(self, min_contrast: float = 35.0, z: float = 6.0) -> np.ndarray:
        """The confident dots: the peaks at least ``max(min_contrast, z · noise)`` high.

        Parameters
        ----------
        min_contrast : float
            Least response, grey levels.
        z : float
            Least response in units of ``noise``.

        Returns
        -------
        ndarray, shape (n_dots, 2)
            (x, y) image pixels, strongest first.
        """
        return self.peaks[self.strength >= max(min_contrast, z * self.noise)]


def dot_response(image, *, dot_sigma: float = 1.0, max_peaks: int = 20000) -> DotResponse:
    """Matched filter for the marker dots (see the module text, step 1) and its local maxima.

    Parameters
    ----------
    image : array_like, (H, W) grey or (H, W, 3) RGB, grey levels 0–255
        At least 16 × 16 pixels.
    dot_sigma : float
        The dots' Gaussian radius, pixels (the matched filter's σ).
    max_peaks : int
        More local maxima than this is refused (not an image of a marked face).

    Returns
    -------
    DotResponse

    Raises
    ------
    ParameterError
        An image of another shape or with NaN / inf, ``dot_sigma`` not > 0, too many peaks.
    """
    img = _gray(image)
    if not (np.isfinite(dot_sigma) and dot_sigma > 0):
        raise ParameterError(f"dot_sigma must be > 0, got {dot_sigma!r}")
    smooth = cv2.GaussianBlur(img, (0, 0), float(dot_sigma))
    detail = smooth - cv2.GaussianBlur(smooth, (0, 0), 3.0 * float(dot_sigma))
    noise = float(1.4826 * np.median(np.abs(detail - np.median(detail))))
    r = max(2, int(np.ceil(3 * dot_sigma)))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    resp = cv2.morphologyEx(smooth, cv2.MORPH_TOPHAT, kernel)
    peak = (resp >= cv2.dilate(resp, np.ones((3, 3), np.uint8))) & (resp > 3.0 * noise)
    peak[[0, -1], :] = peak[:, [0, -1]] = False
    ys, xs = np.nonzero(peak)
    if len(xs) > max_peaks:
        raise ParameterError(f"{len(xs)} bright peaks in the image, more than {max_peaks}: this "
                             "does not look like an image of a marked face")
    c, lft, rgt = resp[ys, xs], resp[ys, xs - 1], resp[ys, xs + 1]
    up, dn = resp[ys - 1, xs], resp[ys + 1, xs]

    def vertex(m, p):  # the parabola through (-1, m), (0, c), (1, p) peaks at this offset
        den = m - 2 * c + p
        return np.where(den < 0, 0.5 * (m - p) / np.where(den < 0, den, -1.0), 0.0).clip(-.5, .5)

    pts = np.stack([xs + vertex(lft, rgt), ys + vertex(up, dn)], axis=1).astype(np.float64)
    order = np.argsort(-c, kind="stable")
    return DotResponse(resp, noise, pts[order], c[order].astype(np.float64))


def detect_marker_dots(image, *, dot_sigma: float = 1.0, min_contrast: float = 35.0,
                       z: float = 6.0) -> np.ndarray:
    """Centres of the bright marker dots in one image, strongest first.

    A dot is a local maximum of the matched-filter response (:func:`dot_response`) at least
    ``min_contrast`` grey levels and ``z`` noise standard deviations high (a dot of peak
    amplitude ``a`` above the skin responds with about ``a / 2``). The noise-relative bar keeps
    noise peaks out of noisy images at the cost of missing faint dots; the face is still placed
    from the rest (:func:`register_layout` needs half of them).

    Parameters
    ----------
    image : array_like, (H, W) grey or (H, W, 3) RGB, grey levels 0–255
    dot_sigma : float
        The dots' Gaussian radius, pixels (the matched filter's σ).
    min_contrast : float
        Least response, grey levels.
    z : float
        Least response in noise standard deviations.

    Returns
    -------
    ndarray, shape (n_dots, 2)
        (x, y) image pixels.

    Raises
    ------
    ParameterError
        As :func:`dot_response`.
    """
    return dot_response(image, dot_sigma=dot_sigma).dots(min_contrast, z)


@dataclass(frozen=True)
class LayoutMatch:
    """A similarity registration of a face layout to detected dots (:func:`register_layout`).

    Attributes
    ----------
    placed : ndarray, shape (79, 2)
        The layout under the similarity, image pixels.
    dot_of : ndarray of int, shape (79,)
        Index of each marker's matched dot, −1 when unmatched.
    rms_px : float
        RMS distance of the matched pairs, pixels (inf when none matched).
    """

    placed: np.ndarray
    dot_of: np.ndarray
    rms_px: float

    @property
    def n_matched(self) -> int:
        """Markers with a matched dot."""
        return int((self.dot_of >= 0).sum())


def _umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares similarity ``dst ≈ src @ A.T + t`` (A = scale · rotation)."""
    ms, md = src.mean(0), dst.mean(0)
    s, d = src - ms, dst - md
    a = (s * d).sum()
    b = (s[:, 0] * d[:, 1] - s[:, 1] * d[:, 0]).sum()
    k = (s**2).sum()
    A = np.array([[a, -b], [b, a]]) / k
    return A, md - ms @ A.T


def _strongest_within(points: np.ndarray, peaks: np.ndarray, strength: np.ndarray,
                      radius: float) -> np.ndarray:
    """Each point's strongest peak within ``radius`` (index, −1 when none); a peak claimed by
    two points (merged dots) is given to neither."""
    owner = np.full(len(points), -1)
    if len(peaks):
        for i, near in enumerate(cKDTree(peaks).query_ball_point(points, radius)):
            if near:
                owner[i] = near[int(np.argmax(strength[near]))]
    taken, counts = np.unique(owner[owner >= 0], return_counts=True)
    owner[np.isin(owner, taken[counts > 1])] = -1
    return owner


def _icp(lay, dots, A, t, n_keep: int, iterations: int, inlier_px: float):
    """Trimmed similarity ICP from ``(A, t)``; returns ``A, t``, the kept pairs' RMS and the
    number of dots within ``inlier_px`` of the placed layout."""
    for _ in range(iterations):
        d, idx = cKDTree(lay @ A.T + t).query(dots)
        keep = np.argsort(d, kind="stable")[:n_keep]
        A_new, t_new = _umeyama(lay[idx[keep]], dots[keep])
        done = np.abs(A_new - A).max() < 1e-9 and np.abs(t_new - t).max() < 1e-7
        A, t = A_new, t_new
        if done:
            break
    d, _ = cKDTree(lay @ A.T + t).query(dots)
    return A, t, float(np.sqrt((np.sort(d)[:n_keep] ** 2).mean())), int((d <= inlier_px).sum())


def register_layout(dots, layout, *, trim: float = 0.8, iterations: int = 100,
                    starts_scale=(0.9, 1.0, 1.1), starts_shift=(-0.1, 0.0, 0.1),
                    starts_angle=(-0.06, 0.0, 0.06), inlier_px: float = 1.5) -> LayoutMatch:
    """Register ``layout`` (79, 2) to ``dots`` (n, 2) by a trimmed similarity ICP.

    Each run pairs every dot with its nearest placed layout point (dots may be missing, merged
    or spurious; every dot is a marker or noise), keeps the ``trim`` fraction of the closest
    pairs (of at most 79) and solves the similarity, until it stops moving. The runs start
    from every combination of a rotation in ``starts_angle`` (radians; the frame is frontal, so
    small), the dots' RMS spread times a factor in ``starts_scale``, and the dots' centroid
    shifted by ``starts_shift`` × the face size in x and in y (a sparse or lopsided set of dots
    has its centroid off the face's). The run with the most dots within ``inlier_px`` of a
    marker wins (then the smallest trimmed RMS). The result matches those inlier dots; its
    ``rms_px`` is theirs.

    Parameters
    ----------
    dots : array_like, shape (n, 2)
        Detected dot centres, image pixels; at least a quarter as many as markers (19).
    layout : array_like, shape (79, 2)
        The face to place (the subject's neutral), pixels.
    trim : float
        Fraction of the closest pairs each ICP step solves for.
    iterations : int
        At most this many ICP steps per start.
    starts_scale, starts_shift, starts_angle : sequence of float
        The starts (see above): factors of the dots' spread, shifts as fractions of the face
        size, rotations in radians.
    inlier_px : float
        A dot within this distance of a placed marker is an inlier, pixels.

    Returns
    -------
    LayoutMatch

    Raises
    ------
    ParameterError
        Points of the wrong shape or not finite, or too few dots.
    """
    dots = as_points(dots, "dots", (2,), stacked=True)
    lay = as_points(layout, "layout", (N_MARKERS, 2), stacked=False)
    if len(dots) < N_MARKERS // 4:
        raise ParameterError(f"found {len(dots)} marker dots, need at least {N_MARKERS // 4} "
                             f"of the {N_MARKERS} to place the face")
    scale = np.sqrt(((dots - dots.mean(0)) ** 2).sum(1).mean()
                    / ((lay - lay.mean(0)) ** 2).sum(1).mean())
    n_keep = max(3, int(round(trim * min(len(dots), N_MARKERS))))
    size = np.sqrt(np.ptp(lay, axis=0).prod()) * scale
    best = (-1, np.inf, None, None)
    for angle, factor, dx, dy in itertools.product(starts_angle, starts_scale, starts_shift,
                                                   starts_shift):
        c, s = np.cos(angle), np.sin(angle)
        A = factor * scale * np.array([[c, -s], [s, c]])
        t = dots.mean(0) - lay.mean(0) @ A.T + size * np.array([dx, dy])
        A, t, rms, inliers = _icp(lay, dots, A, t, n_keep, iterations, inlier_px)
        if (inliers, -rms) > (best[0], -best[1]):
            best = (inliers, rms, A, t)
    _, _, A, t = best
    placed = lay @ A.T + t
    d, idx = cKDTree(placed).query(dots)
    near = np.flatnonzero(d <= inlier_px)
    dot_of = np.full(N_MARKERS, -1)
    dot_of[idx[near]] = near
    rms = float(np.sqrt((d[near] ** 2).mean())) if len(near) else np.inf
    return LayoutMatch(placed, dot_of, rms)


def find_mouth_corners(image, neutral, *, response: DotResponse | None = None,
                       search_px: float = 1.5,
                       **detect) -> tuple[np.ndarray, np.ndarray]:
    """The two outer mouth corners (left, right) in a frontal image of a marked face.

    The face is registered to the confident dots (:func:`register_layout`); each corner is
    then the strongest confident dot within ``search_px`` of the registered corner (the
    registered corner itself when noise hides its dot). This is the paper's manual selection
    of the two corners (§V), automated.

    Parameters
    ----------
    image : array_like, (H, W) or (H, W, 3)
        The first frame, grey levels 0–255.
    neutral : array_like, shape (79, 2)
        The subject's neutral face, pixels, in any frame of similar proportions.
    response : DotResponse, optional
        :func:`dot_response` of ``image``, if already computed.
    search_px : float
        How far from the registered corner its dot is looked for, pixels.
    **detect
        ``min_contrast``, ``z`` of :meth:`DotResponse.dots` (which dots are confident).

    Returns
    -------
    left, right : ndarray, shape (2,)
        The outer mouth corners (markers 46 and 55), (x, y) image pixels.

    Raises
    ------
    ParameterError
        Naming the figures, when too few dots fit the face.
    """
    resp = dot_response(image) if response is None else response
    dots = resp.dots(**detect)
    match = register_layout(dots, neutral)
    if match.n_matched < N_MARKERS // 4:
        raise ParameterError(f"only {match.n_matched} of the {len(dots)} dots found fit the "
                             f"face layout (at least {N_MARKERS // 4} of {N_MARKERS} needed): "
                             "is the face frontal, fully in view and marked like the layout?")
    corners = match.placed[[LEFT_OUTER_CORNER, RIGHT_OUTER_CORNER]]
    owner = _strongest_within(corners, dots, np.arange(len(dots), 0, -1.0), search_px)
    found = np.where((owner >= 0)[:, None], dots[np.maximum(owner, 0)], corners)
    return found[0], found[1]


def initial_markers_from_image(image, units, expression: str = "neutral", *, neutral,
                               radii=(4.0, 3.0, 2.0, 1.5), snap_px: float = 1.0,
                               **detect) -> np.ndarray:
    """The tracker's first-frame markers (79, 2), found in the image (see the module text).

    Parameters
    ----------
    image : array_like, (H, W) or (H, W, 3)
        The first frame.
    units : MotionUnits
        The MU model used to refine the corner placement.
    expression : str
        The frame's expression state.
    neutral : array_like (79, 2)
        The subject's neutral face in the aligned model frame.
    radii : sequence of float
        One match-and-fit round per radius: each marker takes the strongest confident dot
        within the radius of its current position (a dot two markers claim is left out), then
        Eq. 5 is fitted to the matched markers.
    snap_px : float
        A last round matches every response peak (also the faint ones) within ``snap_px``;
        then a marker whose own peak lies within ``snap_px`` of the fit starts on the peak.
    **detect
        ``min_contrast``, ``z`` of :meth:`DotResponse.dots` (the registration's dots).

    Returns
    -------
    ndarray, shape (79, 2)
        The first frame's markers, image pixels.

    Raises
    ------
    ParameterError
        Too few dots fit the face (:func:`find_mouth_corners`), or too few markers found a
        dot in a round.
    """
    s0 = as_points(neutral, "neutral", (N_MARKERS, 2), stacked=False)
    resp = dot_response(image)
    left, right = find_mouth_corners(image, s0, response=resp, **detect)
    placed = init_from_mouth_corners(s0, left, right)
    confident = resp.strength >= max(detect.get("min_contrast", 35.0),
                                     detect.get("z", 6.0) * resp.noise)
    # two points fix the similarity loosely (a corner 1 px off tilts the forehead by 3 px):
    # the similarity is re-fitted to all the confident dots, from the corner placement
    A, t = _umeyama(s0, placed)
    n_keep = max(3, int(round(0.8 * min(int(confident.sum()), N_MARKERS))))
    A, t, _, _ = _icp(s0, resp.peaks[confident], A, t, n_keep, 100, 1.5)
    placed = s0 @ A.T + t
    rounds = [(r, confident) for r in radii] + [(snap_px, np.ones(len(resp.peaks), bool))]
    for radius, pool in rounds:
        peaks, strength = resp.peaks[pool], resp.strength[pool]
        owner = _strongest_within(placed, peaks, strength, radius)
        ok = owner >= 0
        if ok.sum() < N_MARKERS // 4:
            raise ParameterError(f"only {int(ok.sum())} of {N_MARKERS} markers found a dot "
                                 f"within {radius} px of the face placed by the mouth corners "
                                 f"{np.round(left, 1).tolist()}, {np.round(right, 1).tolist()}")
        zeta = np.where(ok[:, None], peaks[np.maximum(owner, 0)], placed)
        placed = fit_linear(zeta[None], units, expression, neutral=s0,
                            weights=ok[None] * 1.0).markers[0]
    owner = _strongest_within(placed, resp.peaks, resp.strength, snap_px)
    return np.where((owner >= 0)[:, None], resp.peaks[np.maximum(owner, 0)], placed)
