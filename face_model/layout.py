"""The 79-marker face layout of the paper's Fig. 2: neutral positions, names, regions and mesh.

Markers 0–21 sit on the forehead (the lowest row on the brows), 22–45 on the cheeks, 46–75 around
the lips and 76–78 on the glasses (rigid with the head). Positions are image coordinates in pixels
(x to the right, y down) of a frontal neutral face in a 640 × 480 frame. The layout is defined here
once and versioned by :data:`LAYOUT_VERSION`; corpora record the version they were made with.

Lip marker order (used by the tracker's mouth-corner initialisation and by the lip measures):

* 46 left outer corner, 47–54 upper outer lip left → right, 55 right outer corner,
  56–63 lower outer lip right → left;
* 64 left inner corner, 65–69 upper inner lip left → right, 70 right inner corner,
  71–75 lower inner lip right → left.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.spatial import Delaunay

from groundwork.errors import ParameterError

LAYOUT_VERSION = "hwh79-1"
N_MARKERS = 79
IMAGE_SIZE = (640, 480)  # width, height in pixels
FACE_CENTRE = (320.0, 240.0)

REGIONS = {
    "forehead": range(0, 22),
    "cheeks": range(22, 46),
    "lips": range(46, 76),
    "glasses": range(76, 79),
}
BROW_ROW = range(0, 8)
LEFT_OUTER_CORNER, RIGHT_OUTER_CORNER = 46, 55
UPPER_OUTER = range(47, 55)
LOWER_OUTER = range(56, 64)
LEFT_INNER_CORNER, RIGHT_INNER_CORNER = 64, 70
UPPER_INNER = range(65, 70)
LOWER_INNER = range(71, 76)
GLASSES = range(76, 79)

MOUTH_CENTRE_Y = 70.0  # relative to FACE_CENTRE
MOUTH_HALF_WIDTH = 32.0


@dataclass(frozen=True)
class FaceLayout:
    """Neutral marker positions and their description.

    Attributes
    ----------
    neutral : ndarray, shape (79, 2)
        Neutral positions in pixels.
    names : tuple of str
        One name per marker.
    region : ndarray of str, shape (79,)
        ``forehead``, ``cheeks``, ``lips`` or ``glasses``.
    triangles : ndarray of int, shape (n_triangles, 3)
        Mesh over the 76 skin markers (Fig. 2b); the mouth opening and the glasses are excluded.
    version : str
        :data:`LAYOUT_VERSION`, recorded by the corpora made with it.
    """

    neutral: np.ndarray
    names: tuple
    region: np.ndarray
    triangles: np.ndarray
    version: str = LAYOUT_VERSION

    def region_mask(self, name: str) -> np.ndarray:
        """Boolean mask of shape (79,) for one region name."""
        return self.region == name


def _lip_profile(x: np.ndarray, half_width: float) -> np.ndarray:
    return np.sqrt(np.clip(1.0 - (x / half_width) ** 2, 0.0, 1.0))


def _relative_positions() -> tuple[np.ndarray, list[str], list[str]]:
    pts: list[tuple[float, float]] = []
    names: list[str] = []
    regions: list[str] = []

    def add(x, y, name, region):
        pts.append((float(x), float(y)))
        names.append(name)
        regions.append(region)

    # Forehead: brow row (8), middle row (7), top row (7).
    for i, x in enumerate(np.linspace(-82, 82, 8)):
        add(x, -62 - 6 * np.cos(x / 82 * np.pi / 2) ** 2 * 0.5, f"brow_{i}", "forehead")
    for i, x in enumerate(np.linspace(-72, 72, 7)):
        add(x, -96, f"forehead_mid_{i}", "forehead")
    for i, x in enumerate(np.linspace(-60, 60, 7)):
        add(x, -128, f"forehead_top_{i}", "forehead")
    # Cheeks: a 4 × 3 grid on each side, rows from below the eyes to the jaw line.
    for side, sgn in (("L", -1), ("R", 1)):
        for r, y in enumerate((-2.0, 28.0, 58.0, 90.0)):
            for c, x in enumerate((104.0, 82.0, 60.0)):
                # The jaw narrows: the lowest row comes in a little.
                xx = x - (8.0 if r == 3 else 0.0)
                add(sgn * xx, y, f"cheek_{side}_{r}{c}", "cheeks")
    # Lips, outer contour then inner contour.
    w, cy = MOUTH_HALF_WIDTH, MOUTH_CENTRE_Y
    add(-w, cy, "lip_outer_corner_L", "lips")
    xs = -w + 2 * w * np.arange(1, 9) / 9
    for i, x in enumerate(xs):
        bow = 2.0 * np.exp(-((x / 6.0) ** 2))  # the cupid's-bow dip in the middle
        add(x, cy - 10.0 * _lip_profile(x, w) + bow, f"lip_outer_upper_{i}", "lips")
    add(w, cy, "lip_outer_corner_R", "lips")
    for i, x in enumerate(xs[::-1]):
        add(x, cy + 13.0 * _lip_profile(x, w), f"lip_outer_lower_{i}", "lips")
    wi = 25.0
    add(-wi, cy, "lip_inner_corner_L", "lips")
    xi = -wi + 2 * wi * np.arange(1, 6) / 6
    for i, x in enumerate(xi):
        add(x, cy - 1.2 * _lip_profile(x, wi), f"lip_inner_upper_{i}", "lips")
    add(wi, cy, "lip_inner_corner_R", "lips")
    for i, x in enumerate(xi[::-1]):
        add(x, cy + 1.2 * _lip_profile(x, wi), f"lip_inner_lower_{i}", "lips")
    # Glasses: left temple, bridge, right temple.
    add(-86, -34, "glasses_L", "glasses")
    add(0, -50, "glasses_bridge", "glasses")
    add(86, -34, "glasses_R", "glasses")
    return np.asarray(pts), names, regions


def _mesh(neutral: np.ndarray, region: np.ndarray) -> np.ndarray:
    skin = np.flatnonzero(region != "glasses")
    tri = Delaunay(neutral[skin]).simplices
    tri = skin[tri]
    inner = set(range(LEFT_INNER_CORNER, 76))
    keep = []
    for t in tri:
        if set(t.tolist()) <= inner:
            continue  # a triangle across the mouth opening
        p = neutral[t]
        edges = np.linalg.norm(p - np.roll(p, 1, axis=0), axis=1)
        a, b = p[1] - p[0], p[2] - p[0]
        area = 0.5 * abs(a[0] * b[1] - a[1] * b[0])
        # Slivers along the convex hull connect markers that are not neighbours on the skin.
        if area / (edges.max() ** 2) < 0.04:
            continue
        keep.append(sorted(t.tolist()))
    return np.asarray(sorted(keep), dtype=np.int64)


@lru_cache(maxsize=1)
def default_layout() -> FaceLayout:
    """The canonical layout (cached; its arrays are read-only)."""
    rel, names, regions = _relative_positions()
    assert rel.shape == (N_MARKERS, 2)
    neutral = rel + np.asarray(FACE_CENTRE)
    region = np.asarray(regions)
    tri = _mesh(neutral, region)
    for arr in (neutral, region, tri):
        arr.setflags(write=False)
    return FaceLayout(neutral=neutral, names=tuple(names), region=region, triangles=tri)


def mouth_opening(markers) -> np.ndarray:
    """The mouth opening per frame: mean y of the inner lower lip (markers 71–75) minus mean y
    of the inner upper lip (markers 65–69), pixels (y down, so an open mouth is positive).

    Parameters
    ----------
    markers : array_like, shape (n_frames, 79, 2)
        Marker positions in pixels, in any frame of reference without rotation (e.g. image
        coordinates, or aligned by :func:`face_model.alignment.align_markers`).

    Returns
    -------
    ndarray, shape (n_frames,)
        In the dtype of ``markers``' mean (float32 markers give float32).

    Raises
    ------
    ParameterError
        Markers of another shape.
    """
    m = np.asarray(markers)
    if m.ndim != 3 or m.shape[1:] != (N_MARKERS, 2):
        raise ParameterError(f"markers must have shape (n_frames, {N_MARKERS}, 2), got {m.shape}")
    lower = m[:, LOWER_INNER.start:LOWER_INNER.stop, 1].mean(1)
    upper = m[:, UPPER_INNER.start:UPPER_INNER.stop, 1].mean(1)
    return lower - upper
