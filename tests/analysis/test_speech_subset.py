"""``speech_set.per_speaker``: the first N recordings of each speaker and part of the real-speech
set, in manifest order (:func:`analysis.speech_set.subset_rows`); the ``speech_eval`` stage
scores exactly those, says so in results.json and in the report, and is made again when the
setting changes."""
from __future__ import annotations

import csv
import json

import pytest

from analysis.speech_report import set_part_text
from analysis.speech_set import SET_DIR, load_speech_set, read_manifest, subset_rows
from groundwork.errors import ParameterError
from talkingface import stages
from talkingface.config import load_config
from talkingface.paths import RunPaths
from talkingface.stages import speech_eval as stage
from talkingface.stages.base import DONE, fingerprint, stage_key
from tests.talkingface.test_evaluate_speech import set_of, tiny_trained_run

TINY = ["mapping.baselines=[]", "mapping.splits=[utterance]", "mapping.train.max_epochs=8",
        "mapping.min_class_frames=20", "mlflow.enabled=false", "voices.grid=none"]


def _group(row) -> tuple:
    return row["speaker"], row["part"]


def _first_of_each(rows, n) -> list:
    """The ids of the first ``n`` rows of each speaker and part, counted afresh per row."""
    return [r["id"] for i, r in enumerate(rows)
            if sum(_group(q) == _group(r) for q in rows[:i]) < n]


@pytest.mark.parametrize("n", [1, 2, 3])
def test_the_subset_is_the_first_n_of_each_speaker_and_part_in_manifest_order(n):
    rows = read_manifest(SET_DIR)
    sub = subset_rows(rows, n)
    assert [r["id"] for r in sub] == _first_of_each(rows, n)
    # every speaker and part of the set stays, with min(n, its recordings) recordings
    assert {_group(r) for r in sub} == {_group(r) for r in rows}
    for g in {_group(r) for r in rows}:
        have = sum(_group(r) == g for r in rows)
        assert sum(_group(r) == g for r in sub) == min(n, have), g
    # a speaker with fewer recordings than n gives all it has (the one ARCTIC slt sentence)
    assert [r["id"] for r in sub if r["speaker"] == "arctic-slt"] == ["slt_a0009"]


def test_the_subset_is_the_same_on_two_calls_and_zero_is_the_whole_set():
    rows = read_manifest(SET_DIR)
    first = [it.id for it in load_speech_set(SET_DIR, per_speaker=1)]
    assert first == [it.id for it in load_speech_set(SET_DIR, per_speaker=1)]
    assert first == [r["id"] for r in subset_rows(read_manifest(SET_DIR), 1)]
    assert [r["id"] for r in subset_rows(rows, 0)] == [r["id"] for r in rows]
    assert len(rows) == 374  # the shipped set (analysis/real_speech/manifest.csv)


@pytest.mark.parametrize("bad", [-1, 1.5, True, "2"])
def test_a_bad_per_speaker_is_refused_naming_the_setting(bad):
    with pytest.raises(ParameterError, match=r"^speech_set\.per_speaker is .*; allowed: an "
                                             r"integer >= 0"):
        subset_rows(read_manifest(SET_DIR), bad)


@pytest.mark.parametrize("value, message", [
    ("-1", r"^speech_set\.per_speaker is -1; allowed: an integer >= 0$"),
    ("x", r"^speech_set\.per_speaker must be an integer, got 'x'$")])
def test_the_setting_refuses_a_bad_value_in_one_line(value, message):
    with pytest.raises(ParameterError, match=message):
        load_config(None, [f"speech_set.per_speaker={value}"])


def _cut_set(root, keep) -> tuple:
    """The shipped set cut to the rows ``keep`` accepts (``set_of`` of
    tests/talkingface/test_evaluate_speech.py); returns (folder, rows)."""
    out = set_of(root, keep)
    return out, read_manifest(out)


@pytest.fixture(scope="module")
def cut_set(tmp_path_factory):
    """17 recordings of 5 speakers in both parts: ARCTIC slt (1), the 7 pocketsphinx test
    recordings, and the first 3 of GRID s1, FSDD jackson (dev) and FSDD george (test)."""
    taken: dict = {}

    def keep(r):
        if r["speaker"] in ("arctic-slt", "pocketsphinx-test"):
            return True
        if r["speaker"] in ("grid-s1", "fsdd-jackson", "fsdd-george"):
            taken[r["speaker"]] = taken.get(r["speaker"], 0) + 1
            return taken[r["speaker"]] <= 3
        return False
    return _cut_set(tmp_path_factory.mktemp("cut_set"), keep)


@pytest.fixture(scope="module")
def tiny_run(small_corpus_dir, tmp_path_factory):
    """runs/t with the small corpus, its Motion Units and a mapping trained for a few epochs."""
    return tiny_trained_run(tmp_path_factory.mktemp("speech_subset"), small_corpus_dir)


def test_the_stage_scores_exactly_the_first_two_of_each_speaker(tiny_run, cut_set,
                                                                monkeypatch):
    set_dir, rows = cut_set
    monkeypatch.setattr(stage, "SET_DIR", set_dir)
    want = _first_of_each(rows, 2)
    assert len(want) == 9 and len(rows) == 17
    done = stage.evaluate_speech(tiny_run, load_config(None, [*TINY, "speech_set.per_speaker=2"]))
    assert done["speech_set"] == {"per_speaker": 2, "set_recordings": 17, "recordings": 9}
    info = json.loads((tiny_run.speech_eval / "results.json").read_text())
    assert info["recordings"] == want
    assert info["speech_set"] == {"per_speaker": 2, "set_recordings": 17}
    with open(tiny_run.speech_eval / "per_file.csv") as f:
        per_file = list(csv.DictReader(f))
    systems = {r["model"] for r in per_file}
    assert {"gated_mlp_utterance", "pocketsphinx-5.1.1 allphone", "pylipsync"} <= systems
    for system in systems:
        assert sorted(r["id"] for r in per_file if r["model"] == system) == sorted(want), system
    # the report says it is a part of the set, not the whole
    text = set_part_text(info)
    assert "9 of 17 recordings (the first 2 of each speaker and part" in text
    assert "of 5 speakers" in text
    assert set_part_text({**info, "speech_set": {"per_speaker": 0, "set_recordings": 17}}) == ""


def _settle(paths, cfg) -> None:
    """Mark every stage ``speech_eval`` needs, and itself, finished under ``cfg``'s keys."""
    for _ in range(len(stages.STAGES)):
        todo = stages.stale(["speech_eval"], paths, cfg)
        if not todo:
            return
        out = paths.stage(todo[0])
        out.mkdir(parents=True, exist_ok=True)
        key = stage_key(stages.STAGES[todo[0]], stages.STAGES, paths, cfg)
        (out / DONE).write_text(json.dumps({"fingerprint": fingerprint(key)}))
    raise AssertionError(f"still stale: {todo}")


def _stale(paths, per_speaker) -> list:
    cfg = load_config(None, [*TINY, f"speech_set.per_speaker={per_speaker}"])
    return stages.stale(["speech_eval"], paths, cfg)


@pytest.mark.parametrize("before, after", [(2, 3), (2, 0), (0, 1)])
def test_a_change_of_the_setting_makes_the_stage_stale(tmp_path, before, after):
    paths = RunPaths.create("s", runs_dir=tmp_path / "runs")
    _settle(paths, load_config(None, [*TINY, f"speech_set.per_speaker={before}"]))
    assert _stale(paths, before) == []
    assert _stale(paths, after) == ["speech_eval"]


def test_the_setting_is_in_the_stages_key_even_when_it_picks_every_recording(tmp_path):
    # 0 and 60 (more than any speaker has) pick the same recordings; results.json and the
    # report still say which setting made them
    paths = RunPaths.create("s", runs_dir=tmp_path / "runs")
    _settle(paths, load_config(None, TINY))
    assert _stale(paths, 60) == ["speech_eval"]
