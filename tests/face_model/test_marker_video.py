"""Rendered marker video: deterministic for a seed, dots on the markers, and each difficulty
setting changing the frames as documented."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from face_model.marker_video import (
    DEFAULT_SIZE,
    FPS,
    ImageMapping,
    VideoDifficulty,
    render_marker_video,
    tracking_error_curve,
)
from groundwork.errors import ParameterError


@pytest.fixture(scope="module")
def markers(small_corpus):
    """30 frames (1 s) of a corpus utterance, head motion included."""
    return np.asarray(small_corpus["s00_smile_001"].markers[:30], dtype=np.float64)


@pytest.fixture(scope="module")
def clean(markers):
    return render_marker_video(markers, seed=11)


def test_frames_shape_mapping_and_determinism(markers, clean):
    frames, mapping = clean
    w, h = DEFAULT_SIZE
    assert frames.shape == (len(markers), h, w) and frames.dtype == np.uint8
    assert isinstance(mapping, ImageMapping) and mapping.scale == 1.0
    np.testing.assert_allclose(mapping.to_markers(mapping.to_image(markers)), markers)
    pts = mapping.to_image(markers)
    assert pts.min() > 0 and pts[..., 0].max() < w - 1 and pts[..., 1].max() < h - 1
    again, mapping2 = render_marker_video(markers, seed=11)
    assert np.array_equal(again, frames) and mapping2 == mapping
    other, _ = render_marker_video(markers, seed=12)
    assert not np.array_equal(other, frames)


def test_dots_sit_on_the_markers(markers, clean):
    """Around every marker that has no neighbour within 6 px, the brightest pixel is the one
    nearest the marker (up to one pixel), in every frame."""
    frames, mapping = clean
    pts = mapping.to_image(markers)
    d = np.linalg.norm(pts[0][:, None] - pts[0][None], axis=-1) + np.eye(79) * 99
    isolated = np.flatnonzero(d.min(1) >= 6.0)
    assert len(isolated) >= 60
    r = 3
    for k in range(len(frames)):
        for j in isolated:
            cx, cy = np.round(pts[k, j]).astype(int)
            patch = frames[k, cy - r:cy + r + 1, cx - r:cx + r + 1]
            iy, ix = np.unravel_index(np.argmax(patch), patch.shape)
            assert abs(ix - r) <= 1 and abs(iy - r) <= 1, (k, j)
    # Scale 2 puts the dots twice as far apart, on a bigger canvas.
    big, m2 = render_marker_video(markers[:2], size=(640, 640), scale=2.0, seed=11)
    p2 = m2.to_image(markers[:2])
    np.testing.assert_allclose(p2[:, 1] - p2[:, 0], 2 * (markers[:2, 1] - markers[:2, 0]))
    cx, cy = np.round(p2[0, 0]).astype(int)
    assert big[0, cy, cx] > np.median(big[0]) + 60


def test_noise_and_blur(markers, clean):
    frames, _ = clean
    noisy, _ = render_marker_video(markers, seed=11, difficulty=VideoDifficulty(noise_sd=12.0))
    diff = noisy.astype(float) - frames
    inner = diff[:, 60:260, 60:260]  # mid-grey skin: no clipping
    assert 11.0 < inner.std() < 13.0 and abs(inner.mean()) < 0.3
    blurred, _ = render_marker_video(markers, seed=11, difficulty=VideoDifficulty(blur_px=1.5))

    def sharpness(x):
        return np.mean([np.abs(cv2.Laplacian(f.astype(np.float32), cv2.CV_32F)).mean()
                        for f in x])

    assert sharpness(blurred) < 0.5 * sharpness(frames)
    np.testing.assert_allclose(blurred.astype(float).mean(), frames.astype(float).mean(), atol=1)


@pytest.mark.parametrize("profile", ["ramp", "step"])
def test_illumination_change(markers, clean, profile):
    frames, _ = clean
    lit, _ = render_marker_video(markers, seed=11, difficulty=VideoDifficulty(
        illumination_change=0.3, illumination_profile=profile))
    n = len(frames)
    ratio = lit.reshape(n, -1).astype(float).mean(1) / frames.reshape(n, -1).astype(float).mean(1)
    assert abs(ratio[0] - 1.0) < 0.005 and abs(ratio[-1] - 1.3) < 0.01
    if profile == "ramp":
        np.testing.assert_allclose(ratio, 1 + 0.3 * np.arange(n) / (n - 1), atol=0.01)
    else:
        assert np.array_equal(lit[:n // 2], frames[:n // 2])
        np.testing.assert_allclose(ratio[n // 2:], 1.3, atol=0.01)


def test_occlusion_hides_markers_only_in_its_window(markers, clean):
    frames, mapping = clean
    pts = mapping.to_image(markers)
    x0, y0 = pts[0, 46] - [15, 20]  # a box over the left half of the mouth
    box = (x0, y0, x0 + 45, y0 + 45)
    d = VideoDifficulty(occlusion=(10 / FPS, 8 / FPS, box))
    occ, _ = render_marker_video(markers, seed=11, difficulty=d)
    window = d.occluded_frames(len(frames))
    assert np.flatnonzero(window).tolist() == list(range(10, 18))
    assert np.array_equal(occ[~window], frames[~window])
    inside = (pts[..., 0] >= x0 + 1) & (pts[..., 0] < x0 + 44) & \
             (pts[..., 1] >= y0 + 1) & (pts[..., 1] < y0 + 44)
    assert inside[window].sum(1).min() >= 5
    for k in np.flatnonzero(window):
        for j in np.flatnonzero(inside[k]):  # flat occluder where the dot was
            cx, cy = np.round(pts[k, j]).astype(int)
            assert frames[k, cy, cx] > occ[k, cy, cx] + 40
            assert np.ptp(occ[k, cy - 1:cy + 2, cx - 1:cx + 2]) == 0
        outside = np.flatnonzero(~inside[k] & ((pts[k, :, 0] < x0 - 4) | (pts[k, :, 1] > y0 + 49)))
        cx, cy = np.round(pts[k, outside]).astype(int).T
        assert np.array_equal(occ[k, cy, cx], frames[k, cy, cx])  # other dots untouched


@pytest.mark.parametrize("kwargs, match", [
    ({"noise_sd": -1.0}, "noise_sd must be a finite number >= 0, got -1.0"),
    ({"blur_px": float("inf")}, "blur_px must be a finite number >= 0"),
    ({"noise_sd": "loud"}, "noise_sd must be a finite number >= 0, got 'loud'"),
    ({"illumination_change": -1.0}, "illumination_change must be a finite number > -1"),
    ({"illumination_profile": "flash"}, "illumination_profile 'flash'; allowed: ramp, step"),
    ({"occlusion": (0.5, 0.0, (0, 0, 10, 10))}, "occlusion must be None or"),
    ({"occlusion": (0.5, 0.2, (10, 0, 5, 10))}, "occlusion must be None or"),
    ({"occlusion": "hand"}, "occlusion must be None or"),
])
def test_difficulty_rejects_bad_values(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        VideoDifficulty(**kwargs)


def test_render_rejects_bad_input(markers):
    with pytest.raises(ParameterError, match=r"markers must have shape \(n_frames, 79, 2\)"):
        render_marker_video(markers[:, :40])
    bad = markers.copy()
    bad[3, 5, 0] = np.nan
    with pytest.raises(ParameterError, match="markers hold NaN"):
        render_marker_video(bad)
    with pytest.raises(ParameterError, match="do not fit a 200x200 image"):
        render_marker_video(markers, size=(200, 200))
    with pytest.raises(ParameterError, match="size must be"):
        render_marker_video(markers, size=(16, 320))
    with pytest.raises(ParameterError, match="scale must be > 0"):
        render_marker_video(markers, scale=0.0)
    with pytest.raises(ParameterError, match="difficulty must be a VideoDifficulty"):
        render_marker_video(markers, difficulty={"noise_sd": 3})


def test_error_curve_rejects_bad_input(small_corpus):
    u = small_corpus.utterances[0]
    with pytest.raises(ParameterError, match="no neutral face for speaker 's00'"):
        tracking_error_curve([u], object(), neutrals={}, noise_levels=(0.0,))
    with pytest.raises(ParameterError, match="init 'truth'; allowed: markers, corners, image"):
        tracking_error_curve([u], object(), neutrals={}, init="truth")
    with pytest.raises(ParameterError, match="at least one noise level and one utterance"):
        tracking_error_curve([], object(), neutrals={})
