"""tools/ship_default_model.py: a run's default child shipped into a folder and checked back
(``--check``, ``--check RUN_DIR``), a damaged file refused before anything is replaced, and
``--check`` failing in one line when the shipped child or its settings are not today's."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from talkingface.stages.models import find_model, shipped_default
from tests.talkingface.bad_input_ship import change_array, child_tfmap, fake_run, tool

REPO = Path(__file__).resolve().parents[2]
DEFAULT, CFG = tool().expected()  # configs/voices.yaml's model: the child the tool ships


def _hashes(root: Path) -> dict:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(Path(root).iterdir()) if p.is_file()}


@pytest.fixture(scope="module")
def shipped(tmp_path_factory):
    """A fake run (the shipped model's arrays under today's settings) shipped into a folder of
    its own: ``(tool module, run, target)``."""
    root = tmp_path_factory.mktemp("ship")
    t = tool()
    run = fake_run(root / "run")
    assert t.main([str(run), "--target", str(root / "target")]) == 0
    return t, run, root / "target"


def _one_line(capsys) -> str:
    out = capsys.readouterr().out
    lines = [ln for ln in out.splitlines() if ln.strip()]
    assert len(lines) == 1, out
    return lines[0]


def test_a_shipped_run_checks_and_reproduces(shipped, capsys):
    t, run, target = shipped
    record = json.loads((target / "provenance.json").read_text())
    assert record["child"] == DEFAULT and record["seed"] == 2002
    names = {n for n in record["files"].values() if n is not None}
    causal = CFG.mapping.recogniser == "causal"  # a causal default keeps its front end beside it
    assert names == {"gated_mlp_utterance.tfmap", "motion_units.npz"} | (
        {"gated_mlp_utterance.front.npz"} if causal else set())
    assert record["sha256"] == {n: v for n, v in _hashes(target).items() if n in names}
    assert record["settings"]["mapping.recogniser"] == CFG.mapping.recogniser
    assert record["settings_sha256"] == t.settings_hash(record["settings"])
    assert record["trained_on"]["faces"] == ["s00"]
    assert record["trained_on"]["voices"] == ["espeak:en-us+m3"]
    if causal:
        assert record["trained_on"]["front_end"]["name"].startswith("causal-front v1 sha256:")
    else:
        assert not record["trained_on"].get("front_end")
    # the run's arrays are the shipped model's, whatever its record says besides
    _, _, real = shipped_default()
    assert record["arrays_sha256"] == real["arrays_sha256"]
    capsys.readouterr()
    assert t.main(["--check", "--target", str(target)]) == 0
    assert f"the shipped default model {DEFAULT}" in capsys.readouterr().out
    assert t.main(["--check", str(run), "--target", str(target)]) == 0
    assert "reproduces the shipped model" in capsys.readouterr().out
    # the shipped folder animates: the tfmap, its front end and its own Motion Units
    tfmap, units = find_model(str(target / "gated_mlp_utterance.tfmap"))
    assert units == target / "motion_units.npz"


def test_a_damaged_array_is_refused_before_the_shipped_files_are_replaced(shipped, tmp_path,
                                                                          capsys):
    t, _, target = shipped
    run = fake_run(tmp_path / "run")
    tfmap = child_tfmap(run)
    change_array(tfmap, keep_checksum=True)
    before = _hashes(target)
    assert t.main([str(run), "--target", str(target)]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and str(tfmap) in err[0] and "checksum mismatch" in err[0]
    assert _hashes(target) == before
    assert not list(target.parent.glob(".target.*"))  # no partial folder left


def test_a_run_of_other_weights_does_not_reproduce_the_shipped_model(shipped, tmp_path,
                                                                     capsys):
    t, _, target = shipped
    run = fake_run(tmp_path / "run")
    change_array(child_tfmap(run), keep_checksum=False)  # a valid file, other weights
    capsys.readouterr()
    assert t.main(["--check", str(run), "--target", str(target)]) == 1
    line = _one_line(capsys)
    assert str(child_tfmap(run)) in line and "does not reproduce" in line


def test_check_fails_in_one_line_when_voices_yaml_names_another_child(shipped, tmp_path,
                                                                      monkeypatch, capsys):
    t, _, target = shipped
    grid = tmp_path / "voices.yaml"
    text = (REPO / "configs" / "voices.yaml").read_text()
    assert f"\nmodel: {DEFAULT}\n" in text and DEFAULT != "one-voice"
    grid.write_text(text.replace(f"\nmodel: {DEFAULT}\n", "\nmodel: one-voice\n"))
    monkeypatch.setattr(t, "VOICES_GRID", grid)
    capsys.readouterr()
    assert t.main(["--check", "--target", str(target)]) == 1
    line = _one_line(capsys)
    assert f"'{DEFAULT}'" in line and "voices.yaml's model is 'one-voice'" in line


def test_check_fails_in_one_line_when_the_papers_settings_changed(shipped, tmp_path,
                                                                  monkeypatch, capsys):
    t, _, target = shipped
    paper = tmp_path / "paper.yaml"
    text = (REPO / "configs" / "paper.yaml").read_text()
    assert "\n  hidden_max: 25\n" in text
    paper.write_text(text.replace("\n  hidden_max: 25\n", "\n  hidden_max: 30\n"))
    monkeypatch.setattr(t, "PAPER", paper)
    capsys.readouterr()
    assert t.main(["--check", "--target", str(target)]) == 1
    line = _one_line(capsys)
    assert "mapping.hidden_max=25 (now 30)" in line and "paper.yaml" in line


def test_check_fails_in_one_line_when_a_shipped_file_changed(shipped, tmp_path, capsys):
    t, run, _ = shipped
    target = tmp_path / "target"
    assert t.main([str(run), "--target", str(target)]) == 0
    units = target / "motion_units.npz"
    units.write_bytes(units.read_bytes() + b"\0")
    capsys.readouterr()
    assert t.main(["--check", "--target", str(target)]) == 1
    line = _one_line(capsys)
    assert str(units) in line and "not the file shipped" in line


def test_the_tool_ships_where_animate_looks():
    from talkingface.stages import models

    t = tool()
    assert (t.SHIPPED_DIR.resolve(), t.PROVENANCE) == (models.SHIPPED_DIR, models.PROVENANCE)
