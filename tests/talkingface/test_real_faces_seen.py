"""Who a candidate has seen on a real face (``talkingface.stages.real_faces.face_speakers``):
faces drawn with an articulation fitted on a real speaker's sentences have seen that speaker's
mouth, though the model never heard them; the hand table and a given corpus add nobody."""
from __future__ import annotations

import csv
import dataclasses

from data_synth.articulation import Articulation, articulation_record, write_articulation
from data_synth.generate import synthesize_corpus
from face_model.corpus import corpus_hash
from talkingface.config import Config
from talkingface.stages.real_faces import BUILTIN, face_speakers
from talkingface.stages.real_speaker import real_corpus
from tests.conftest import small_synth_config


def _draw(root, articulation: str):
    cfg = small_synth_config(n_sentences=1, expressions=("neutral",), articulation=articulation)
    return synthesize_corpus(root, cfg, 2002, progress=False)


def test_faces_drawn_with_the_shipped_fit_have_seen_the_real_speaker(tmp_path):
    real = real_corpus(Config())
    assert real is not None
    fitted = _draw(tmp_path / "fitted", "grid-s1")
    table = _draw(tmp_path / "table", "table")
    assert face_speakers(fitted, real) == {"grid-s1"}  # the fit's sentences' speaker
    assert face_speakers(table, real) == frozenset()
    assert face_speakers(BUILTIN["test"], real) == frozenset()  # a given corpus: its own ids


def test_the_speakers_are_those_of_the_fits_own_sentences(tmp_path):
    """A fit whose record names a corpus of two speakers and sentences of one of them: only
    that one is seen; without that corpus at hand, the record's corpus name."""
    real = tmp_path / "two"
    synthesize_corpus(real, dataclasses.replace(
        small_synth_config(n_sentences=2, expressions=("neutral",)), speakers=2), 2002,
        progress=False)
    with open(real / "manifest.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    speakers = sorted({r["speaker"] for r in rows})
    assert len(speakers) == 2
    mine = [r["utt_id"] for r in rows if r["speaker"] == speakers[1]]
    model = tmp_path / "fit.npz"
    write_articulation(model, Articulation.table(), {
        "corpus": "two", "corpus_hash": corpus_hash(real), "training_utterances": mine})
    assert articulation_record(model)["training_utterances"] == mine
    drawn = _draw(tmp_path / "drawn", str(model))
    assert face_speakers(drawn, real) == {speakers[1]}
    assert face_speakers(drawn, None) == {"two"}
