"""The FSDD part of the real-speech set (issue 37): its shipped files are what the tool makes, its
labels put espeak-ng's phones of the digit inside the word span the energy rule finds, a changed
copy is caught by its checksum, and the parts follow the stated speaker rule."""
from __future__ import annotations

import hashlib
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from analysis.speech_set import FSDD_WORDS, SET_DIR, read_labels, read_manifest
from groundwork.audio import read_wav
from groundwork.errors import ParameterError

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import fsdd_speech_labels as tool  # noqa: E402


@pytest.fixture(scope="module")
def built():
    return tool.build(progress=False)  # from the shipped copies: no download needed


@pytest.fixture(scope="module")
def digits():
    return tool.word_phones(tool.DIGITS)


def test_the_shipped_fsdd_files_are_what_the_tool_makes(built):
    assert tool.differences(files=built) == []
    assert sum(k.endswith(".wav") for k in built) == 300 == len(tool.subset_names())


def test_the_check_passes_and_a_changed_file_is_named(built, monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(tool, "build", lambda *a, **k: built)
    assert tool.main(["--check", "--source", str(tmp_path)]) == 0
    name = tool.subset_names()[7]
    changed = dict(built)
    changed[f"fsdd/{name}.csv"] = built[f"fsdd/{name}.csv"].replace(b",", b", ", 1)
    monkeypatch.setattr(tool, "build", lambda *a, **k: changed)
    assert tool.main(["--check", "--source", str(tmp_path)]) == 1
    assert f"fsdd/{name}.csv: differs from what the tool makes" in capsys.readouterr().err


def test_the_labeller_on_one_shipped_file_reproduces_its_labels(digits):
    name = "6_lucas_1"  # "six" with silence at both ends
    y, sr = read_wav(SET_DIR / "fsdd" / f"{name}.wav")
    segs = tool.file_labels(y, sr, digits["six"], source=name)
    shipped = read_labels(SET_DIR / "fsdd" / f"{name}.csv", len(y) / sr)
    assert tuple(segs) == shipped
    inside = [s.phone for s in shipped if s.phone != "sil"]
    assert inside == [p for p, _ in digits["six"]] == ["s", "ih", "k", "s"]
    start, end = tool.word_span(y, sr)
    assert shipped[0].phone == "sil" and shipped[0].end_s == pytest.approx(start, abs=1e-4)
    assert shipped[-1].phone == "sil" and shipped[-1].start_s == pytest.approx(end, abs=1e-4)


def test_the_word_span_recovers_a_tone_between_silences():
    sr = 8000
    rng = np.random.default_rng(3)
    lead, tone, trail = 0.12, 0.30, 0.25
    t = np.arange(int(tone * sr)) / sr
    y = np.concatenate([np.zeros(int(lead * sr)), 0.5 * np.sin(2 * np.pi * 440 * t),
                        np.zeros(int(trail * sr))])
    y = y + 1e-4 * rng.standard_normal(len(y))  # a noise floor 71 dB below the tone
    start, end = tool.word_span(y, sr)
    assert (start, end) == pytest.approx((lead, lead + tone), abs=1e-9)
    # a word within 40 dB of the loudest frame everywhere spans the whole file
    assert tool.word_span(0.5 * np.sin(2 * np.pi * 440 * t), sr) == (0.0, tone)


def test_a_changed_copy_is_caught_by_its_checksum(tmp_path):
    name = tool.subset_names()[0]
    sums = (SET_DIR / "fsdd" / "SHA256SUMS").read_text().splitlines()
    data = (SET_DIR / "fsdd" / f"{name}.wav").read_bytes()
    assert f"{hashlib.sha256(data).hexdigest()}  {name}.wav" in sums
    shutil.copytree(SET_DIR / "fsdd", tmp_path / "fsdd")
    shutil.copy(SET_DIR / "manifest.csv", tmp_path / "manifest.csv")
    (tmp_path / "fsdd" / f"{name}.wav").write_bytes(data[:-2] + bytes([data[-2] ^ 1, data[-1]]))
    assert "fsdd/SHA256SUMS" in tool.differences(tmp_path, tool.build(tmp_path, progress=False))


def test_the_parts_follow_the_speaker_rule():
    rows = [r for r in read_manifest() if r["label_source"] == FSDD_WORDS]
    assert len(rows) == 300
    by_speaker = {}
    for r in rows:
        by_speaker.setdefault(r["speaker"], set()).add(r["part"])
        assert r["transcript"] == tool.DIGITS[int(r["id"].split("_")[1])]
    assert by_speaker == {f"fsdd-{s}": {"dev" if s in ("jackson", "lucas") else "test"}
                          for s in tool.SPEAKERS}
    # the rule: the first (sorted) speaker of each accent with two speakers
    pairs = {}
    for s in sorted(tool.ACCENTS):
        pairs.setdefault(tool.ACCENTS[s], []).append(s)
    assert tuple(sorted(v[0] for v in pairs.values() if len(v) == 2)) == tool.DEV_SPEAKERS


def test_a_missing_source_is_refused_naming_the_folder(tmp_path):
    with pytest.raises(ParameterError, match=rf"--source {tmp_path}: no recordings/ folder"):
        tool.build(SET_DIR, tmp_path, progress=False)
