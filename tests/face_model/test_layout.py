"""The 79-marker layout of the paper's Fig. 2: counts, regions, lip order and the skin mesh."""
from __future__ import annotations

import re
from collections import Counter

import numpy as np
import pytest

from face_model import layout
from face_model.layout import (
    GLASSES,
    IMAGE_SIZE,
    LEFT_INNER_CORNER,
    LEFT_OUTER_CORNER,
    LOWER_INNER,
    LOWER_OUTER,
    N_MARKERS,
    REGIONS,
    RIGHT_INNER_CORNER,
    RIGHT_OUTER_CORNER,
    UPPER_INNER,
    UPPER_OUTER,
    default_layout,
    mouth_opening,
)
from groundwork.errors import ParameterError

MOUTH_OPENING = ([LEFT_INNER_CORNER, *UPPER_INNER, RIGHT_INNER_CORNER, *LOWER_INNER])


def _inside_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even-odd rule: which ``points`` (n, 2) lie strictly inside ``polygon`` (k, 2)."""
    x, y = points[:, 0][:, None], points[:, 1][:, None]
    x0, y0 = polygon[:, 0][None], polygon[:, 1][None]
    x1, y1 = np.roll(polygon[:, 0], -1)[None], np.roll(polygon[:, 1], -1)[None]
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return (crosses & (x < x_at)).sum(1) % 2 == 1


def test_79_markers_with_unique_names_inside_the_image():
    lay = default_layout()
    assert N_MARKERS == 79
    assert lay.neutral.shape == (79, 2)
    assert len(lay.names) == 79 and len(set(lay.names)) == 79
    w, h = IMAGE_SIZE
    assert np.all((lay.neutral >= 0) & (lay.neutral < [w, h]))


def test_region_counts_are_22_24_30_3_in_index_order():
    lay = default_layout()
    assert Counter(lay.region.tolist()) == {"forehead": 22, "cheeks": 24, "lips": 30, "glasses": 3}
    for name, idx in REGIONS.items():
        assert np.array_equal(np.flatnonzero(lay.region_mask(name)), np.arange(idx.start, idx.stop))
    assert list(GLASSES) == [76, 77, 78]


def test_regions_are_stacked_top_to_bottom():
    lay = default_layout()
    y = {name: lay.neutral[lay.region_mask(name), 1] for name in REGIONS}
    # The lips are below every forehead marker, the glasses between brows and mouth.
    assert y["forehead"].max() < y["glasses"].min()
    assert y["glasses"].max() < y["lips"].min()


def test_lip_marker_order_follows_the_documented_contours():
    p = default_layout().neutral
    assert p[LEFT_OUTER_CORNER, 0] < p[list(UPPER_OUTER), 0].min()
    assert p[RIGHT_OUTER_CORNER, 0] > p[list(UPPER_OUTER), 0].max()
    assert np.all(np.diff(p[list(UPPER_OUTER), 0]) > 0)  # left → right
    assert np.all(np.diff(p[list(LOWER_OUTER), 0]) < 0)  # right → left
    assert np.all(np.diff(p[list(UPPER_INNER), 0]) > 0)
    assert np.all(np.diff(p[list(LOWER_INNER), 0]) < 0)
    # Upper lip above (smaller y) the lower lip at the same x; inner contour inside the outer one.
    assert np.all(p[list(UPPER_OUTER), 1] < p[list(LOWER_OUTER)[::-1], 1])
    assert np.all(p[list(UPPER_INNER), 1] < p[list(LOWER_INNER)[::-1], 1])
    assert p[LEFT_OUTER_CORNER, 0] < p[LEFT_INNER_CORNER, 0] < p[RIGHT_INNER_CORNER, 0] \
        < p[RIGHT_OUTER_CORNER, 0]
    # Left/right symmetry of the lips about the face centre.
    cx = layout.FACE_CENTRE[0]
    lips = p[list(REGIONS["lips"])]
    mirrored = np.c_[2 * cx - lips[:, 0], lips[:, 1]]
    dist = np.linalg.norm(mirrored[:, None] - lips[None], axis=2).min(1)
    assert dist.max() < 1e-9


def test_mesh_triangles_are_valid_and_cover_every_skin_marker():
    lay = default_layout()
    tri = lay.triangles
    assert tri.ndim == 2 and tri.shape[1] == 3 and len(tri) > 0
    assert np.issubdtype(tri.dtype, np.integer)
    assert tri.min() >= 0 and tri.max() < N_MARKERS
    assert np.all(np.diff(np.sort(tri, axis=1), axis=1) > 0)  # three distinct corners
    assert len({tuple(sorted(t)) for t in tri.tolist()}) == len(tri)  # no duplicates
    p = lay.neutral[tri]
    u, v = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    area = 0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
    assert area.min() > 1.0  # pixels²: no degenerate slivers
    assert set(tri.ravel().tolist()) == set(range(76))  # every skin marker is in the mesh
    # A planar mesh: every edge borders one (boundary) or two (interior) triangles.
    edges = Counter(tuple(sorted(e)) for t in tri.tolist()
                    for e in ((t[0], t[1]), (t[1], t[2]), (t[0], t[2])))
    assert set(edges.values()) <= {1, 2}


def test_mesh_excludes_the_glasses():
    tri = default_layout().triangles
    assert not np.isin(tri, list(GLASSES)).any()


def test_no_triangle_spans_the_mouth_opening():
    lay = default_layout()
    tri = lay.triangles
    inner = set(MOUTH_OPENING)
    assert not any(set(t) <= inner for t in tri.tolist())
    upper = set(UPPER_INNER) | set(UPPER_OUTER)
    lower = set(LOWER_INNER) | set(LOWER_OUTER)
    assert not any(set(t) & upper and set(t) & lower for t in tri.tolist())
    opening = lay.neutral[MOUTH_OPENING]
    centroids = lay.neutral[tri].mean(1)
    assert not _inside_polygon(centroids, opening).any()
    # The helper itself sees the mouth centre as inside the opening.
    assert _inside_polygon(np.array([[layout.FACE_CENTRE[0],
                                      layout.FACE_CENTRE[1] + layout.MOUTH_CENTRE_Y]]), opening)[0]


def test_layout_is_deterministic_and_read_only():
    first = default_layout()
    default_layout.cache_clear()
    second = default_layout()
    assert second is not first
    assert np.array_equal(first.neutral, second.neutral)
    assert np.array_equal(first.triangles, second.triangles)
    assert np.array_equal(first.region, second.region)
    assert first.names == second.names and first.version == second.version == layout.LAYOUT_VERSION
    with pytest.raises(ValueError, match="read-only"):
        second.neutral[0, 0] = 0.0
    with pytest.raises(ValueError, match="read-only"):
        second.triangles[0, 0] = 0


def test_mouth_opening_is_the_inner_lip_gap_in_pixels(rng):
    neutral = default_layout().neutral
    # The layout's inner lips are 1.2 px · sqrt(1 − (x/25)²) above and below the mouth centre
    # line at x = −25 + 50 k/6, k = 1…5, so the neutral opening is 2.4 px times their mean.
    x = -25.0 + 50.0 * np.arange(1, 6) / 6
    opening = mouth_opening(neutral[None])
    assert opening.shape == (1,)
    assert opening[0] == pytest.approx(2.4 * np.sqrt(1.0 - (x / 25.0) ** 2).mean(), abs=1e-12)
    frames = neutral + rng.normal(0.0, 2.0, (20, N_MARKERS, 2))
    base = mouth_opening(frames)
    assert base.shape == (20,)
    # Lowering the inner lower lip by 7 px opens the mouth by 7 px; x and head shifts do not.
    lowered = frames.copy()
    lowered[5, list(LOWER_INNER), 1] += 7.0
    lowered[:, :, 0] += 30.0
    np.testing.assert_allclose(mouth_opening(lowered) - base, np.eye(20)[5] * 7.0, atol=1e-9)
    np.testing.assert_allclose(mouth_opening(frames + [13.0, -4.0]), base, atol=1e-9)
    # Bit for bit the expression the call sites wrote by hand, in the markers' own precision.
    for dtype in (np.float64, np.float32):
        m = frames.astype(dtype)
        by_hand = m[:, 71:76, 1].mean(1) - m[:, 65:70, 1].mean(1)
        got = mouth_opening(m)
        assert got.dtype == by_hand.dtype and np.array_equal(got, by_hand)


@pytest.mark.parametrize("shape", [(79, 2), (4, 78, 2), (4, 79, 3), (4, 79)])
def test_mouth_opening_refuses_other_shapes(shape):
    with pytest.raises(ParameterError, match=re.escape(
            f"markers must have shape (n_frames, 79, 2), got {shape}")):
        mouth_opening(np.zeros(shape))
