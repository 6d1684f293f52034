"""tools/recogniser_bilabials.py: recall and precision of /p b m/ frames, exact on a known case."""
from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from face_model.corpus import PhoneSegment
from face_model.phones import PHONE_INDEX

TOOL = Path(__file__).resolve().parents[2] / "tools" / "recogniser_bilabials.py"


def _tool():
    spec = importlib.util.spec_from_file_location("recogniser_bilabials", TOOL)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_recall_and_precision_count_the_frames_exactly(monkeypatch):
    tool = _tool()
    sr, fps = 16000, 30
    # 10 frames: frames 0-3 labelled /b/, the rest /a/ (aa)
    item = SimpleNamespace(id="x", sr=sr, audio=np.zeros(sr * 10 // fps, np.float32),
                           phones=(PhoneSegment(0.0, 4 / fps, "b"),
                                   PhoneSegment(4 / fps, 10 / fps, "aa")))
    said = np.full(10, PHONE_INDEX["aa"])
    said[[1, 2, 7]] = PHONE_INDEX["m"]  # 2 of the 4 /b/ frames named bilabial, and 1 other
    monkeypatch.setattr(tool, "recognised", lambda rec, y, s, f: (said, {3: said}))
    monkeypatch.setattr(tool, "recogniser_name", lambda rec: rec)
    [row] = tool.bilabial_rows([item], ["r"], 3, fps)
    assert row == {"recogniser": "r", "bilabial_frames": 4, "named_bilabial": 3,
                   "recall": 0.5, "precision": 2 / 3}


def test_a_missing_run_is_one_line(capsys, tmp_path):
    assert _tool().main([str(tmp_path / "nope")]) == 2
    assert capsys.readouterr().err.strip() == f"error: {tmp_path / 'nope'}: not a run folder"
