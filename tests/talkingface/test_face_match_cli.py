"""``evaluate-face --speaker X`` on videos of another face (issue 42): refused in one line naming
the speaker, the first clip, the misfit and the threshold, before anything is written; the same
videos under their own name are scored. Real GRID s1 clips (tests/data/grid, CC BY 4.0) read by
the landmark worker; the model is a small one trained on the small synthetic corpus, whose
corpus sits in the run folder beside the model file (as a run's does)."""
from __future__ import annotations

import re
import shutil
from pathlib import Path

import talkingface.cli.faces as faces
from face_model.face_match import MAX_FACE_MISFIT
from mapping.animator import FaceAnimator
from talkingface.cli.main import main
from tests.mapping.small_mapping import train_small

GRID = Path(__file__).resolve().parents[1] / "data" / "grid"


def test_videos_of_another_face_named_as_a_training_speaker_are_refused(
        small_corpus, small_corpus_dir, tmp_path, monkeypatch, capsys):
    trained = train_small(small_corpus, method="linear", epochs=5)
    animator = FaceAnimator(trained.mapping, trained.units)
    shutil.copytree(small_corpus_dir, tmp_path / "run" / "corpus")
    tfmap = tmp_path / "run" / "mapping" / "m.tfmap"
    monkeypatch.setattr(faces, "load_animator", lambda model, runs_dir: (animator, tfmap))
    monkeypatch.chdir(tmp_path)
    video = tmp_path / "s1" / "video"
    video.mkdir(parents=True)
    for clip in ("bbbf8p", "lbbk4n"):
        shutil.copy(GRID / "video" / f"{clip}.mpg", video)
    speaker = small_corpus.utterances[0].speaker

    assert main(["evaluate-face", "--speaker", speaker, str(video), "--out", "res"]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines()
           if ln.strip() and "%|" not in ln]  # progress bars apart
    assert len(err) == 1, err
    m = re.fullmatch(rf"error: clips bbbf8p \(and 1 more\) scored as speaker '{speaker}' show "
                     r"another face: their neutral face misfits the speaker's by (\d+\.\d) % .*"
                     rf"at most {MAX_FACE_MISFIT:.1f} % allowed.*", err[0])
    assert m and float(m.group(1)) > MAX_FACE_MISFIT, err[0]
    assert not (tmp_path / "res").exists()

    # under their own speaker's name (the folder's, one the model never saw): scored, no LVE
    assert main(["evaluate-face", str(video), "--out", "res"]) == 0
    out = capsys.readouterr().out
    assert "2 clips, 1 speaker(s)" in out and "LVE" not in out
    assert (tmp_path / "res" / "scores.json").is_file()
