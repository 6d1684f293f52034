"""The shipped real faces (face_model/real_faces): GRID s1 (the real speaker), s26 (development)
and s31 (test, never trained on), each a corpus the one reader takes whole, with GRID's word
times that join to each sentence and sit on its speech, its speaker id, and its attribution."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from face_model.corpus import load_corpus

REAL = Path(__file__).resolve().parents[2] / "face_model" / "real_faces"
SPEAKERS = ("s1", "s26", "s31")
PART = {"s26": "development", "s31": "test"}
CLIPS = 10  # in ../shared/grid-more/<speaker>/, each


@pytest.fixture(scope="module", params=SPEAKERS)
def shipped(request):
    spk = request.param
    return spk, load_corpus(REAL / f"grid-{spk}")


def test_each_shipped_corpus_loads_under_its_own_speaker_id(shipped):
    spk, corpus = shipped
    assert {u.speaker for u in corpus.utterances} == {f"grid-{spk}"}
    assert corpus.info["settings"]["speaker"] == f"grid-{spk}"
    assert corpus.info["made_by"] == "talkingface corpus from-video"
    assert corpus.info["settings"]["audio_format"] == "flac"
    assert all(u.quality is not None and u.phones for u in corpus.utterances)


def test_every_utterance_has_words_that_join_to_its_text(shipped):
    spk, corpus = shipped
    for u in corpus.utterances:
        assert u.words, u.utt_id
        assert " ".join(w.word for w in u.words) == u.text
        assert all(a.end_s <= b.start_s for a, b in zip(u.words, u.words[1:]))
        assert u.words[-1].end_s <= len(u.audio) / u.sample_rate
    assert corpus.info["words"]["utterances"] == len(corpus)


def test_the_word_times_sit_on_the_speech_the_aligner_found(shipped):
    """GRID's word times and the forced-aligned phones (made independently from the audio) agree:
    nearly all of the non-silence phones' time lies inside some word."""
    _, corpus = shipped
    speech = inside = 0.0
    for u in corpus.utterances:
        for p in u.phones:
            if p.phone == "sil":
                continue
            speech += p.end_s - p.start_s
            inside += sum(max(0.0, min(p.end_s, w.end_s) - max(p.start_s, w.start_s))
                          for w in u.words)
    assert inside / speech > 0.9


@pytest.mark.parametrize("spk", ["s26", "s31"])
def test_the_unseen_speakers_say_their_part_how_they_were_made_and_what_was_refused(spk):
    root = REAL / f"grid-{spk}"
    notice = root / "NOTICE.md"
    text = " ".join(notice.read_text().split())
    info = json.loads((root / "corpus.json").read_text())
    assert f"the {PART[spk]} speaker" in text and "No model of the project is trained on it" in text
    assert ("Cooke" in text and "Creative Commons Attribution 4.0" in text
            and "Zenodo (record 3625687)" in text)
    assert "CC BY 4.0" in info["licence"] and f"speaker {spk}" in info["licence"]
    assert (f".venv/bin/talkingface corpus from-video ../shared/grid-more/{spk}/video "
            f"--out face_model/real_faces/grid-{spk} --speaker grid-{spk} --audio-format flac "
            f"--licence \"{info['licence']}\"") in text.replace("\\ ", "")
    refused = root / "refused.csv"
    rows = list(csv.DictReader(open(refused, newline=""))) if refused.is_file() else []
    assert info["clips"] == CLIPS and info["utterances"] + len(rows) == CLIPS
    assert info["refused"] == len(rows)
    for r in rows:  # every refused clip is named in the notice with its reason
        assert f"`{r['clip']}`: {' '.join(r['reason'].split())}" in text
    ids = [u.utt_id for u in load_corpus(root).utterances]
    assert not set(ids) & {r["clip"] for r in rows}


def test_the_shipped_corpora_stay_small():
    for spk, limit_mb in (("s26", 2), ("s31", 2)):
        size = sum(p.stat().st_size for p in (REAL / f"grid-{spk}").rglob("*") if p.is_file())
        assert size < limit_mb * 2**20, (spk, size)
        assert not list((REAL / f"grid-{spk}").glob("audio/*.wav"))  # FLAC, as grid-s1
