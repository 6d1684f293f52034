"""The video import's pieces on known ground truth: gaps, 30 fps resampling, the audio's rate,
the landmark → marker correspondence, the rigidity measurement."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest

from face_model.landmarks import LIP_SPANS, MARKER_LANDMARKS, N_LANDMARKS, markers_from_landmarks
from face_model.layout import GLASSES, N_MARKERS, default_layout
from face_model.video_corpus import (ClipRefused, FromVideoSettings, decode_audio, fill_gaps,
                                     find_videos, longest_run, resample_track, source_frames)
from groundwork.errors import ParameterError

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tools"))
import marker_correspondence  # noqa: E402


def test_every_marker_is_a_convex_combination_of_landmarks():
    assert sorted(MARKER_LANDMARKS) == list(range(N_MARKERS))
    for k, (idx, w) in MARKER_LANDMARKS.items():
        assert len(idx) == len(w) and all(0 <= i < N_LANDMARKS for i in idx)
        assert sum(w) == pytest.approx(1.0, abs=2e-4), k
        assert min(w) >= -1e-9, k


def test_markers_follow_a_moving_face_exactly():
    rng = np.random.default_rng(0)
    face = rng.uniform(50, 300, (N_LANDMARKS, 2))
    shift = np.array([[0.0, 0.0], [3.5, -2.0]])
    frames = face[None] + shift[:, None]
    m = markers_from_landmarks(np.concatenate([frames, np.zeros((2, N_LANDMARKS, 1))], 2))
    assert m.shape == (2, N_MARKERS, 2)
    np.testing.assert_allclose(m[1] - m[0], np.broadcast_to(shift[1], (N_MARKERS, 2)), atol=1e-4)
    for k, lm in zip(GLASSES, (23, 10, 254)):  # the alignment markers sit on single landmarks
        np.testing.assert_allclose(m[0, k], face[lm])
    with pytest.raises(ParameterError, match=r"landmarks must be \(n_frames, 478, 2 or 3\)"):
        markers_from_landmarks(np.zeros((3, 468, 3)))


def test_lip_markers_lie_on_their_contour_in_the_layouts_order():
    x = default_layout().neutral[:, 0]
    for contour, markers, _ in LIP_SPANS:
        positions = []
        for k in markers:
            idx, w = MARKER_LANDMARKS[k]
            assert set(idx) <= set(contour)
            positions.append(contour.index(idx[0]) + w[1])
        # a marker further right in the layout sits further along the contour (left → right)
        assert np.argsort(positions).tolist() == np.argsort(x[list(markers)]).tolist()


def test_gaps_are_filled_linearly_and_held_at_the_ends():
    v = np.arange(10, dtype=float)[:, None] * 2.0
    found = np.ones(10, bool)
    found[[0, 1, 4, 5, 9]] = False
    out = fill_gaps(np.where(found[:, None], v, np.nan), found)
    np.testing.assert_allclose(out[2:9, 0], v[2:9, 0])  # interior: exact for a linear track
    assert out[0, 0] == out[1, 0] == v[2, 0] and out[9, 0] == v[8, 0]
    assert longest_run(~found) == (0, 2) and longest_run(np.zeros(3, bool)) == (0, 0)


def test_resampling_25_to_30_fps_recovers_a_linear_track_and_a_slow_sine():
    t25 = np.arange(75) / 25
    linear = np.stack([3 * t25 + 1, -2 * t25], axis=1)
    out = resample_track(linear, t25, 89)
    t30 = np.arange(89) / 30
    np.testing.assert_allclose(out, np.stack([3 * t30 + 1, -2 * t30], axis=1), atol=1e-12)
    sine = np.sin(2 * np.pi * 1.5 * t25)
    err = resample_track(sine, t25, 89) - np.sin(2 * np.pi * 1.5 * t30)
    assert np.max(np.abs(err)) < 0.02  # linear interpolation of a 1.5 Hz movement at 25 fps
    before, after = source_frames(t25, 90)
    assert np.all(t25[before] <= t30.max() + 1 / 30) and np.all(before <= after)
    with pytest.raises(ParameterError, match="frame times must be increasing"):
        resample_track(linear, t25[::-1], 10)


def _make_video(path: Path, *, audio: bool = True, seconds: float = 1.0, freq: float = 440.0):
    cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-y", "-f", "lavfi", "-i",
           f"color=c=gray:s=160x120:d={seconds}:r=25"]
    if audio:
        cmd += ["-f", "lavfi", "-i", f"sine=frequency={freq}:duration={seconds}:sample_rate=44100",
                "-c:a", "mp2", "-shortest"]
    subprocess.run([*cmd, "-c:v", "mpeg1video", str(path)], check=True)
    return path


def test_audio_is_decoded_and_resampled_to_the_corpus_rate(tmp_path):
    video = _make_video(tmp_path / "tone.mpg", seconds=1.0, freq=440.0)
    y = decode_audio(video, 22050, tmp_path)
    assert abs(len(y) / 22050 - 1.0) < 0.05
    spectrum = np.abs(np.fft.rfft(y * np.hanning(len(y))))
    peak = np.fft.rfftfreq(len(y), 1 / 22050)[np.argmax(spectrum)]
    assert abs(peak - 440.0) < 3.0
    assert not list(tmp_path.glob("*.wav"))  # the scratch file is gone


def test_a_video_without_audio_is_refused(tmp_path):
    video = _make_video(tmp_path / "silent.mpg", audio=False)
    with pytest.raises(ClipRefused, match="silent.mpg: no audio could be decoded"):
        decode_audio(video, 22050, tmp_path)


def test_settings_and_sources_are_checked(tmp_path):
    with pytest.raises(ParameterError, match="sample rate 16000 Hz gives no integer hop"):
        FromVideoSettings(sample_rate=16000).check()
    with pytest.raises(ParameterError, match="no videos in this folder"):
        find_videos(tmp_path)
    with pytest.raises(ParameterError, match="no such file or folder"):
        find_videos(tmp_path / "nothing")


def test_the_rigidity_measure_finds_the_rigid_points():
    rng = np.random.default_rng(1)
    base = rng.uniform(0, 100, (40, 2))
    frames = []
    for _ in range(60):
        x = base + rng.normal(0, 0.05, base.shape)
        x[20:] += rng.normal(0, 2.0, (20, 2))  # half the points move on their own
        a = rng.uniform(-0.1, 0.1)
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) * rng.uniform(0.9, 1.1)
        frames.append(x @ R.T + rng.uniform(-5, 5, 2))
    _, res = marker_correspondence.rigidity(np.stack(frames), n_rigid=15)
    assert set(np.argsort(res)[:20]) == set(range(20))
