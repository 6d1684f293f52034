"""Render a marker face as a grayscale video for the tracker, and measure the tracker on it.

The paper tracks markers on a real face in video (§V: per-point Lucas–Kanade [58], then the
MU constraint of Eq. 5). A synthetic corpus only holds marker positions, so this module draws
them: 30 fps frames, uint8 grayscale, one image per marker frame.

What a frame shows, in drawing order:

* a skin texture (band-limited noise over a smooth shading, with a dark background outside the
  face ellipse) attached to the face: each frame warps the first frame's texture piecewise
  affinely over the skin mesh of Fig. 2b (``FaceLayout.triangles``), so the skin moves exactly
  with its markers, and by the markers' least-squares similarity elsewhere;
* the lips (outer contour, darkened) and the mouth opening (inner contour, dark);
* one bright Gaussian dot (σ = ``DOT_SIGMA_PX``, peak ``DOT_AMPLITUDE`` grey levels above the
  skin) centred exactly on each marker. At rest the inner-lip markers are 2.4 px apart, so
  their dots merge, as real markers on closed lips do;
* then the :class:`VideoDifficulty`: an occluding box, a brightness change, blur, sensor noise.

Image coordinates follow OpenCV: pixel (row i, column j) has its centre at (x = j, y = i). Marker
pixels map to image pixels by ``image = scale · markers + offset`` (:class:`ImageMapping`); the
default 320 × 320 frame at scale 1 holds the corpus face (about 240 × 270 px with head motion)
centred on its bounding box over the utterance. Every random choice comes from ``seed``.

:func:`tracking_error_curve` renders utterances at several noise levels, tracks them with
:class:`face_model.tracker.MUTracker` and returns the marker errors of raw Lucas–Kanade and of
the MU-constrained tracker.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from face_model.alignment import similarity_params
from face_model.detect import initial_markers_from_image
from face_model.layout import (
    LEFT_INNER_CORNER,
    LEFT_OUTER_CORNER,
    LOWER_INNER,
    LOWER_OUTER,
    N_MARKERS,
    RIGHT_INNER_CORNER,
    RIGHT_OUTER_CORNER,
    UPPER_INNER,
    UPPER_OUTER,
    default_layout,
)
from face_model.tracker import MUTracker, init_from_mouth_corners, track_points_lk
from groundwork.errors import ParameterError

FPS = 30
DEFAULT_SIZE = (320, 320)  # width, height in pixels
DOT_SIGMA_PX = 1.0
DOT_AMPLITUDE = 130.0  # grey levels added at a dot's centre
_DOT_RADIUS = 3  # the dot is drawn on a (2r+1)² patch (±3σ)
_SKIN, _BACKGROUND = 105.0, 35.0  # grey levels
_LIPS, _MOUTH = 0.7, 0.3  # brightness factors inside the lips and the mouth opening
_OCCLUDER = 70.0
_MARGIN_PX = 4
_OUTER = [LEFT_OUTER_CORNER, *UPPER_OUTER, RIGHT_OUTER_CORNER, *LOWER_OUTER]
_INNER = [LEFT_INNER_CORNER, *UPPER_INNER, RIGHT_INNER_CORNER, *LOWER_INNER]
ILLUMINATION_PROFILES = ("ramp", "step")


@dataclass(frozen=True)
class VideoDifficulty:
    """How hard the rendered video is to track.

    Parameters
    ----------
    noise_sd : float
        Standard deviation of i.i.d. Gaussian sensor noise, grey levels (of 0–255).
    blur_px : float
        σ of a Gaussian blur applied to every frame, pixels (0: none).
    illumination_change : float
        Relative brightness change over the sequence: the frames are multiplied by
        ``1 + illumination_change · p(t)`` with ``p`` rising from 0 to 1 (``ramp``, linear over
        the sequence) or jumping from 0 to 1 at the middle frame (``step``). 0.3 = 30 %
        brighter at the end; negative values (> −1) darken.
    illumination_profile : {"ramp", "step"}
        The shape of ``p(t)``.
    occlusion : tuple or None
        ``(start_s, duration_s, (x0, y0, x1, y1))``: a flat box (image pixels, x0 ≤ x < x1,
        y0 ≤ y < y1) drawn over the face in the frames with ``start_s ≤ k / 30 < start_s +
        duration_s`` — a hand passing in front of the face.

    Raises
    ------
    ParameterError
        A value outside those ranges.
    """

    noise_sd: float = 0.0
    blur_px: float = 0.0
    illumination_change: float = 0.0
    illumination_profile: str = "ramp"
    occlusion: tuple | None = None

    def __post_init__(self):
        def number(v) -> float:
            try:
                return float(v)
            except (TypeError, ValueError):
                return float("nan")

        for name in ("noise_sd", "blur_px"):
            v = getattr(self, name)
            if not number(v) >= 0 or not np.isfinite(number(v)):
                raise ParameterError(f"VideoDifficulty.{name} must be a finite number >= 0, "
                                     f"got {v!r}")
        change = number(self.illumination_change)
        if not np.isfinite(change) or change <= -1:
            raise ParameterError("VideoDifficulty.illumination_change must be a finite number "
                                 f"> -1, got {self.illumination_change!r}")
        if self.illumination_profile not in ILLUMINATION_PROFILES:
            raise ParameterError(f"VideoDifficulty.illumination_profile "
                                 f"{self.illumination_profile!r}; allowed: "
                                 f"{', '.join(ILLUMINATION_PROFILES)}")
        if self.occlusion is not None:
            try:
                start, dur, box = self.occlusion
                x0, y0, x1, y1 = (float(b) for b in box)
                ok = start >= 0 and dur > 0 and x1 > x0 and y1 > y0
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise ParameterError("VideoDifficulty.occlusion must be None or (start_s >= 0, "
                                     "duration_s > 0, (x0, y0, x1, y1)) with x1 > x0 and "
                                     f"y1 > y0, got {self.occlusion!r}")

    def occluded_frames(self, n_frames: int) -> np.ndarray:
        """Boolean mask (n_frames,) of the frames the occluding box is drawn on."""
        if self.occlusion is None:
            return np.zeros(n_frames, bool)
        t = np.arange(n_frames) / FPS
        start, dur, _ = self.occlusion
        return (t >= start - 1e-9) & (t < start + dur - 1e-9)


@dataclass(frozen=True)
class ImageMapping:
    """``image = scale · markers + offset``: from marker pixels to the video's image pixels.

    Attributes
    ----------
    scale : float
        Image pixels per marker pixel.
    offset : tuple of float
        (x, y) image pixels.
    """

    scale: float
    offset: tuple = field(default=(0.0, 0.0))

    def to_image(self, points) -> np.ndarray:
        """Marker-pixel points (..., 2) → image pixels (..., 2)."""
        return self.scale * np.asarray(points, dtype=np.float64) + np.asarray(self.offset)

    def to_markers(self, points) -> np.ndarray:
        """Image-pixel points (..., 2) → marker pixels (..., 2)."""
        return (np.asarray(points, dtype=np.float64) - np.asarray(self.offset)) / self.scale


def _check_markers(markers) -> np.ndarray:
    m = np.asarray(markers, dtype=np.float64)
    if m.ndim != 3 or m.shape[1:] != (N_MARKERS, 2) or len(m) == 0:
        raise ParameterError(f"markers must have shape (n_frames, {N_MARKERS}, 2) with "
                             f"n_frames >= 1, got {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ParameterError("markers hold NaN or inf values")
    return m


def _mapping(m: np.ndarray, size: tuple, scale: float) -> ImageMapping:
    """Centre the markers' bounding box (over all frames) in the image, on whole pixels."""
    w, h = size
    lo, hi = m.reshape(-1, 2).min(0), m.reshape(-1, 2).max(0)
    centre_img = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    offset = np.round(centre_img - scale * (lo + hi) / 2.0)
    mapping = ImageMapping(float(scale), (float(offset[0]), float(offset[1])))
    pts = mapping.to_image(m)
    bad = np.flatnonzero(((pts < _MARGIN_PX) | (pts > np.array([w, h]) - 1 - _MARGIN_PX))
                         .any(axis=(1, 2)))
    if len(bad):
        raise ParameterError(f"at scale {scale} the markers do not fit a {w}x{h} image (they "
                             f"span {np.ptp(pts[..., 0]):.0f}x{np.ptp(pts[..., 1]):.0f} px; "
                             f"first frame outside: {bad[0]}); use a larger size or a smaller "
                             "scale")
    return mapping


def _texture(rng: np.random.Generator, ref: np.ndarray, w: int, h: int) -> np.ndarray:
    """Skin texture (h, w) float32 in the first frame's geometry: smooth shading, fine noise,
    dark background outside an ellipse around the face."""
    fine = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 1.5)
    coarse = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 8.0)
    tex = _SKIN + 14.0 * fine / fine.std() + 10.0 * coarse / coarse.std()
    centre = 0.5 * (ref.min(0) + ref.max(0))
    half = 0.5 * np.ptp(ref, axis=0) + 18.0
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r = np.hypot((xx - centre[0]) / half[0], (yy - centre[1]) / half[1])
    inside = np.clip((1.08 - r) / 0.08, 0.0, 1.0)  # a soft edge a few pixels wide
    return (inside * tex + (1.0 - inside) * _BACKGROUND).astype(np.float32)


def _warp_maps(cur: np.ndarray, ref: np.ndarray, tri: np.ndarray, x: np.ndarray,
               y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Backward maps (h, w) float32: where each pixel of this frame was in the first frame.

    Inside the skin mesh (Fig. 2b) the warp is piecewise affine — the skin moves exactly with
    its markers; elsewhere (background, mouth opening) it is the least-squares similarity
    cur → ref of all markers.
    """
    A, t = similarity_params(cur[None], ref[None])
    # One affine per triangle (rows: coefficients of x, y, 1), then the similarity, which
    # the pixels no triangle covers pick (their label is the number of triangles).
    P = np.concatenate([cur[tri], np.ones((len(tri), 3, 1))], axis=2)
    M = np.concatenate([np.linalg.pinv(P) @ ref[tri],  # pinv: a collapsed triangle is no error
                        np.concatenate([A[0].T, t[0][None]])[None]]).astype(np.float32)
    label = np.full(x.shape, len(tri), np.uint8)  # the layout has < 255 triangles
    for k, corners in enumerate(np.round(cur[tri] * 16).astype(np.int32)):
        cv2.fillConvexPoly(label, corners, k, cv2.LINE_8, shift=4)
    lut = np.zeros((256, 6), np.float32)
    lut[:len(M)] = M.reshape(len(M), 6)
    c = [cv2.LUT(label, np.ascontiguousarray(lut[:, i])) for i in range(6)]  # a table look-up
    return x * c[0] + y * c[2] + c[4], x * c[1] + y * c[3] + c[5]


def _shade(img: np.ndarray, poly: np.ndarray, factor: float) -> None:
    """Multiply ``img`` by ``factor`` inside the polygon (anti-aliased edge, sub-pixel
    vertices): the region darkens and keeps its texture."""
    mask = np.zeros(img.shape, np.uint8)
    cv2.fillPoly(mask, [np.round(poly * 16).astype(np.int32)], 255, cv2.LINE_AA, shift=4)
    img *= 1.0 - (1.0 - factor) * (mask.astype(np.float32) / 255.0)


def _add_dots(frames: np.ndarray, pts: np.ndarray, amplitude: float) -> None:
    """Add a Gaussian dot of peak ``amplitude`` at each of ``pts`` (n, 79, 2) to ``frames``."""
    n, h, w = frames.shape
    r = np.arange(-_DOT_RADIUS, _DOT_RADIUS + 1)
    f = np.arange(n)[:, None, None]
    for j in range(pts.shape[1]):  # one marker at a time: its patches never collide
        p = pts[:, j]
        px = np.round(p[:, 0]).astype(np.int64)[:, None, None] + r[None, None, :]
        py = np.round(p[:, 1]).astype(np.int64)[:, None, None] + r[None, :, None]
        val = np.exp(-((px - p[:, 0, None, None]) ** 2 + (py - p[:, 1, None, None]) ** 2)
                     / (2 * DOT_SIGMA_PX**2))
        px, py = np.clip(px, 0, w - 1), np.clip(py, 0, h - 1)  # markers keep a margin: no-op
        frames[f, py, px] += (amplitude * val).astype(np.float32)


def render_marker_video(markers, *, size: tuple = DEFAULT_SIZE, scale: float = 1.0,
                        difficulty: VideoDifficulty | None = None,
                        seed: int = 0) -> tuple[np.ndarray, ImageMapping]:
    """Draw an utterance's markers as a 30 fps grayscale video.

    Parameters
    ----------
    markers : array_like, shape (n_frames, 79, 2)
        Marker positions in pixels (a corpus utterance's ``markers``, head motion included).
    size : (int, int)
        Frame width and height, pixels.
    scale : float
        Image pixels per marker pixel.
    difficulty : VideoDifficulty, optional
        Noise, blur, illumination change and occlusion (default: none).
    seed : int
        Seeds the skin texture and the sensor noise (the noise draws are the same standard
        normals for every ``noise_sd``, so levels of one curve differ only in amplitude).

    Returns
    -------
    frames : ndarray of uint8, shape (n_frames, height, width)
        Grey levels; frame k is at k / 30 s.
    mapping : ImageMapping
        ``mapping.to_image(markers)`` gives the dot centres in image pixels.

    Raises
    ------
    ParameterError
        Markers of another shape, empty or not finite; a size below 32 pixels or a scale not
        > 0; markers that do not fit the frame at that scale.
    """
    m = _check_markers(markers)
    difficulty = VideoDifficulty() if difficulty is None else difficulty
    if not isinstance(difficulty, VideoDifficulty):
        raise ParameterError(f"difficulty must be a VideoDifficulty, got {type(difficulty)}")
    try:
        w, h = (int(s) for s in size)
    except (TypeError, ValueError):
        w = h = 0
    if w < 32 or h < 32:
        raise ParameterError(f"size must be (width, height) of at least 32 px each, got {size!r}")
    if not np.isfinite(scale) or scale <= 0:
        raise ParameterError(f"scale must be > 0, got {scale!r}")
    mapping = _mapping(m, (w, h), float(scale))
    pts = mapping.to_image(m)
    n = len(pts)
    tex_seed, noise_seed = np.random.SeedSequence(seed).spawn(2)
    texture = _texture(np.random.default_rng(tex_seed), pts[0], w, h)
    tri = default_layout().triangles
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    frames = np.empty((n, h, w), np.float32)
    for k in range(n):
        mx, my = _warp_maps(pts[k], pts[0], tri, x, y)
        img = cv2.remap(texture, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        _shade(img, pts[k, _OUTER], _LIPS)
        _shade(img, pts[k, _INNER], _MOUTH)
        frames[k] = img
    _add_dots(frames, pts, DOT_AMPLITUDE)
    d = difficulty
    occluded = d.occluded_frames(n)
    if occluded.any():
        x0, y0, x1, y1 = d.occlusion[2]
        xs = slice(max(int(np.ceil(x0)), 0), max(int(np.ceil(x1)), 0))
        ys = slice(max(int(np.ceil(y0)), 0), max(int(np.ceil(y1)), 0))
        frames[occluded, ys, xs] = _OCCLUDER
    if d.illumination_change:
        if d.illumination_profile == "ramp":
            p = np.arange(n) / max(n - 1, 1)
        else:
            p = (np.arange(n) >= n // 2).astype(np.float64)
        frames *= (1.0 + d.illumination_change * p).astype(np.float32)[:, None, None]
    if d.blur_px > 0:
        for k in range(n):
            frames[k] = cv2.GaussianBlur(frames[k], (0, 0), d.blur_px)
    if d.noise_sd > 0:
        noise = np.random.default_rng(noise_seed).standard_normal(frames.shape, np.float32)
        frames += np.float32(d.noise_sd) * noise
    return np.clip(np.rint(frames), 0, 255).astype(np.uint8), mapping


INITS = ("markers", "corners", "image")


def first_frame_markers(frame, truth, units, expression: str, neutral, init: str) -> np.ndarray:
    """The tracker's starting markers on the first frame of a rendered video.

    Parameters
    ----------
    frame : ndarray of uint8, shape (height, width)
        The first frame.
    truth : array_like, shape (79, 2)
        The true markers of that frame, image pixels.
    units : MotionUnits
        The MU model (``init="image"`` refines its placement with it).
    expression : str
        The utterance's expression state.
    neutral : array_like, shape (79, 2)
        The speaker's neutral face in the aligned frame, pixels.
    init : {"markers", "corners", "image"}
        The true markers; the neutral face placed by the true mouth corners (the paper's
        manual initialisation, §V); or the markers found in the image
        (:func:`face_model.detect.initial_markers_from_image`).

    Returns
    -------
    ndarray, shape (79, 2)
        Image pixels.

    Raises
    ------
    ParameterError
        An unknown ``init``, or (``image``) a face not found in the frame.
    """
    if init == "markers":
        return np.asarray(truth, dtype=np.float64)
    if init == "corners":
        return init_from_mouth_corners(neutral, truth[LEFT_OUTER_CORNER],
                                       truth[RIGHT_OUTER_CORNER])
    if init == "image":
        return initial_markers_from_image(frame, units, expression, neutral=neutral)
    raise ParameterError(f"init {init!r}; allowed: {', '.join(INITS)}")


@dataclass(frozen=True)
class TrackingErrorCurve:
    """Mean marker error (marker pixels) against the ground truth, one entry per noise level.

    Attributes
    ----------
    noise_sd : ndarray, shape (n_levels,)
        The sensor noise levels, grey levels.
    lk_px : ndarray, shape (n_levels,)
        Raw Lucas–Kanade chained through the sequence.
    measured_px : ndarray, shape (n_levels,)
        The Lucas–Kanade measurements ``ζ(t)`` inside the constrained tracker (one LK step
        from the constrained positions).
    constrained_px : ndarray, shape (n_levels,)
        The MU-constrained tracker (§V).
    n_frames : int
        Frames tracked per level (over all utterances).
    """

    noise_sd: np.ndarray
    lk_px: np.ndarray
    measured_px: np.ndarray
    constrained_px: np.ndarray
    n_frames: int

    def rows(self) -> list[dict]:
        """One dict per noise level, for a table."""
        return [{"noise_sd": float(s), "lk_px": float(a), "measured_px": float(m),
                 "constrained_px": float(c)}
                for s, a, m, c in zip(self.noise_sd, self.lk_px, self.measured_px,
                                      self.constrained_px)]


def tracking_error_curve(utterances, units, *, neutrals, noise_levels=(0.0, 10.0, 20.0, 40.0),
                         difficulty: VideoDifficulty | None = None, size: tuple = DEFAULT_SIZE,
                         scale: float = 1.0, seed: int = 0, tracker=None,
                         init: str = "markers") -> TrackingErrorCurve:
    """Render utterances at several noise levels, track them, and measure the marker errors.

    Each utterance is rendered with :func:`render_marker_video` (its own seed from ``seed``,
    shared by the noise levels), then tracked by raw Lucas–Kanade and by the MU-constrained
    tracker, both started from the same first-frame positions. Errors are Euclidean distances
    to the rendered markers, averaged over markers, frames and utterances, in marker pixels.

    Parameters
    ----------
    utterances : sequence of Utterance
        Each with ``markers`` (n, 79, 2), ``expression`` and ``speaker``.
    units : MotionUnits
    neutrals : dict
        Speaker → neutral face (79, 2) in the aligned frame (``speaker_neutrals(corpus)``).
    noise_levels : sequence of float
        Sensor noise standard deviations, grey levels.
    difficulty : VideoDifficulty, optional
        Other difficulty settings; its ``noise_sd`` is replaced by each level.
    size, scale
        Frame size and image pixels per marker pixel (:func:`render_marker_video`).
    seed : int
        Seeds each utterance's video (one seed per utterance, drawn from this one).
    tracker : MUTracker, optional
        Default: ``MUTracker()``.
    init : {"markers", "corners", "image"}
        Start from the true first-frame markers; from the neutral face placed by the true
        mouth corners (:func:`face_model.tracker.init_from_mouth_corners`, the paper's manual
        initialisation; its placement error then stays in both tracks); or from the markers
        found in the first image (:func:`face_model.detect.initial_markers_from_image`).

    Returns
    -------
    TrackingErrorCurve

    Raises
    ------
    ParameterError
        An unknown ``init``, no noise level or utterance, a speaker without a neutral face.
    """
    tracker = MUTracker() if tracker is None else tracker
    base = VideoDifficulty() if difficulty is None else difficulty
    levels = np.asarray(noise_levels, dtype=np.float64)
    utterances = list(utterances)
    if init not in INITS:
        raise ParameterError(f"init {init!r}; allowed: {', '.join(INITS)}")
    if levels.ndim != 1 or len(levels) == 0 or not utterances:
        raise ParameterError("tracking_error_curve needs at least one noise level and one "
                             "utterance")
    seeds = np.random.SeedSequence(seed).generate_state(len(utterances))
    sums = np.zeros((len(levels), 3))
    n_total = 0
    for u, s in zip(utterances, seeds):
        if u.speaker not in neutrals:
            raise ParameterError(f"no neutral face for speaker {u.speaker!r}; neutrals has "
                                 f"{sorted(neutrals)}")
        n_total += u.markers.shape[0]
        for i, sd in enumerate(levels):
            frames, mapping = render_marker_video(u.markers, size=size, scale=scale, seed=int(s),
                                                  difficulty=replace(base, noise_sd=float(sd)))
            truth = mapping.to_image(u.markers)
            p0 = first_frame_markers(frames[0], truth[0], units, u.expression,
                                     neutrals[u.speaker], init)
            lk, _ = track_points_lk(frames, p0, win_size=tracker.win_size,
                                    max_level=tracker.max_level,
                                    lk_iterations=tracker.lk_iterations,
                                    lk_epsilon=tracker.lk_epsilon)
            res = tracker.track(frames, units, u.expression, neutral=neutrals[u.speaker],
                                init_markers=p0)
            for j, est in enumerate((lk, res.measured, res.markers)):
                sums[i, j] += np.linalg.norm(est - truth, axis=-1).mean(1).sum() / scale
    mean = sums / n_total
    return TrackingErrorCurve(levels, mean[:, 0], mean[:, 1], mean[:, 2], n_total)
