"""tools/real_speaker_steps.py: the real speaker's steps measured on training sentences only
(a held-out sentence changed changes nothing), with every row the module text promises."""
from __future__ import annotations

import csv
import json

import numpy as np

from tests.talkingface.full_run import real_speaker_part
from talkingface.stages.real_speaker import training_part
from talkingface.stages.real_steps import CONTEXTS, LAGS
from tools.real_speaker_steps import main, measure


def test_the_steps_never_read_a_held_out_sentence(tmp_path, capsys):
    corpus = real_speaker_part(tmp_path / "c", every=8)  # 25 of GRID s1's sentences
    before = measure(corpus, 2002)
    from face_model.corpus import load_corpus

    whole = load_corpus(corpus)
    kept = {u.utt_id for u in training_part(whole, 2002, 0.8).utterances}
    held = [u for u in whole.utterances if u.utt_id not in kept]
    assert held and before["training_sentences"] == len(kept)
    with open(corpus / "manifest.csv", newline="") as f:
        row = next(r for r in csv.DictReader(f) if r["utt_id"] == held[0].utt_id)
    path = corpus / row["markers"]
    np.save(path, np.load(path) * 1.5 + 3.0)  # a held-out sentence's face changed
    assert main(["--corpus", str(corpus), "--json"]) == 0  # the command, after the change
    assert json.loads(capsys.readouterr().out) == json.loads(json.dumps(before, default=float))
    assert set(before["offset"]["r"]) == set(LAGS) and before["offset"]["best"] in LAGS
    assert set(before["context"]) == set(CONTEXTS)
    assert before["definition"]["paper"] == before["context"][3]  # the same probe, two rows
    assert 0 < before["reconstruction_r"] <= 1 and len(before["units"]) == 7
    assert abs(sum(u["variance_share"] for u in before["units"]) - 1) < 1e-9


def test_a_folder_that_is_not_a_corpus_is_one_line(tmp_path, capsys):
    assert main(["--corpus", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "nowhere" in err[0] \
        and "manifest not found" in err[0]
