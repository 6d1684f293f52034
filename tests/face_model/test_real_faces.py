"""The shipped real faces (face_model/real_faces): GRID s1 (the real speaker), s26 (development)
and s31 (test, never trained on), each a corpus the one reader takes whole, with GRID's word
times that join to each sentence and sit on its speech, its speaker id, and its attribution;
s26 and s31 keep all their clips, each admitted by the rule for the source's own word times."""
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
KEPT = {"s26": 10, "s31": 10}  # none refused (corpus.json's admitted_by says by which rule)


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
    """GRID's word times and the forced-aligned phones agree: nearly all of the non-silence
    phones' time lies inside some word (s1's phones were aligned over the whole sentence, without
    the word times; s26's and s31's within them, so all of it)."""
    spk, corpus = shipped
    speech = inside = 0.0
    for u in corpus.utterances:
        for p in u.phones:
            if p.phone == "sil":
                continue
            speech += p.end_s - p.start_s
            inside += sum(max(0.0, min(p.end_s, w.end_s) - max(p.start_s, w.start_s))
                          for w in u.words)
    assert inside / speech > (0.9 if spk == "s1" else 1 - 1e-6)


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
    assert info["refused"] == len(rows) and info["utterances"] == KEPT[spk]
    assert len(rows) == 0 and not refused.exists() and "there is no `refused.csv`" in text
    assert info["admitted_by"] == {u: "source word times" for u in info["admitted_by"]}
    assert len(info["admitted_by"]) == KEPT[spk] and "source word times" in info["admission_rules"]
    assert "admitted by the rule `source word times`" in text
    for r in rows:  # every refused clip is named in the notice with its reason
        assert f"`{r['clip']}`: {' '.join(r['reason'].split())}" in text
    ids = [u.utt_id for u in load_corpus(root).utterances]
    assert not set(ids) & {r["clip"] for r in rows}


def test_the_shipped_corpora_stay_small():
    for spk, limit_mb in (("s26", 2), ("s31", 2)):
        size = sum(p.stat().st_size for p in (REAL / f"grid-{spk}").rglob("*") if p.is_file())
        assert size < limit_mb * 2**20, (spk, size)
        assert not list((REAL / f"grid-{spk}").glob("audio/*.wav"))  # FLAC, as grid-s1


def test_the_development_speaker_loads_with_all_ten_sentences():
    corpus = load_corpus(REAL / "grid-s26")
    assert len(corpus) == 10
    assert [u.utt_id for u in corpus.utterances] == [
        "bgbsza", "bwaq8s", "lbbo3n", "lrbi7p", "lwajza", "lwwx5p", "pbbg5p", "pwabza", "srizza",
        "swbm3n"]


@pytest.mark.parametrize("spk", ["s26", "s31"])
def test_each_phone_of_the_unseen_speakers_lies_inside_one_of_its_words(spk):
    """Aligned within GRID's word times: every phone but silence lies inside one word's interval
    (up to the phones' 0.1 ms rounding), and every word holds at least one phone."""
    for u in load_corpus(REAL / f"grid-{spk}").utterances:
        for p in u.phones:
            if p.phone != "sil":
                assert any(w.start_s - 1e-4 <= p.start_s and p.end_s <= w.end_s + 1e-4
                           for w in u.words), (u.utt_id, p)
        for w in u.words:
            assert any(p.phone != "sil" and w.start_s - 1e-4 <= p.start_s < w.end_s
                       for p in u.phones), (u.utt_id, w)
