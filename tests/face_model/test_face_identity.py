"""Whose face, which way up, and how long: a clip showing two faces, an upside-down face, and a
clip cut short are refused with the reason, on known geometry and on real GRID clips (tests/data/
grid, CC BY 4.0) changed with FFmpeg; a clip as recorded and an older landmark file still pass."""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest

from face_model.landmark_worker import _roll
from face_model.landmarks import Landmarks, extract_landmarks
from face_model.transcripts import Transcript, read_transcript
from face_model.video_corpus import (ClipData, ClipRefused, FromVideoSettings, check_face,
                                     check_length, clip_data, face_orientation)
from face_model.video_import import corpus_from_video
from groundwork.errors import CorpusError, ParameterError

GRID = Path(__file__).resolve().parents[2] / "tests" / "data" / "grid"
SETTINGS = FromVideoSettings()

# MediaPipe's detector keypoints of an upright face, pixels: right eye, left eye, nose tip,
# mouth centre, right ear, left ear (a GRID s1 frame, bbbf8p)
UPRIGHT = np.array([(135, 152), (183, 152), (165, 183), (162, 207), (99, 162), (201, 162)],
                   np.float64)


def _turn(points: np.ndarray, degrees: float) -> np.ndarray:
    """``points`` turned clockwise on screen (image y down) by ``degrees`` about their mean."""
    a = np.radians(degrees)
    c = points.mean(axis=0)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return (points - c) @ rot.T + c


def _landmarks(n: int = 50, *, n_faces=None, roll=None, found=None) -> Landmarks:
    found = np.ones(n, bool) if found is None else found
    return Landmarks(np.zeros((n, 478, 3), np.float32), found, np.full(n, 0.9),
                     np.arange(n) / 25.0, (360, 288), "test", n_faces, roll)


@pytest.mark.parametrize("degrees", [0.0, 12.0, -30.0, 90.0, -135.0, 180.0])
def test_the_roll_of_turned_keypoints_is_the_turn(degrees):
    measured = _roll(_turn(UPRIGHT, degrees))
    assert abs((measured - degrees + 180) % 360 - 180) < 3.0  # the upright face's own tilt


def test_an_upside_down_face_labelled_on_the_turned_frame_is_at_180_degrees():
    # vflip: the detector, on the frame turned by 180°, sees an upright mirrored face and names
    # its eyes by their places there; taken back, the eye line and eyes-to-mouth agree on 180°
    h = 288
    flipped = UPRIGHT * (1, -1) + (0, h)  # vflip of the recorded face
    turned = (360, h) - flipped  # the frame turned by 180°: an upright, mirrored face
    labelled = turned[[1, 0, 2, 3, 5, 4]]  # the detector names the eyes by image side
    assert abs(abs(_roll((360, h) - labelled)) - 180) < 3.0


def test_two_faces_and_a_turned_face_are_refused_with_counts_and_bounds():
    n = 50
    many = np.ones(n, int)
    many[:6] = 2  # 12 % of frames
    with pytest.raises(ClipRefused, match=r"v\.mpg: 6 of 50 frames show more than one face "
                                          r"\(12 %\); allowed: .* at most 10 % .*crop the video"):
        check_face(Path("v.mpg"), _landmarks(n, n_faces=many), SETTINGS)
    many[5] = 1  # 10 %: allowed
    check_face(Path("v.mpg"), _landmarks(n, n_faces=many), SETTINGS)
    roll = np.full(n, 176.0)
    roll[:30] = -178.0  # both sides of upside down; the median of |roll| is 178°
    with pytest.raises(ClipRefused, match=r"v\.mpg: the face is turned 178° from upright .*"
                                          r"allowed: at most 30°"):
        check_face(Path("v.mpg"), _landmarks(n, roll=roll), SETTINGS)
    tilted = np.full(n, -25.0)
    tilted[:10] = np.nan  # frames without a detection do not count
    check_face(Path("v.mpg"), _landmarks(n, roll=tilted), SETTINGS)
    assert face_orientation(_landmarks(n, roll=tilted)) == (0.0, 25.0)


def test_an_older_landmark_file_without_counts_or_roll_is_read_as_unknown(tmp_path):
    n = 10
    old = tmp_path / "old.npz"
    np.savez(old, landmarks=np.zeros((n, 478, 3), np.float32), found=np.ones(n, bool),
             confidence=np.full(n, 0.9, np.float32), time_s=np.arange(n) / 25.0,
             size=np.array([360, 288]), fps=np.float64(25), detector=np.str_("older"))
    lm = Landmarks.load(old)
    assert lm.n_faces is None and lm.roll_deg is None
    assert np.isnan(face_orientation(lm)[1])
    check_face(Path("old.mpg"), lm, SETTINGS)
    bad = tmp_path / "bad.npz"
    with np.load(old) as d:
        np.savez(bad, **d, n_faces=np.ones(n + 1, np.int16), roll_deg=np.zeros(n, np.float32))
    with pytest.raises(ClipRefused, match=r"v\.mpg: its landmark file .*bad\.npz is unreadable "
                                          r"\(n_faces has shape \(11,\); allowed: \(10,\)"):
        clip_data(Path("v.mpg"), bad, SETTINGS, tmp_path)


def test_the_bounds_are_checked():
    with pytest.raises(ParameterError, match="max_roll_deg 180; allowed: 0 < degrees < 180"):
        FromVideoSettings(max_roll_deg=180).check()
    with pytest.raises(ParameterError, match="max_multi_face_fraction 1.5; allowed"):
        FromVideoSettings(max_multi_face_fraction=1.5).check()


def test_a_clip_shorter_than_its_transcripts_times_is_called_truncated():
    clip = ClipData(Path("cut.mpg"), np.zeros(100), 22050, np.zeros((41, 79, 2), np.float32),
                    np.ones(41), np.zeros(41, bool), 1.48, 37, 1.38)
    long = Transcript("bin blue", "cut.align", (), 2.98)
    with pytest.raises(ClipRefused, match=r"cut\.mpg: the video is truncated .* picture lasts "
                                          r"1\.48 s \(37 frames\) and its audio 1\.38 s, but "
                                          r"cut\.align runs to 2\.98 s"):
        check_length(clip, long)
    check_length(clip, Transcript("bin blue", "cut.align", (), 41 / 30 + 0.1))  # tolerance
    check_length(clip, Transcript("bin blue", "cut.txt"))  # no times: nothing to compare


# -- real clips through the landmark worker --------------------------------------------------
def _ffmpeg(args: list, out: Path) -> Path:
    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", *args, "-t", "1",
                    "-c:v", "mpeg1video", "-q:v", "4", "-c:a", "mp2", str(out)], check=True)
    return out


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    """Landmarks of a GRID clip as recorded, side by side with another, and upside down (1 s)."""
    tmp = tmp_path_factory.mktemp("faces")
    a, b = GRID / "video" / "bbbf8p.mpg", GRID / "video" / "lbbk4n.mpg"
    clips = {"one": _ffmpeg(["-i", str(a)], tmp / "one.mpg"),
             "two": _ffmpeg(["-i", str(a), "-i", str(b), "-filter_complex",
                             "[0:v][1:v]hstack=inputs=2[v]", "-map", "[v]", "-map", "0:a"],
                            tmp / "two.mpg"),
             "flip": _ffmpeg(["-i", str(a), "-vf", "vflip"], tmp / "flip.mpg")}
    jobs = [(v, tmp / f"{k}.npz") for k, v in clips.items()]
    replies = extract_landmarks(jobs, workers=2)
    assert all("error" not in r for r in replies.values())
    return {k: (clips[k], Landmarks.load(tmp / f"{k}.npz")) for k in clips}


def test_a_recorded_clip_has_one_upright_face_and_passes(real):
    video, lm = real["one"]
    assert np.all(lm.n_faces == 1) and lm.found.all()
    share, roll = face_orientation(lm)
    assert share == 0.0 and roll < 10.0
    check_face(video, lm, SETTINGS)


def test_two_real_faces_side_by_side_are_counted_and_refused(real):
    video, lm = real["two"]
    assert lm.found.all() and np.all(lm.n_faces == 2)  # the mesh follows one, both counted
    with pytest.raises(ClipRefused, match=rf"{video.name}: 25 of 25 frames show more than one"):
        check_face(video, lm, SETTINGS)


def test_a_real_upside_down_face_is_measured_and_refused(real):
    video, lm = real["flip"]
    # the mesh fits an upright face to it: its own eye line says nothing is wrong
    eyes = lm.points[:, 263, :2] - lm.points[:, 33, :2]
    assert np.all(np.abs(np.degrees(np.arctan2(eyes[:, 1], eyes[:, 0]))) < 20)
    share, roll = face_orientation(lm)
    assert share == 0.0 and roll > 150.0
    with pytest.raises(ClipRefused, match=rf"{video.name}: the face is turned 1[5-8]\d° from"):
        check_face(video, lm, SETTINGS)


def test_a_real_mpg_cut_to_half_its_bytes_is_called_truncated(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    whole = (GRID / "video" / "bbbf8p.mpg").read_bytes()
    (src / "bbbf8p.mpg").write_bytes(whole[:len(whole) // 2])
    shutil.copy(GRID / "align" / "bbbf8p.align", src)
    end = read_transcript(src / "bbbf8p.align").end_s
    with pytest.raises(CorpusError, match=rf"bbbf8p\.mpg: the video is truncated .* runs to "
                                          rf"{end:.2f} s"):
        corpus_from_video(src, tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()
