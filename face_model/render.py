"""A clean 2D face drawn from the 79 markers (paper Figs. 6 and 7): skin, mesh, outline, eyes
behind the glasses, brows, nose, filled lips and the mouth opening.

Parts without markers (head outline, eyes, nose, ears) are auxiliary points that follow the
markers: each moves by an inverse-distance-weighted mean of the displacements of its nearest
markers (weights fixed on the neutral layout), so head motion, jaw opening and expressions carry
them along. Drawing uses OpenCV with anti-aliasing and sub-pixel coordinates.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from face_model.layout import (BROW_ROW, FACE_CENTRE, LEFT_INNER_CORNER, LEFT_OUTER_CORNER,
                               LOWER_INNER, LOWER_OUTER, N_MARKERS, RIGHT_INNER_CORNER,
                               RIGHT_OUTER_CORNER, UPPER_INNER, UPPER_OUTER, default_layout)
from groundwork.errors import ParameterError

_SHIFT = 4  # sub-pixel bits for cv2 drawing
_COLOURS = {  # RGB
    "background": (236, 240, 244), "skin": (238, 200, 170), "skin_edge": (190, 140, 110),
    "mesh": (222, 182, 152), "lips": (196, 74, 84), "mouth": (70, 22, 30), "teeth": (245, 242,
                                                                                       235),
    "brow": (92, 62, 44), "eye_white": (252, 252, 250), "iris": (70, 100, 140),
    "pupil": (20, 20, 25), "glasses": (45, 45, 55), "nose": (176, 128, 100), "hair": (80, 56, 40),
}


def _ellipse(cx, cy, ax, ay, n=48, start=0.0, stop=2 * np.pi):
    t = np.linspace(start, stop, n, endpoint=False)
    return np.stack([cx + ax * np.cos(t), cy + ay * np.sin(t)], 1)


@dataclass(frozen=True)
class _Aux:
    """Auxiliary shapes on the neutral face (relative to FACE_CENTRE), and their weights."""

    shapes: dict  # name → (n, 2) neutral points (absolute pixels)
    weights: np.ndarray  # (n_aux, 79): displacement of aux = weights @ marker displacement
    slices: dict  # name → slice into the stacked aux points


@lru_cache(maxsize=1)
def _aux() -> _Aux:
    c = np.asarray(FACE_CENTRE)
    rel = {
        "head": _ellipse(0, -18, 124, 152),
        "hair": _ellipse(0, -44, 130, 138),
        "ear_L": _ellipse(-128, -10, 12, 26, 16),
        "ear_R": _ellipse(128, -10, 12, 26, 16),
        "eye_L": _ellipse(-44, -32, 17, 8, 24),
        "eye_R": _ellipse(44, -32, 17, 8, 24),
        "iris_L": _ellipse(-44, -32, 6, 6, 16),
        "iris_R": _ellipse(44, -32, 6, 6, 16),
        "lens_L": _ellipse(-44, -32, 30, 19, 32),
        "lens_R": _ellipse(44, -32, 30, 19, 32),
        "nose": np.array([[-4, -22], [-7, 10], [-14, 22], [-6, 27], [0, 25], [6, 27], [14, 22],
                          [7, 10], [4, -22]], float),
    }
    shapes = {k: v + c for k, v in rel.items()}
    pts = np.concatenate(list(shapes.values()))
    neutral = default_layout().neutral
    d = np.linalg.norm(pts[:, None, :] - neutral[None], axis=2)
    k = 6
    near = np.argsort(d, axis=1)[:, :k]
    w = np.zeros((len(pts), N_MARKERS))
    rows = np.arange(len(pts))[:, None]
    w[rows, near] = 1.0 / (d[rows, near] + 8.0) ** 2
    w /= w.sum(1, keepdims=True)
    slices, i = {}, 0
    for name, v in shapes.items():
        slices[name] = slice(i, i + len(v))
        i += len(v)
    return _Aux(shapes, w, slices)


def _check_markers(markers) -> np.ndarray:
    m = np.asarray(markers, dtype=np.float64)
    if m.shape != (N_MARKERS, 2):
        raise ParameterError(f"markers must have shape ({N_MARKERS}, 2), got {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ParameterError("markers hold NaN or inf values")
    return m


def _pts(p: np.ndarray) -> np.ndarray:
    return np.round(p * (1 << _SHIFT)).astype(np.int32).reshape(-1, 1, 2)


class FaceRenderer:
    """Draw faces from markers into RGB images (the paper's Figs. 6 and 7).

    Parameters
    ----------
    size : (width, height)
        Output image size in pixels.
    crop : (x0, y0, x1, y1)
        The region of the marker image (pixels) shown; the default frames the head.
    mesh : bool
        Draw the skin mesh (the paper's Fig. 2b triangles) faintly over the skin.
    neutral : ndarray (79, 2), optional
        The neutral face the auxiliary parts are attached to, pixels (default: the layout's).

    Raises
    ------
    ParameterError
        An empty crop, a size below 16 pixels, or a ``neutral`` of another shape.
    """

    def __init__(self, size=(368, 400), crop=(136.0, 50.0, 504.0, 450.0), mesh: bool = True,
                 neutral: np.ndarray | None = None):
        self.size = (int(size[0]), int(size[1]))
        self.crop = tuple(float(v) for v in crop)
        self.mesh = mesh
        self.neutral = (default_layout().neutral if neutral is None
                        else _check_markers(neutral))
        x0, y0, x1, y1 = self.crop
        if x1 <= x0 or y1 <= y0 or min(self.size) < 16:
            raise ParameterError(f"invalid crop {self.crop} or size {self.size}")
        self._scale = np.array([self.size[0] / (x1 - x0), self.size[1] / (y1 - y0)])
        self._offset = np.array([x0, y0])
        self._triangles = default_layout().triangles

    def _to_image(self, p: np.ndarray) -> np.ndarray:
        return (p - self._offset) * self._scale

    def render(self, markers: np.ndarray) -> np.ndarray:
        """One face.

        Parameters
        ----------
        markers : ndarray, shape (79, 2)
            Marker positions, pixels, in the frame of the layout (head motion included, if
            any).

        Returns
        -------
        ndarray of uint8, shape (height, width, 3)
            RGB.

        Raises
        ------
        ParameterError
            Markers of another shape or not finite.
        """
        m = _check_markers(markers)
        aux = _aux()
        disp = m - self.neutral
        base = np.concatenate(list(aux.shapes.values()))
        pts = self._to_image(base + aux.weights @ disp)
        mk = self._to_image(m)
        part = {k: pts[s] for k, s in aux.slices.items()}
        img = np.empty((self.size[1], self.size[0], 3), np.uint8)
        img[:] = _COLOURS["background"]
        aa = cv2.LINE_AA

        def poly(p, colour, filled=True, thick=1):
            if filled:
                cv2.fillPoly(img, [_pts(p)], colour, aa, _SHIFT)
            else:
                cv2.polylines(img, [_pts(p)], False, colour, thick, aa, _SHIFT)

        lw = max(1, int(round(self._scale.mean())))
        poly(part["hair"], _COLOURS["hair"])
        for ear in ("ear_L", "ear_R"):
            poly(part[ear], _COLOURS["skin"])
        poly(part["head"], _COLOURS["skin"])
        cv2.polylines(img, [_pts(part["head"])], True, _COLOURS["skin_edge"], lw, aa, _SHIFT)
        if self.mesh:  # the skin mesh, kept inside the head outline
            layer = img.copy()
            tri = mk[self._triangles]
            cv2.polylines(layer, [_pts(t) for t in tri], True, _COLOURS["mesh"], 1, aa, _SHIFT)
            inside = np.zeros(img.shape[:2], np.uint8)
            cv2.fillPoly(inside, [_pts(part["head"])], 1, cv2.LINE_8, _SHIFT)
            img[inside > 0] = layer[inside > 0]
        for side in ("L", "R"):
            poly(part[f"eye_{side}"], _COLOURS["eye_white"])
            poly(part[f"iris_{side}"], _COLOURS["iris"])
            centre = part[f"iris_{side}"].mean(0)
            cv2.circle(img, tuple(_pts(centre)[0, 0]), int(2.5 * self._scale.mean() * 16),
                       _COLOURS["pupil"], -1, aa, _SHIFT)
            cv2.polylines(img, [_pts(part[f"lens_{side}"])], True, _COLOURS["glasses"], lw + 1,
                          aa, _SHIFT)
        # glasses: temples and bridge through the three glasses markers
        gl, gb, gr = mk[76], mk[77], mk[78]
        lens_l, lens_r = part["lens_L"], part["lens_R"]
        poly(np.stack([gl, lens_l[np.argmin(lens_l[:, 0])]]), _COLOURS["glasses"], False, lw + 1)
        poly(np.stack([gr, lens_r[np.argmax(lens_r[:, 0])]]), _COLOURS["glasses"], False, lw + 1)
        poly(np.stack([lens_l[np.argmax(lens_l[:, 0])], gb, lens_r[np.argmin(lens_r[:, 0])]]),
             _COLOURS["glasses"], False, lw + 1)
        brow = mk[list(BROW_ROW)]
        for half in (brow[:4], brow[4:]):
            poly(half, _COLOURS["brow"], False, 3 * lw)
        poly(part["nose"], _COLOURS["nose"], False, lw)
        # nasolabial folds from the nose wings to just outside the mouth corners: they follow
        # the corners, so a smile (corners up and out) and a sad mouth (corners down) read at once
        for wing, corner, sgn in ((part["nose"][2], mk[LEFT_OUTER_CORNER], -1.0),
                                  (part["nose"][6], mk[RIGHT_OUTER_CORNER], 1.0)):
            end = corner + self._scale * np.array([sgn * 5.0, 6.0])
            mid = (wing + end) / 2 + self._scale * np.array([sgn * 6.0, 0.0])
            poly(np.stack([wing + self._scale * [sgn * 3.0, 2.0], mid, end]),
                 _COLOURS["skin_edge"], False, lw)
        outer = mk[[LEFT_OUTER_CORNER, *UPPER_OUTER, RIGHT_OUTER_CORNER, *LOWER_OUTER]]
        inner = mk[[LEFT_INNER_CORNER, *UPPER_INNER, RIGHT_INNER_CORNER, *LOWER_INNER]]
        poly(outer, _COLOURS["lips"])
        poly(inner, _COLOURS["mouth"])
        upper_inner = mk[[LEFT_INNER_CORNER, *UPPER_INNER, RIGHT_INNER_CORNER]]
        gap = float(np.ptp(inner[:, 1]))
        if gap > 3.0:  # an open mouth shows the upper teeth
            teeth = np.concatenate([upper_inner, upper_inner[::-1] + [0, min(gap * 0.3, 4.0)]])
            poly(self._clip_inside(teeth, inner), _COLOURS["teeth"])
        cv2.polylines(img, [_pts(outer)], True, (150, 50, 60), lw, aa, _SHIFT)
        return img

    @staticmethod
    def _clip_inside(teeth: np.ndarray, inner: np.ndarray) -> np.ndarray:
        lo = inner[:, 1].min()
        out = teeth.copy()
        out[:, 1] = np.maximum(out[:, 1], lo)
        return out


GRID_WIDTH_IN = 4.5  # narrower than the narrowest a report draws a grid (0.7 x 17 cm = 4.69 in)
GRID_CELL_IN = 1.9  # a face's width when few columns leave room
GRID_TITLE_PT = 7.5


def face_grid(images: list, titles: list, path, *, ncols: int = 5,
              width_in: float | None = None) -> Path:
    """Rendered faces in a grid with a title under each (Figs. 4, 6, 7 style), as a PNG.

    The grid is ``width_in`` wide (by default :data:`GRID_CELL_IN` a column, at most
    :data:`GRID_WIDTH_IN`), and a report draws it at least that wide, so its titles print at
    :data:`GRID_TITLE_PT` or more.

    Parameters
    ----------
    images : list of ndarray, each (height, width, 3) uint8
        RGB faces (:meth:`FaceRenderer.render`), all of the first one's size.
    titles : list of str
        One per image.
    path : path-like
        The PNG file (200 dpi); its folder is created.
    ncols : int
        Faces per row.
    width_in : float, optional
        The grid's width, inches.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    from matplotlib.figure import Figure  # the figure alone: no pyplot, no backend to choose

    n = len(images)
    nrows = int(np.ceil(n / ncols))
    h, w = images[0].shape[:2]
    width_in = min(GRID_CELL_IN * ncols, GRID_WIDTH_IN) if width_in is None else width_in
    cell = width_in / ncols
    fig = Figure(figsize=(width_in, nrows * (cell * h / w + 0.2)), layout="constrained")
    fig.get_layout_engine().set(w_pad=1 / 72, h_pad=1 / 72, wspace=0.01, hspace=0.01)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, img, title in zip(axes.ravel(), images, titles):
        ax.imshow(img)
        ax.text(0.5, -0.03, title, fontsize=GRID_TITLE_PT, ha="center", va="top",
                transform=ax.transAxes)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=200, bbox_inches="tight", pad_inches=0.03)
    return path
