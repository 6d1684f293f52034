"""tools/front_end_losses.py: per viseme class, per speaker and per look-ahead figures recovered
from frames whose hits are known, and a folder that is not a run refused in one line."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from analysis.speech_recogniser import LOOKAHEAD_FRAMES
from face_model.phones import VISEMES

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import front_end_losses as tool  # noqa: E402

M, A, N = VISEMES.index("m"), VISEMES.index("a"), VISEMES.index("neutral")


def _heard():
    # 10 frames: 4 of m, 4 of a, 2 neutral; speaker x the first 6, y the last 4
    true = np.array([M, M, M, M, A, A, A, A, N, N])
    said3 = np.array([M, M, A, A, A, A, A, N, N, N])  # m 2/4, a 3/4, neutral 2/2
    said = {k: (said3 if k == 3 else true.copy()) for k in LOOKAHEAD_FRAMES}
    said[0] = np.full(10, N)  # no look-ahead: all neutral, 2/10 right
    return {"pocketsphinx": {"true": true, "speaker": np.array(["x"] * 6 + ["y"] * 4, object),
                             "said": said}}


def test_the_tables_recover_known_hits():
    out = tool.losses(_heard(), 3)
    c = out["by_class"]["pocketsphinx-5.1.1 allphone"]
    assert c["m"] == {"frames": 4, "recall": 0.5}
    assert c["a"] == {"frames": 4, "recall": 0.75}
    assert c["neutral"]["recall"] == 1.0 and c["f"] == {"frames": 0, "recall": None}
    s = out["by_speaker"]["pocketsphinx-5.1.1 allphone"]
    assert s == {"x": pytest.approx(4 / 6), "y": pytest.approx(3 / 4)}
    la = out["by_lookahead"]["pocketsphinx-5.1.1 allphone"]
    assert la[0] == pytest.approx(0.2) and la[3] == pytest.approx(0.7) and la[6] == 1.0
    text = tool.report(out, 2, "made-up")
    assert "a 4, o 0, f 0, u 0, m 4, neutral 2" in text and "look-ahead 3 frames (100 ms)" in text


def test_a_folder_that_is_not_a_run_is_one_line(tmp_path, capsys):
    assert tool.main([str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {tmp_path / 'nope'}: not a run folder"]
