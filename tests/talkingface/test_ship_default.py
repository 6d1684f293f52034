"""The default model shipped with the package (mapping/models/default): ``animate`` and
``stream`` use it from a folder with no run, and say so; a run's own model still wins; the
commands that score a run's model (``evaluate-face``) keep refusing without one."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from groundwork.errors import ParameterError
from talkingface.cli.main import main
from talkingface.stages import models
from talkingface.stages.models import (SHIPPED_DIR, find_model, model_label, model_run,
                                       shipped_default)

REPO = Path(__file__).resolve().parents[2]
WAV = REPO / "analysis" / "real_speech" / "arctic" / "awb_a0007.wav"  # 4 s, an unseen speaker


def test_the_shipped_files_are_the_ones_recorded_and_small():
    tfmap, units, record = shipped_default()
    child = record["child"]
    assert tfmap.parent == units.parent == SHIPPED_DIR
    import yaml
    assert child == yaml.safe_load((REPO / "configs" / "voices.yaml").read_text())["model"]
    import hashlib
    for name, digest in record["sha256"].items():
        path = SHIPPED_DIR / name
        assert hashlib.sha256(path.read_bytes()).hexdigest() == digest, name
        assert path.stat().st_size < 2_000_000, name


def test_animate_in_an_empty_folder_uses_the_shipped_default(tmp_path):
    """A fresh process in a folder with no runs/ (the package's own files only): an MP4 of the
    WAV's length, markers that move, and the model named on stdout."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    run = subprocess.run([sys.executable, "-m", "talkingface", "animate", str(WAV), "-o",
                          "face.mp4", "--markers", "m.npy"], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    child = shipped_default()[2]["child"]
    assert f"model the shipped default model {child} ({SHIPPED_DIR}" in run.stdout
    assert (tmp_path / "face.mp4").stat().st_size > 0
    markers = np.load(tmp_path / "m.npy")
    assert markers.shape[1:] == (79, 2) and np.all(np.isfinite(markers))
    assert abs(len(markers) - 30 * 4.0) < 30  # ~4 s at 30 fps
    assert np.ptp(markers[:, 46:76], axis=0).max() > 1.0  # the lips move with the speech
    assert sorted(p.name for p in tmp_path.iterdir()) == ["face.mp4", "m.npy"]  # no runs/ made


def test_stream_in_an_empty_folder_says_it_used_the_shipped_default(tmp_path, monkeypatch,
                                                                     capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["stream", str(WAV), "--fast"]) == 0
    captured = capsys.readouterr()
    assert "frames streamed" in captured.out
    assert f"model: the shipped default model {shipped_default()[2]['child']}" in captured.err


def _run_with_model(runs: Path, name: str, *, voices: bool) -> Path:
    """A run folder under ``runs`` holding a copy of the shipped model as its mapping (and, with
    ``voices``, as its voices stage's default child), with its Motion Units."""
    tfmap, units, _ = shipped_default()
    run = runs / name
    for folder in ("mapping", "units"):
        (run / folder).mkdir(parents=True)
    shutil.copyfile(units, run / "units" / "motion_units.npz")
    shutil.copyfile(tfmap, run / "mapping" / "gated_mlp_utterance.tfmap")
    (run / "mapping" / "done.json").write_text(json.dumps(
        {"models": {"utterance": "gated_mlp_utterance.tfmap"}}))
    if voices:
        child = run / "voices" / "own"
        child.mkdir(parents=True)
        for f in (tfmap, tfmap.with_name(f"{tfmap.stem}.front.npz")):
            if f.is_file():  # a default read through pocketsphinx keeps no front end file
                shutil.copyfile(f, child / f.name)
        (run / "voices" / "done.json").write_text(json.dumps(
            {"model": "own", "models": {"own": {"tfmap": f"own/{tfmap.name}"}}}))
    return run


@pytest.mark.parametrize("voices", [False, True])
def test_a_runs_own_model_wins_over_the_shipped_one(tmp_path, voices):
    run = _run_with_model(tmp_path / "runs", "mine", voices=voices)
    tfmap, units = find_model(None, tmp_path / "runs", shipped=True)
    assert SHIPPED_DIR not in tfmap.resolve().parents
    assert tfmap.parent.parent == (run / "voices" if voices else run)
    assert units == run / "units" / "motion_units.npz"
    assert model_label(tfmap) == str(tfmap)  # a run's model is named by its path, as before


def test_without_a_run_only_animate_and_stream_fall_back(tmp_path):
    tfmap, units = find_model(None, tmp_path / "runs", shipped=True)
    assert (tfmap, units) == shipped_default()[:2]
    assert model_label(tfmap).startswith("the shipped default model ")
    # evaluate-face (and every caller that does not ask for it) keeps the refusal: it writes
    # beside its model and scores a run's default
    with pytest.raises(ParameterError, match="no trained mapping under .*make replicate"):
        find_model(None, tmp_path / "runs")
    # the shipped model belongs to no run: what needs one says so
    with pytest.raises(ParameterError, match="is the shipped default model: it belongs to no run"):
        model_run(tfmap)


def test_a_missing_shipped_model_is_one_line_naming_both(tmp_path, monkeypatch):
    monkeypatch.setattr(models, "SHIPPED_DIR", tmp_path / "gone")
    with pytest.raises(ParameterError, match=r"no trained mapping under .*runs/ and no shipped "
                       r"default model \(.*gone/provenance.json not found\)"):
        find_model(None, tmp_path / "runs", shipped=True)
