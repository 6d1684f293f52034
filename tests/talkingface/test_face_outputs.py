"""Nothing lost by the real-face commands: ``evaluate-face`` replaces an earlier result only with
``--overwrite`` and then atomically, its default folder is one per source, ``corpus from-video
--keep-landmarks`` never replaces another import's files, and sources that cannot be imported
(two clips with one name, audio files) are refused before any work. The scorer is replaced by a
fast one on seeded tracks (the scoring itself: tests/analysis/test_face_eval.py)."""
from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest

import talkingface.cli.faces as faces
from analysis.face_eval import ClipTrack, score_clips
from face_model.video_import import check_keep_landmarks, check_sources, corpus_from_video, \
    keep_landmark_files
from groundwork.errors import ParameterError
from talkingface.cli.main import main

GRID = Path(__file__).resolve().parents[1] / "data" / "grid"


def _tree(folder: Path) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _error_line(capsys) -> str:
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    return lines[0]


@pytest.fixture
def fake_scoring(tmp_path, monkeypatch):
    """``evaluate-face`` with a model file under ``tmp_path/run/mapping`` and a scorer that
    gives each clip of a source seeded random openings (``calls`` counts the sources read;
    ``seed[0]`` changes the scores of the next run)."""
    tfmap = tmp_path / "run" / "mapping" / "m.tfmap"
    calls, seed = [], [0]

    def clips_from_videos(src, **_):
        calls.append(Path(src))
        return [p.stem for p in check_sources(src)], [], []

    def score_model(animator, clips, **_):
        rng = np.random.default_rng(seed[0])
        return score_clips([ClipTrack(c, "spk", rng.normal(size=60), rng.normal(size=60), 30.0)
                            for c in clips])

    monkeypatch.setattr(faces, "load_animator", lambda model, runs_dir: (None, tfmap))
    monkeypatch.setattr(faces, "clips_from_videos", clips_from_videos)
    monkeypatch.setattr(faces, "score_model", score_model)
    monkeypatch.chdir(tmp_path)
    return tfmap, calls, seed


def _grid_speaker(root: Path, speaker: str, clips=("bbbf8p", "lbbk4n")) -> Path:
    """``root/<speaker>/video`` with GRID clips (the same names for every speaker)."""
    video = root / speaker / "video"
    video.mkdir(parents=True)
    for c in clips:
        shutil.copy(GRID / "video" / f"{c}.mpg", video)
    return video


# -- evaluate-face: the default folder ------------------------------------------------------
def test_the_default_folder_is_one_per_source_and_readable(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    a, b = (tmp_path / s / "video" for s in ("s1", "s2"))
    for v in (a, b):
        v.mkdir(parents=True)
    fa, fb = (faces.default_eval_folder("run/mapping/m.tfmap", v) for v in (a, b))
    assert fa != fb and fa.parent == fb.parent == Path("run/mapping/face_eval")
    assert fa.name.startswith("s1-video-") and fb.name.startswith("s2-video-")
    assert faces.default_eval_folder("run/mapping/m.tfmap", Path("s1/video")) == fa


def test_a_second_speaker_never_replaces_the_first(fake_scoring, tmp_path, capsys):
    tfmap, calls, _ = fake_scoring
    s1, s2 = _grid_speaker(tmp_path, "s1"), _grid_speaker(tmp_path, "s2")
    assert main(["evaluate-face", str(s1)]) == 0
    first = faces.default_eval_folder(tfmap, s1)
    assert f"results: {first}/" in capsys.readouterr().out
    kept = _tree(first)
    assert sorted(kept) == ["opening_bbbf8p.png", "per_clip.csv", "scores.json"]
    assert main(["evaluate-face", str(s2)]) == 0
    second = faces.default_eval_folder(tfmap, s2)
    assert f"results: {second}/" in capsys.readouterr().out
    assert second != first and _tree(first) == kept and (second / "scores.json").is_file()
    assert len(calls) == 2


def test_the_same_source_again_needs_overwrite_and_is_refused_before_any_work(fake_scoring,
                                                                             tmp_path, capsys):
    tfmap, calls, seed = fake_scoring
    s1 = _grid_speaker(tmp_path, "s1")
    assert main(["evaluate-face", str(s1)]) == 0
    out = faces.default_eval_folder(tfmap, s1)
    before = _tree(out)
    capsys.readouterr()
    assert main(["evaluate-face", str(s1)]) == 2
    line = _error_line(capsys)
    assert str(out) in line and "--overwrite" in line and str(s1.resolve()) in line
    assert _tree(out) == before and len(calls) == 1  # no landmarks were read
    seed[0] = 1
    assert main(["evaluate-face", str(s1), "--overwrite"]) == 0
    after = _tree(out)
    assert sorted(after) == sorted(before) and after["per_clip.csv"] != before["per_clip.csv"]
    assert not list(out.parent.glob(".*"))  # no partial or replaced folder left


def test_out_over_an_earlier_evaluation_needs_overwrite(fake_scoring, tmp_path, capsys):
    _, calls, seed = fake_scoring
    s1 = _grid_speaker(tmp_path, "s1")
    assert main(["evaluate-face", str(s1), "--out", "res"]) == 0
    before = _tree(tmp_path / "res")
    assert main(["evaluate-face", str(s1), "--out", "res"]) == 2
    line = _error_line(capsys)
    assert "--out res already holds an evaluation" in line and "--overwrite" in line
    assert _tree(tmp_path / "res") == before and len(calls) == 1
    seed[0] = 2
    assert main(["evaluate-face", str(s1), "--out", "res", "--overwrite"]) == 0
    assert _tree(tmp_path / "res")["scores.json"] != before["scores.json"]


def test_a_failed_overwrite_leaves_the_earlier_result_as_it_was(fake_scoring, tmp_path,
                                                                monkeypatch):
    _, _, seed = fake_scoring
    s1 = _grid_speaker(tmp_path, "s1")
    assert main(["evaluate-face", str(s1), "--out", "res"]) == 0
    before = _tree(tmp_path / "res")

    def broken(*_a, **_k):
        raise RuntimeError("figure failed")

    monkeypatch.setattr(faces, "opening_strip_figure", broken)
    seed[0] = 3
    with pytest.raises(RuntimeError, match="figure failed"):
        main(["evaluate-face", str(s1), "--out", "res", "--overwrite"])
    assert _tree(tmp_path / "res") == before
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_a_folder_of_other_files_is_never_replaced(fake_scoring, tmp_path, capsys, overwrite):
    _, calls, _ = fake_scoring
    s1 = _grid_speaker(tmp_path, "s1")
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep me\n")
    assert main(["evaluate-face", str(s1), "--out", "mine", *overwrite]) == 2
    line = _error_line(capsys)
    assert "--out mine holds files that are not an evaluation's" in line
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep me\n" and not calls


def test_out_that_is_a_file_is_refused(fake_scoring, tmp_path, capsys):
    s1 = _grid_speaker(tmp_path, "s1")
    (tmp_path / "res.txt").write_text("x")
    assert main(["evaluate-face", str(s1), "--out", "res.txt"]) == 2
    assert "--out res.txt is a file; give a folder" in _error_line(capsys)


# -- sources that are not one video per clip name -------------------------------------------
def test_two_clips_with_one_name_are_refused_naming_both(tmp_path, capsys):
    v = tmp_path / "v"
    v.mkdir()
    shutil.copy(GRID / "video" / "bbbf8p.mpg", v / "clip.mpg")
    shutil.copy(GRID / "video" / "bbbf8p.mpg", v / "clip.mp4")
    (v / "clip.txt").write_text("bin blue by f eight please\n")
    with pytest.raises(ParameterError, match=r"v/clip\.mp4 and .*v/clip\.mpg are two clips "
                                             r"named 'clip'"):
        corpus_from_video(v, tmp_path / "out", progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v"]  # no partial folder
    assert main(["corpus", "from-video", str(v), "--out", str(tmp_path / "out")]) == 2
    assert "clip.mp4" in _error_line(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v"]


def test_an_audio_file_is_not_a_video(tmp_path, capsys):
    wav = tmp_path / "speech.wav"
    shutil.copy(GRID / "audio" / "bbaf3s.wav", wav)
    assert main(["corpus", "from-video", str(wav), "--out", str(tmp_path / "x")]) == 2
    line = _error_line(capsys)
    assert f"{wav} is audio, not a video" in line and ".mpg" in line
    assert "talkingface animate" in line and "transcript" not in line
    with pytest.raises(ParameterError, match=r"speech\.wav is audio, not a video"):
        check_sources(wav)
    with pytest.raises(ParameterError, match=r"notes\.txt is not a video \(allowed extensions"):
        (tmp_path / "notes.txt").write_text("hello")
        check_sources(tmp_path / "notes.txt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "speech.wav"]


def test_a_folder_of_audio_files_is_told_it_holds_no_videos(tmp_path, capsys):
    shutil.copytree(GRID / "audio", tmp_path / "audio")
    assert main(["corpus", "from-video", str(tmp_path / "audio"), "--out", "x"]) == 2
    line = _error_line(capsys)
    assert "no videos in this folder, only audio files (bbaf3s.wav, lwbl7s.wav, sgap1s.wav;" \
        in line
    assert "talkingface animate" in line


def test_a_workers_count_below_one_is_one_clear_line(tmp_path, capsys):
    for value in ("0", "-3", "two"):
        assert main(["corpus", "from-video", str(GRID / "video"), "--out", str(tmp_path / "x"),
                     "--workers", value]) == 2
        line = _error_line(capsys)
        assert f"--workers: {value}; allowed: a whole number, 1 or more" in line
    assert main(["evaluate-face", str(GRID / "video"), "--workers", "0"]) == 2
    assert "--workers: 0; allowed" in _error_line(capsys)
    assert not list(tmp_path.iterdir())


# -- --keep-landmarks ------------------------------------------------------------------------
def test_keep_landmarks_over_another_imports_files_is_refused_before_any_work(tmp_path,
                                                                                capsys):
    keep = tmp_path / "lm"
    keep.mkdir()
    (keep / "bbbf8p.npz").write_bytes(b"another speaker's landmarks")
    (keep / "sbbh2n.npz").write_bytes(b"and more")
    (keep / "other.npz").write_bytes(b"not this import's name")
    before = _tree(keep)
    assert main(["corpus", "from-video", str(GRID / "video"), "--out", str(tmp_path / "c"),
                 "--keep-landmarks", str(keep)]) == 2
    line = _error_line(capsys)
    assert f"--keep-landmarks {keep} already holds 2 of this import's 4 landmark files " \
           "(bbbf8p.npz, sbbh2n.npz)" in line
    assert _tree(keep) == before and sorted(p.name for p in tmp_path.iterdir()) == ["lm"]
    assert check_keep_landmarks(tmp_path / "new", check_sources(GRID / "video")) == \
        tmp_path / "new"


def test_kept_landmarks_never_replace_a_file_that_appeared_meanwhile(tmp_path):
    made = tmp_path / "made"
    made.mkdir()
    files = []
    for name in ("a", "b", "c"):
        files.append(made / f"{name}.npz")
        files[-1].write_bytes(name.encode() * 10)
    keep = tmp_path / "keep"
    keep.mkdir()
    (keep / "b.npz").write_bytes(b"someone else's")
    with pytest.raises(ParameterError, match=r"keep already holds 1 of this import's 3 "
                                             r"landmark files \(b\.npz\)"):
        keep_landmark_files(files, keep)
    assert _tree(keep) == {"b.npz": hashlib.sha256(b"someone else's").hexdigest()}
    assert all(f.is_file() for f in files)  # still where they were: the import can resume
    (keep / "b.npz").unlink()
    keep_landmark_files(files, tmp_path / "new" / "keep")
    assert sorted(_tree(tmp_path / "new" / "keep")) == ["a.npz", "b.npz", "c.npz"]
    assert (tmp_path / "new" / "keep" / "c.npz").read_bytes() == b"c" * 10
    assert not any(f.exists() for f in files)


def test_an_import_keeps_its_landmarks_beside_another_speakers(tmp_path, capsys):
    """End to end on one GRID clip: its landmark file is kept, and another speaker's files of
    other names in the folder are untouched."""
    video = _grid_speaker(tmp_path, "s1", clips=("bbbf8p",))
    (tmp_path / "s1" / "align").mkdir()
    shutil.copy(GRID / "align" / "bbbf8p.align", tmp_path / "s1" / "align")
    keep = tmp_path / "lm"
    keep.mkdir()
    (keep / "lbbk4n.npz").write_bytes(b"s2's landmarks")
    assert main(["corpus", "from-video", str(video), "--out", str(tmp_path / "c"),
                 "--keep-landmarks", str(keep), "--workers", "1"]) == 0
    assert sorted(p.name for p in keep.iterdir()) == ["bbbf8p.npz", "lbbk4n.npz"]
    assert (keep / "lbbk4n.npz").read_bytes() == b"s2's landmarks"
    with np.load(keep / "bbbf8p.npz") as d:
        assert "detector" in d.files
    assert not list(tmp_path.glob(".*"))  # no partial folder left
