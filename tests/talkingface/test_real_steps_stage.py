"""The real_steps stage's trained steps (talkingface.stages.real_steps): the copy of the training
sentences it trains on holds no held-out sentence, its grid refuses children it cannot train,
and the report's table and the first page's finding print the stage's rows."""
from __future__ import annotations

import csv
import json

import pytest

from analysis.findings import real_steps_finding
from analysis.real_steps_report import TRAINED_QUESTIONS, trained_rows, trained_sentence
from face_model.corpus import load_corpus
from groundwork.errors import ParameterError
from talkingface.config import Config, load_config
from talkingface.stages.grid import REAL_STEPS
from talkingface.stages.grid_files import load_real_steps_grid
from talkingface.stages.real_speaker import copy_training_part, training_part
from tests.talkingface.full_run import real_speaker_part


def test_the_copy_holds_exactly_the_training_sentences(tmp_path):
    src = real_speaker_part(tmp_path / "c", every=8)  # 25 of GRID s1's sentences
    cfg = Config()
    dst = copy_training_part(src, tmp_path / "train", cfg)
    whole = load_corpus(src)
    want = [u.utt_id for u in training_part(whole, cfg.seed, cfg.mapping.train_fraction)
            .utterances]
    copied = load_corpus(dst)
    assert [u.utt_id for u in copied.utterances] == want and 0 < len(want) < len(whole)
    for a, b in zip(copied.utterances, (u for u in whole.utterances if u.utt_id in want)):
        assert (a.markers == b.markers).all() and (a.audio == b.audio).all()
    held = {u.text for u in whole.utterances} - {u.text for u in copied.utterances}
    assert held and not held & {u.text for u in copied.utterances}
    from analysis.speech_eval import training_speakers

    assert training_speakers(dst) == training_speakers(src) == {"grid-s1"}  # a seen speaker
    stamp = (dst / "manifest.csv").stat().st_mtime_ns
    assert copy_training_part(src, dst, cfg) == dst  # a finished copy is kept as it is
    assert (dst / "manifest.csv").stat().st_mtime_ns == stamp


def test_the_project_grid_and_a_child_it_cannot_train(tmp_path):
    children = REAL_STEPS.children(Config())
    assert list(children)[0] == "ours" and set(children) <= set(TRAINED_QUESTIONS)
    assert children["oracle"].mapping.gate_front_end == "labels"
    assert all(c.mapping.splits == ("random_frames", "utterance") for c in children.values())
    bad = tmp_path / "g.yaml"
    bad.write_text("children:\n  a: {}\n  b: {units.n_utterance: 5}\n")
    with pytest.raises(ParameterError, match=r"g\.yaml: child 'b' changes the Motion Units"):
        load_real_steps_grid(bad, Config())
    cfg = load_config(None, [f"real_steps.grid={bad}"])
    with pytest.raises(ParameterError, match=r"^real_steps\.grid: .*child 'b'"):
        REAL_STEPS.grid_file(None, cfg)


ROWS = [
    {"step": "ours", "utterance_R": "0.4321", "utterance_R_ci95": "0.0104",
     "utterance_R_differs": "reference", "random_frames_R": "0.4712",
     "random_frames_R_ci95": "0.002", "utterance_closure": "0.2", "n_seeds": "3"},
    {"step": "oracle", "utterance_R": "0.5561", "utterance_R_ci95": "0.03",
     "utterance_R_differs": "True", "utterance_R_diff": "0.12", "random_frames_R": "0.58",
     "utterance_closure": "0.6", "n_seeds": "3"},
]


def test_the_trained_rows_and_their_sentence():
    rows = trained_rows(ROWS)
    assert rows[0][2:] == ["0.432 ± 0.010", "0.471 ± 0.002", "+0.039", "0.20"]
    assert rows[1][2] == "0.556 ± 0.030 ↑" and rows[1][1] == TRAINED_QUESTIONS["oracle"]
    text = trained_sentence(ROWS)
    assert "reaches R 0.432" in text and "the best step is oracle (R 0.556)" in text
    assert "adds +0.039" in text and trained_sentence(ROWS[1:]) == ""
    assert "The true phones raise R to 0.556 in a paired test" in text
    same = [ROWS[0], {**ROWS[1], "utterance_R": "0.4", "utterance_R_differs": "False"}]
    assert "The true phones reach R 0.400, not higher than the run's mapping" in \
        trained_sentence(same)


def test_the_finding_quotes_the_tables_cells(tmp_path):
    steps = {"reconstruction_r": 0.947, "smoothing_floor": {"3": 0.992},
             "definition": {"paper": 0.36, "pixels": 0.5134},
             "regions": {"lips": {"weight": 0.31, "r": 0.48},
                         "forehead": {"weight": 0.3, "r": 0.2191}},
             "units": [{"unit": 0, "variance_share": 0.6, "cheeks": 0.1, "r_audio": 0.7},
                       {"unit": 1, "variance_share": 0.4, "cheeks": 0.6, "r_audio": 0.3}]}
    (tmp_path / "steps.json").write_text(json.dumps(steps))
    only = real_steps_finding(tmp_path)  # the probe's rows without the trained steps
    assert "the run's mapping" not in only and "keep R 0.947" in only
    with open(tmp_path / "results.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for r in ROWS for k in r)))
        w.writeheader()
        w.writerows(ROWS)
    text = real_steps_finding(tmp_path)
    cells = {r[0]: r for r in trained_rows(ROWS)}
    assert f"R {cells['ours'][2]} on held-out sentences and {cells['ours'][3]} on the " \
           "paper's frame split" in text
    assert f"with the true phones {cells['oracle'][2]}" in text
    assert "keep R 0.947" in text and "smoothed self is R 0.992" in text
    assert "probe reaches R 0.360, and 0.513 in pixels without Eq. 6's division" in text
    assert "R 0.480 on the lips' coordinates and 0.219 on the brows and forehead's" in text \
        and "(31 % and 30 %)" in text
    assert "hold 40 % of the variance, which the audio predicts at R 0.300 at most" in text
    assert real_steps_finding(tmp_path / "nowhere") is None
