"""The front_end stage (talkingface.stages.front_end): when it runs, what it trains on (never a
recording of the evaluation set), what its model file records, that the same config and seed
give the same file, that a second run reuses the teacher pass, and how the voices stage reads
it; and the report's subsection (analysis.front_end_report)."""
from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pytest

from analysis.front_end_report import accuracy_rows, front_end_section, training_rows
from analysis.report import Report
from face_model.corpus import load_corpus
from groundwork.errors import ParameterError
from mapping.front_net import front_name, read_front, training_speakers
from talkingface.config import Config, load_config
from talkingface.paths import RunPaths
from talkingface.stages import STAGES
from talkingface.stages.front_end import (front_end_applies, front_file, front_inputs, real_part,
                                          set_recordings, train_front_end)
from talkingface.stages.voices import link_tree, with_front

TINY = ["front_end.corpora=[run]", "front_end.copies=1", "front_end.train.epochs=2",
        "front_end.train.hidden=8", "front_end.train.holdout_fraction=0.25",
        "front_end.workers=1"]


def test_it_runs_when_a_voices_child_reads_the_causal_front_end(tmp_path):
    assert front_end_applies(Config())  # configs/voices.yaml has causal children
    assert not front_end_applies(load_config(None, ["voices.grid=none"]))
    assert not front_end_applies(load_config(None, ["corpus.source=c"]))  # a given corpus
    grid = tmp_path / "g.yaml"
    grid.write_text("model: a\nchildren:\n  a: {mapping.gate_front_end: recogniser, "
                    "mapping.recogniser: causal, mapping.front_model: own.npz}\n")
    assert not front_end_applies(load_config(None, [f"voices.grid={grid}"]))  # its own file
    assert "front_end" in STAGES["voices"].upstream
    assert "front_end" in STAGES["speech_eval"].upstream


def test_the_real_speaker_part_leaves_out_every_recording_of_the_evaluation_set():
    cfg = Config()
    part = real_part(cfg)
    held = set_recordings("grid-s1")
    assert held and part.utterances
    assert not {u.utt_id for u in part.utterances} & held
    from talkingface.stages.real_speaker import real_corpus, training_part

    whole = training_part(load_corpus(real_corpus(cfg)), cfg.seed, cfg.mapping.train_fraction)
    dropped = {u.utt_id for u in whole.utterances} - {u.utt_id for u in part.utterances}
    assert dropped and dropped <= held  # only those: the rest of the training part is kept


def test_real_without_a_real_speaker_is_refused_in_one_line(tmp_path):
    cfg = load_config(None, ["front_end.corpora=[run, real]", "real_speaker.corpus="])
    with pytest.raises(ParameterError, match=r"^front_end\.corpora lists 'real' but "
                                             r"real_speaker\.corpus names no corpus"):
        front_inputs(RunPaths.at(tmp_path / "r"), cfg)
    assert front_inputs(None, Config()) == {}  # no real corpus: nothing outside the run


@pytest.fixture(scope="module")
def trained(tmp_path_factory, small_corpus_dir):
    """The stage run twice on the small corpus (12 utterances), each in its own run folder
    sharing one cache: (paths, done) of both."""
    root = tmp_path_factory.mktemp("front")
    cfg = load_config(None, TINY)
    out = []
    for name in ("a", "b"):
        paths = RunPaths.create(name, runs_dir=root / "runs")
        shutil.copytree(small_corpus_dir, paths.corpus)
        out.append((paths, train_front_end(paths, cfg)))
    return cfg, out


def test_the_stage_writes_a_model_file_that_records_its_speakers(trained):
    cfg, [(paths, done), _] = trained
    arrays, meta = read_front(front_file(paths))
    assert done["model"] == front_file(paths).name
    assert meta["training_speakers"] == done["training_speakers"] == ["espeak"]
    assert training_speakers(front_file(paths)) == {"espeak"}
    assert meta["corpora"] == ["run"] and meta["run_seed"] == cfg.seed
    assert meta["hidden"] == 8 and len(meta["history"]) == 2
    assert done["examples"] == 2 * sum(done["utterances"].values())  # one augmented copy each
    assert done["teacher"]["heard"] + done["teacher"]["reused"] >= 1


def test_the_same_config_and_seed_give_the_same_file_and_reuse_the_teacher(trained):
    _, [(a, first), (b, second)] = trained
    assert second["teacher"]["heard"] == 0
    assert second["teacher"]["reused"] == first["teacher"]["heard"] + first["teacher"]["reused"]
    arrays_a, _ = read_front(front_file(a))
    arrays_b, _ = read_front(front_file(b))
    for k in arrays_a:
        np.testing.assert_array_equal(arrays_a[k], arrays_b[k])
    assert front_name(front_file(a)) == front_name(front_file(b))


def test_a_voices_child_reads_the_runs_front_end(trained, tmp_path):
    _, [(paths, _), _] = trained
    child = load_config(None, ["mapping.gate_front_end=recogniser", "mapping.recogniser=causal"])
    assert with_front(child, paths).mapping.front_model == str(front_file(paths).resolve())
    own = dataclasses.replace(child, mapping=dataclasses.replace(child.mapping,
                                                                 front_model="own.npz"))
    assert with_front(own, paths) is own  # a file of its own is kept
    hama = load_config(None, ["mapping.gate_front_end=recogniser", "mapping.recogniser=hama"])
    assert with_front(hama, paths) is hama
    assert with_front(child, RunPaths.at(tmp_path / "none")) is child  # no run front end
    copy = link_tree(paths.corpus, tmp_path / "linked")
    assert sorted(p.name for p in copy.rglob("*")) == \
        sorted(p.name for p in paths.corpus.rglob("*"))


def test_the_report_prints_the_stage_record_and_the_rows(trained, tmp_path):
    _, [(paths, done), _] = trained
    rows = dict(training_rows(done))
    assert rows["training speakers (seen)"] == "espeak"
    assert rows["training"].startswith(f"{done['train_seconds']:.0f} s, 2 epochs")
    results = [{"model": "causal-front v1 sha256:x", "split": "unseen-dev", "files": "3",
                "speakers": "2", "viseme_acc": "0.5", "viseme_acc_stream_100ms": "0.25",
                "input_rate": "native"},
               {"model": "hama-1.7.0 phoneme CTC", "split": "unseen-dev", "files": "4",
                "speakers": "2", "viseme_acc": "0.75", "viseme_acc_stream_100ms": "0.5",
                "input_rate": "native"}]
    assert accuracy_rows(results, "viseme_acc_stream_100ms") == [
        ["the causal front end (ours)", "development", "2 / 3", "0.500", "0.250"],
        ["hama (its teacher)", "development", "2 / 4", "0.750", "0.500"]]
    speech = tmp_path / "speech_eval"
    speech.mkdir()
    with open(speech / "results.csv", "w") as f:
        f.write(",".join(results[0]) + "\n")
        for r in results:
            f.write(",".join(r.values()) + "\n")
    rep = Report("t")
    front_end_section(rep, done, speech)
    text = json.dumps([str(x) for x in rep.story])
    assert "The causal front end" in text and "espeak" in text
    assert rep.build(tmp_path / "r.pdf").stat().st_size > 0
