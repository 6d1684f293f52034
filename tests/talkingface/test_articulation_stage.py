"""The articulation fitted on the real speaker: only its training sentences are read, the
shipped file is its fit, and the stage scores the hand table against it on held-out lips."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from data_synth.articulation import read_articulation
from face_model.corpus import load_corpus
from talkingface.config import load_config
from talkingface.paths import RunPaths
from talkingface.stages.articulation import (evaluate_articulation, fit_real_articulation,
                                             shipped_path)
from talkingface.stages.given_corpus import combine_corpora
from talkingface.stages.real_speaker import BUILTIN
from talkingface.stages.training import utterance_test_ids

REPO = Path(__file__).resolve().parents[2]
N_CLIPS = 14


@pytest.fixture(scope="module")
def small_real(tmp_path_factory):
    """The first 14 clips of the built-in real speaker, as a corpus folder of real files."""
    ids = [u.utt_id for u in load_corpus(BUILTIN).utterances[:N_CLIPS]]
    out = tmp_path_factory.mktemp("real") / "corpus"
    combine_corpora([(BUILTIN, set(ids), "")], out)
    for p in out.rglob("*"):  # hard links: make every file its own before a test edits one
        if p.is_file():
            data = p.read_bytes()
            p.unlink()
            p.write_bytes(data)
    return out


def _cfg(corpus: Path):
    return load_config(REPO / "configs" / "paper.yaml", [f"real_speaker.corpus={corpus}"])


def _shift_markers(corpus: Path, utt_id: str) -> None:
    path = corpus / "markers" / f"{utt_id}.npy"
    m = np.load(path)
    m[:, 46:76, 1] += np.linspace(0, 4, len(m), dtype=np.float32)[:, None]
    np.save(path, m)


def test_held_out_sentences_change_no_fitted_parameter(small_real, tmp_path):
    cfg = _cfg(small_real)
    corpus = load_corpus(small_real)
    held = utterance_test_ids(corpus, cfg)
    train = [u.utt_id for u in corpus.utterances if u.utt_id not in held]
    assert held and train
    first, record = fit_real_articulation(cfg, small_real, steps=25)
    assert sorted(record["training_utterances"]) == sorted(train)
    changed = tmp_path / "changed"
    combine_corpora([(small_real, None, "")], changed)
    for utt in held:  # new files, not links into the fixture
        (changed / "markers" / f"{utt}.npy").unlink()
        (changed / "markers" / f"{utt}.npy").write_bytes(
            (small_real / "markers" / f"{utt}.npy").read_bytes())
        _shift_markers(changed, utt)
    again, _ = fit_real_articulation(cfg, changed, steps=25)
    np.testing.assert_array_equal(again.targets, first.targets)
    np.testing.assert_array_equal(again.dominance, first.dominance)
    assert again.theta_anticipation == first.theta_anticipation
    # a training sentence does change the fit (the check above can fail)
    (changed / "markers" / f"{train[0]}.npy").unlink()
    (changed / "markers" / f"{train[0]}.npy").write_bytes(
        (small_real / "markers" / f"{train[0]}.npy").read_bytes())
    _shift_markers(changed, train[0])
    moved, _ = fit_real_articulation(cfg, changed, steps=25)
    assert not np.array_equal(moved.targets, first.targets)


def test_the_shipped_file_records_its_data_and_command():
    model = read_articulation(shipped_path())
    rec = model.record
    assert rec["command"] == "python tools/fit_articulation.py"
    assert rec["seed"] == 2002 and rec["train_fraction"] == 0.8
    assert rec["corpus_hash"] and "CC BY 4.0" in rec["licence"]
    cfg = load_config(REPO / "configs" / "paper.yaml")
    corpus = load_corpus(BUILTIN)
    held = set(utterance_test_ids(corpus, cfg))
    assert not held & set(rec["training_utterances"])
    assert len(rec["training_utterances"]) + len(held) == len(corpus.utterances)


def test_the_stage_scores_table_and_fitted_on_held_out_lips(small_real, tmp_path):
    cfg = _cfg(small_real)
    paths = RunPaths.at(tmp_path / "run")
    paths.stage("articulation").mkdir(parents=True)
    evaluate_articulation(paths, cfg)
    summary = json.loads((paths.stage("articulation") / "summary.json").read_text())
    rows = {r["model"]: r for r in summary["rows"]}
    assert list(rows) == ["articulatory space", "hand table", "fitted (grid-s1)"]
    assert summary["held_out_clips"] == len(utterance_test_ids(load_corpus(small_real), cfg))
    for r in rows.values():
        assert -1 <= r["r_opening"] <= 1 and r["speech_frames"] > 0
    # both models force the lips shut inside /p b m/
    assert rows["hand table"]["closed"] == rows["fitted (grid-s1)"]["closed"] == 1.0
