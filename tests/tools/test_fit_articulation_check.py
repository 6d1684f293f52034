"""tools/fit_articulation.py --check: a new fit that differs from the shipped file by rounding
(another processor, another thread count: ~1e-4 in the largest parameter) passes, a fit of other
data or settings fails with one line, and the check writes nothing."""
from __future__ import annotations

import dataclasses
import hashlib
import sys
from pathlib import Path

import numpy as np
import pytest

from data_synth.articulation import read_articulation
from talkingface.stages.articulation import shipped_path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import fit_articulation as fit_tool  # noqa: E402


def _moved(model, by: float):
    """``model`` with its first target moved by ``by`` and its anticipation rate by ``by`` in log."""
    targets = model.targets.copy()
    targets[0, 0] += by
    return dataclasses.replace(model, targets=targets,
                               theta_anticipation=model.theta_anticipation * float(np.exp(by)))


@pytest.fixture
def checked(monkeypatch):
    """Run ``--check`` against the shipped file with the fit replaced by the shipped model moved
    by ``by``: returns ``(exit code, the shipped file's sha256 before, after)``."""
    shipped = read_articulation(shipped_path())

    def run(by: float, record: dict | None = None):
        monkeypatch.setattr(fit_tool, "fit_real_articulation",
                            lambda cfg: (_moved(shipped, by), dict(record or shipped.record)))
        monkeypatch.setattr(fit_tool, "held_out_table", lambda cfg, models: [])
        before = hashlib.sha256(shipped_path().read_bytes()).hexdigest()
        code = fit_tool.main(["--check"])
        return code, before, hashlib.sha256(shipped_path().read_bytes()).hexdigest()
    return run


def test_the_difference_is_the_largest_parameter_gap():
    shipped = read_articulation(shipped_path())
    assert fit_tool.difference(shipped, shipped) == 0.0
    assert fit_tool.difference(shipped, _moved(shipped, 3e-3)) == pytest.approx(3e-3, rel=1e-9)


@pytest.mark.parametrize("by", [0.0, 9.2e-5, 5e-4])
def test_a_fit_that_differs_by_rounding_passes(checked, capsys, by):
    code, before, after = checked(by)
    out = capsys.readouterr().out
    assert code == 0, out
    assert "is the fit of paper.yaml" in out
    assert before == after


@pytest.mark.parametrize("by", [2e-3, 4.1e-2])
def test_a_fit_that_moved_fails_with_one_line(checked, capsys, by):
    code, before, after = checked(by)
    out = capsys.readouterr().out.strip().splitlines()
    assert code == 1
    assert out[-1].endswith("run python tools/fit_articulation.py to make it again")
    assert f"a new fit differs by {by:.2e} (> 0.001)" in out[-1]
    assert before == after


def test_a_fit_of_other_sentences_fails_on_its_record(checked, capsys):
    shipped = read_articulation(shipped_path())
    record = dict(shipped.record)
    record["training_utterances"] = record["training_utterances"][1:]
    code, before, after = checked(0.0, record)
    out = capsys.readouterr().out.strip().splitlines()
    assert code == 1
    assert "its record's training_utterances differ from the config's" in out[-1]
    assert before == after
