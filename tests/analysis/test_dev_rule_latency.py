"""The development rule weighs time (issue 40): a model whose measured live latency p99 exceeds
the bound (the paper's window plus one frame) cannot be the default, whatever its accuracy; a
model without a measured latency cannot either; the report and tools/choose_voice_model.py say
which models the bound excluded, and say so when the latency was not measured."""
from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import pytest

from analysis.config import PAPER_STREAM_LATENCY_MS, TargetsConfig
from analysis.report import Report
from analysis.dev_rule import (DEV_RULE, LATENCY_FILE, dev_choice, excluded_by_latency,
                               latency_p99, read_latency)
from analysis.speech_report import speech_section
from groundwork.settings import SettingError
from tests.analysis.findings_check import page_texts

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import choose_voice_model as voice_tool  # noqa: E402


def _row(model, split, *v):
    return {"model": model, "split": split, **dict(zip(DEV_RULE, map(str, v)))}


RESULTS = [_row("voices-hama", "unseen-dev", 0.8, 0.8, 0.8, 0.8),  # 0.80: the best score
           _row("voices-one", "unseen-dev", 0.6, 0.6, 0.6, 0.6),  # 0.60
           _row("voices-two", "unseen-dev", 0.5, 0.5, 0.5, 0.5),  # 0.50
           _row("voices-hama", "unseen-test", 1, 1, 1, 1)]


def test_the_bound_is_the_papers_window_plus_one_frame():
    # context_forward 3 frames at 30 fps (100 ms) + one frame (33.3 ms)
    assert PAPER_STREAM_LATENCY_MS == pytest.approx(100 + 1000 / 30)
    assert TargetsConfig().stream_latency_p99_ms == PAPER_STREAM_LATENCY_MS
    with pytest.raises(SettingError, match=r"stream_latency_p99_ms is 0; allowed: a finite "
                                           r"number in \(0, 10000\]"):
        TargetsConfig(stream_latency_p99_ms=0)


def test_a_model_over_the_bound_is_not_the_pick_whatever_its_score():
    latency = {"voices-hama": 183.0, "voices-one": 123.0, "voices-two": 120.0}
    best, scores = dev_choice(RESULTS, latency=latency, bound_ms=133.3)
    assert best == "voices-one"
    assert scores["voices-hama"] == pytest.approx(0.8)  # still scored, not picked
    assert excluded_by_latency(RESULTS, latency, 133.3) == {"voices-hama": 183.0}
    # without latency or without a bound the rule is the development figures alone
    assert dev_choice(RESULTS)[0] == "voices-hama"
    assert dev_choice(RESULTS, latency=latency)[0] == "voices-hama"
    assert dev_choice(RESULTS, bound_ms=133.3)[0] == "voices-hama"
    assert excluded_by_latency(RESULTS, None, 133.3) == {}


def test_a_model_without_a_measured_latency_is_excluded_when_a_bound_is_given():
    latency = {"voices-hama": 100.0, "voices-one": None}  # one: not paced; two: not measured
    best, _ = dev_choice(RESULTS, latency=latency, bound_ms=133.3)
    assert best == "voices-hama"
    assert excluded_by_latency(RESULTS, latency, 133.3) == {"voices-one": None,
                                                            "voices-two": None}
    assert dev_choice(RESULTS, latency={"voices-hama": 200.0}, bound_ms=133.3) == \
        (None, pytest.approx({"voices-hama": 0.8, "voices-one": 0.6, "voices-two": 0.5}))
    assert dev_choice(RESULTS, latency={}, bound_ms=133.3)[0] is None


def _latency_file(folder: Path, p99: dict) -> dict:
    data = {"recording": "analysis/real_speech/arctic/awb_a0007.wav", "seconds": 4.0,
            "chunk_s": 0.01, "paced": True,
            "models": {m: {"latency_p50_ms": None if v is None else v - 10,
                           "latency_p99_ms": v, "compute_p50_ms": 1.0, "compute_p99_ms": 2.0,
                           "algorithmic_latency_ms": 112.5, "paced": v is not None}
                       for m, v in p99.items()}}
    (folder / LATENCY_FILE).write_text(json.dumps(data), encoding="utf-8")
    return data


def test_the_latency_file_is_read_as_p99_per_model(tmp_path):
    assert read_latency(tmp_path) is None and latency_p99(None) is None
    data = _latency_file(tmp_path, {"voices-hama": 183.0, "voices-one": None})
    assert read_latency(tmp_path) == data == read_latency(tmp_path / LATENCY_FILE)
    assert latency_p99(data) == {"voices-hama": 183.0, "voices-one": None}


class _Recorder:
    """Keeps the text of what a section adds (a stand-in for analysis.report.Report)."""

    def __init__(self):
        self.paragraphs, self.tables = [], []

    def heading(self, *a, **k):
        pass

    def paragraph(self, text):
        self.paragraphs.append(text)

    def table(self, caption, header, rows, **k):
        self.tables.append((caption, header, rows, k))

    def figure(self, *a, **k):
        pass


def _speech_dir(tmp_path: Path) -> Path:
    speech = tmp_path / "speech_eval"
    speech.mkdir()
    with open(speech / "results.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, ["model", "split", *DEV_RULE, "files"])
        w.writeheader()
        w.writerows({**r, "files": "3"} for r in RESULTS)
    return speech


def test_the_report_lists_the_models_the_bound_excluded(tmp_path):
    speech = _speech_dir(tmp_path)
    _latency_file(speech, {"voices-hama": 183.0, "voices-one": 123.0,
                           "gated_mlp_utterance": 124.0})
    rep = _Recorder()
    speech_section(rep, speech, [], table_ii_R=None, default_model="hama")
    rule = next(p for p in rep.paragraphs if p.startswith("The development rule"))
    assert "picks <b>voices-one</b> (0.600)" in rule
    assert "exceeds 133.3 ms (targets.stream_latency_p99_ms" in rule
    assert "the bound excluded <b>voices-hama</b>, <b>voices-two</b>" in rule
    assert "The run's default is <b>voices-hama</b> (0.800, over the latency bound)" in rule
    caption, header, rows, kw = next(t for t in rep.tables if t[3].get("key") == "speech_latency")
    assert "133.3 ms" in caption and "paced in real time" in kw["note"]
    by = {r[0]: r for r in rows}
    assert by["voices-hama"][1:4] == ["0.800", "173", "183"]
    assert by["voices-hama"][-1] == "excluded" and by["voices-one"][-1] == "within"
    assert by["voices-two"][3] == "–" and by["voices-two"][-1] == "excluded: not measured"
    assert by["gated_mlp_utterance"][-1] == "not a candidate"


def test_the_report_says_when_the_latency_was_not_measured(tmp_path):
    speech = _speech_dir(tmp_path)
    rep = _Recorder()
    speech_section(rep, speech, [], table_ii_R=None, default_model="hama",
                   targets=TargetsConfig(stream_latency_p99_ms=150))
    rule = next(p for p in rep.paragraphs if p.startswith("The development rule"))
    assert "picks <b>voices-hama</b> (0.800)" in rule
    assert (f"The live latency of the candidates was not measured (no {LATENCY_FILE}), so the "
            "bound on it, 150.0 ms") in rule
    assert "(the same)." in rule
    assert not any(t[3].get("key") == "speech_latency" for t in rep.tables)


def test_the_latency_table_is_typeset_in_the_pdf(tmp_path):
    speech = _speech_dir(tmp_path)
    _latency_file(speech, {"voices-hama": 183.0, "voices-one": 123.0})
    rep = Report("T")
    speech_section(rep, speech, [], table_ii_R=None, default_model="one")
    text = " ".join(" ".join(page_texts(rep.build(tmp_path / "r.pdf"))).split())
    assert "Live latency of each model in `talkingface stream`" in text
    assert "the bound excluded voices-hama, voices-two (Table" in text


# -- tools/choose_voice_model.py ----------------------------------------------------------------

def _run(tmp_path: Path, p99: dict | None, model: str = "hama") -> tuple[Path, Path]:
    run = tmp_path / "run"
    speech = run / "speech_eval"
    speech.mkdir(parents=True)
    with open(speech / "results.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, ["model", "split", *DEV_RULE])
        w.writeheader()
        w.writerows(RESULTS)
    if p99 is not None:
        _latency_file(speech, p99)
    voices = tmp_path / "voices.yaml"
    voices.write_text(f"model: {model}\nchildren:\n  one: {{}}\n", encoding="utf-8")
    return run, voices


def test_the_chooser_prints_latency_and_leaves_out_a_child_over_the_bound(tmp_path, capsys):
    run, voices = _run(tmp_path, {"voices-hama": 183.0, "voices-one": 123.0,
                                  "voices-two": 120.0}, model="one")
    result = voice_tool.choose(voice_tool.read_results(run),
                               read_latency(run / "speech_eval"), 133.3)
    assert result["pick"] == "one" and result["excluded"] == ["hama"]
    rows = {r["child"]: r for r in result["rows"]}
    assert rows["hama"]["latency_p99_ms"] == 183.0 and rows["hama"]["excluded"]
    assert voice_tool.main([str(run), "--voices", str(voices)]) == 0
    out = capsys.readouterr().out
    hama = next(line for line in out.splitlines() if line.startswith("hama "))
    assert hama.split()[-5:] == ["173", "183", "over", "the", "bound"]
    assert "latency bound: p99 at most 133.3 ms (targets.stream_latency_p99_ms); excluded: hama" \
        in out and "pick: one" in out
    assert voice_tool.main([str(run), "--voices", str(voices), "--check"]) == 0
    # a looser bound lets the best score through again
    assert voice_tool.main([str(run), "--voices", str(voices), "--bound-ms", "200"]) == 0
    assert "pick: hama" in capsys.readouterr().out


def test_the_check_applies_the_bound_and_names_it(tmp_path, capsys):
    run, voices = _run(tmp_path, {"voices-hama": 183.0, "voices-one": 123.0}, model="hama")
    assert voice_tool.main([str(run), "--voices", str(voices), "--check"]) == 1
    assert capsys.readouterr().err.strip() == (
        f"{voices}: model is 'hama' (over the latency bound of 133.3 ms) but the development "
        "rule picks 'one'")


def test_the_bound_comes_from_the_runs_targets(tmp_path, capsys):
    run, voices = _run(tmp_path, {"voices-hama": 183.0, "voices-one": 123.0})
    (run / "speech_eval" / "config.yaml").write_text(
        "targets:\n  stream_latency_p99_ms: 190.0\n", encoding="utf-8")
    assert voice_tool.run_bound(run) == 190.0
    assert voice_tool.main([str(run), "--voices", str(voices), "--check"]) == 0
    (run / "speech_eval" / "config.yaml").write_text(
        "targets:\n  stream_latency_p99_ms: -1\n", encoding="utf-8")
    assert voice_tool.main([str(run), "--voices", str(voices)]) == 2
    assert capsys.readouterr().err.strip().endswith(
        "config.yaml: targets.stream_latency_p99_ms is -1; allowed: a finite number in "
        "(0, 10000]")


def test_without_a_latency_file_the_chooser_says_so_and_applies_no_bound(tmp_path, capsys):
    run, voices = _run(tmp_path, None)
    assert voice_tool.main([str(run), "--voices", str(voices)]) == 0
    out = capsys.readouterr().out
    assert "latency: not measured (no speech_eval/latency.json); no bound applied" in out
    assert "pick: hama" in out


def test_when_the_bound_excludes_every_scored_child_the_chooser_says_which(tmp_path, capsys):
    run, voices = _run(tmp_path, {"voices-hama": 183.0, "voices-one": 150.0})
    assert voice_tool.main([str(run), "--voices", str(voices)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"{run / 'speech_eval'}: the latency bound (133.3 ms) excluded every voices child with "
        "a score: hama, one, two")
