"""The stimulus set built from a trained mapping: every stimulus the design plays, videos in
sync with their sentence's calm audio, checksums that catch a changed file, and a manifest a
researcher can point at their own recordings."""
import csv
import shutil
import subprocess

import numpy as np
import pytest

from groundwork.audio import read_wav, write_wav
from groundwork.errors import ParameterError
from groundwork.movie import write_mp4
from study.design import AUDIO, EXPRESSIONS, required_stimuli
from study.stimuli import COLUMNS, MANIFEST, load_manifest, read_video_frames, write_silent_mp4
from talkingface.cli.main import main
from tests.talkingface.bad_input_cases import RUN


@pytest.fixture(scope="session")
def stimuli(small_run_dir, shared_build):
    """The stimuli of the small run with a trained mapping (``small_run_dir``, tests/conftest.py)
    made again by ``talkingface study stimuli`` in a copy of the run, once per test run; the
    tests only read them (or copy them first)."""
    def build(root):
        shutil.copytree(small_run_dir / "runs", root / "runs")
        shutil.rmtree(root / "runs" / "R" / "stimuli")  # the stage runs again; the rest is reused
        with pytest.MonkeyPatch.context() as mp:
            mp.chdir(root)
            assert main(["study", "stimuli", "--name", "R", *RUN]) == 0

    return shared_build("stimuli_run", build) / "runs" / "R" / "stimuli"


def _rows(stim):
    with open(stim / MANIFEST, newline="") as f:
        return list(csv.DictReader(f))


def _copy(stim, tmp_path):
    dst = tmp_path / "stimuli"
    shutil.copytree(stim, dst)
    return dst


def _rewrite(stim, rows):
    with open(stim / MANIFEST, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)


def test_every_stimulus_of_the_design_in_sync_with_its_audio(stimuli):
    s = load_manifest(stimuli)
    assert sorted(s) == sorted(required_stimuli())
    for a in AUDIO:
        wavs = {s[f"{f}-{e}-{a}"].wav for f in ("synthetic", "real") for e in EXPRESSIONS}
        assert wavs == {s[f"audio-{a}"].wav}  # one calm reading per sentence, for every face
        y, sr = read_wav(s[f"audio-{a}"].wav)
        for f in ("synthetic", "real"):
            for e in EXPRESSIONS:
                st = s[f"{f}-{e}-{a}"]
                frames, fps = read_video_frames(st.video)
                assert fps == 30 and len(frames) == st.n_frames
                assert abs(len(y) / sr * 30 - st.n_frames) <= 1  # frame k at k/30 s
                assert np.load(st.markers).shape == (st.n_frames, 79, 2)
    # the expressions differ where they should: real smile vs neutral, synthetic smile vs neutral
    for f in ("real", "synthetic"):
        smile = np.load(s[f"{f}-smile-normal"].markers)
        neutral = np.load(s[f"{f}-neutral-normal"].markers)
        corners = smile[:, [46, 55]].mean(1)[:, 1] - neutral[:, [46, 55]].mean(1)[:, 1]
        assert corners[len(corners) // 2] < 0  # the mouth corners rise (image y points down)


def test_a_changed_file_is_caught_and_a_blank_checksum_is_filled_in(stimuli, tmp_path):
    stim = _copy(stimuli, tmp_path)
    with open(stim / "video" / "real-smile-good.mp4", "ab") as f:
        f.write(b"\0")
    with pytest.raises(ParameterError, match=r"line \d+: .*real-smile-good\.mp4 does not match "
                                             "its checksum"):
        load_manifest(stim)
    rows = _rows(stim)
    for r in rows:
        if r["stimulus_id"] == "real-smile-good":
            r["sha256_video"] = ""
    _rewrite(stim, rows)
    assert len(load_manifest(stim)["real-smile-good"].sha256["video"]) == 64


def test_a_researchers_own_real_face_recording(stimuli, tmp_path):
    """Point a real-face row at another video and WAV (absolute paths), clear the checksums."""
    stim = _copy(stimuli, tmp_path)
    own = tmp_path / "lab"
    own.mkdir()
    shutil.copy(stim / "video" / "real-sad-bad.mp4", own / "my_sad_face.mp4")
    shutil.copy(stim / "audio" / "audio-bad.wav", own / "my_bad.wav")
    rows = _rows(stim)
    for r in rows:
        if r["stimulus_id"] == "real-sad-bad":
            r.update(video=str(own / "my_sad_face.mp4"), wav=str(own / "my_bad.wav"),
                     markers="", sha256_video="", sha256_wav="", sha256_markers="")
    _rewrite(stim, rows)
    s = load_manifest(stim)["real-sad-bad"]
    assert s.video == own / "my_sad_face.mp4" and s.markers is None


@pytest.mark.parametrize("edit, message", [
    (lambda rows: rows[1:], r"the design needs stimuli \['audio-normal'\]"),
    (lambda rows: rows + rows[:1], r"stimulus 'audio-normal' listed twice"),
    (lambda rows: [dict(r, video="video/nowhere.mp4") if r["kind"] == "video" else r
                   for r in rows], r"video file .*nowhere\.mp4 not found"),
    (lambda rows: [dict(r, audio="loud") for r in rows], r"'loud' not in the design"),
])
def test_bad_manifests_name_the_line_and_the_problem(stimuli, tmp_path, edit, message):
    stim = _copy(stimuli, tmp_path)
    _rewrite(stim, edit(_rows(stim)))
    with pytest.raises(ParameterError, match=message):
        load_manifest(stim)


def test_stimuli_are_never_overwritten(stimuli):
    from study.stimuli import build_stimuli

    with pytest.raises(ParameterError, match="stimuli are never overwritten"):
        build_stimuli(stimuli, animator=None, synth_cfg=None, seed=0)


def test_silent_stimulus_videos_and_videos_with_sound(tmp_path):
    """study.stimuli writes silent H.264 videos through groundwork.movie.write_mp4, which muxes
    a sound file as AAC when given one; frame k is at k/fps s either way."""
    import imageio_ffmpeg  # heavy and optional: imported where it is used

    rng = np.random.default_rng(3)
    frames = [rng.integers(0, 256, (64, 80, 3), dtype=np.uint8) for _ in range(12)]
    wav = tmp_path / "tone.wav"
    write_wav(wav, 0.1 * np.sin(np.arange(6400) / 5.0), 16000)
    silent = write_silent_mp4(tmp_path / "a" / "silent.mp4", iter(frames), (80, 64))
    voiced = write_mp4(tmp_path / "voiced.mp4", frames, len(frames), (80, 64), fps=30,
                       audio_path=wav, progress=False)
    for path in (silent, voiced):
        got, fps = read_video_frames(path)
        assert fps == 30 and len(got) == len(frames)
    probe = lambda p: subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-i", str(p)],  # noqa: E731
                                     capture_output=True, text=True).stderr
    assert "Video: h264" in probe(silent) and "Audio:" not in probe(silent)
    assert "Audio: aac" in probe(voiced)
