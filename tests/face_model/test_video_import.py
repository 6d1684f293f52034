"""The import of real video end to end: the shipped GRID clips (tests/data/grid, CC BY 4.0, see
its NOTICE.md) through MediaPipe in the face environment, into a corpus the reader takes, equal
to the built-in real corpus made from the same clips (its phones aside: those were aligned over
the whole sentence, these within GRID's word times), resumable, and trainable; corpus.json
names the rule each clip was admitted by, and a typed transcript that does not match the audio
is refused as before."""
from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import face_model.video_import as video_import
from face_model.corpus import load_corpus
from face_model.forced_align import MAX_SCORE_GAP
from face_model.transcripts import read_align
from face_model.video_corpus import FromVideoSettings
from face_model.video_import import corpus_from_video
from groundwork.errors import CorpusError
from talkingface.cli.main import main

REPO = Path(__file__).resolve().parents[2]
GRID = REPO / "tests" / "data" / "grid"
BUILTIN = REPO / "face_model" / "real_faces" / "grid-s1"
CLIPS = ("bbbf8p", "lbbk4n", "sbbh2n")


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    out = tmp_path_factory.mktemp("import") / "corpus"
    assert main(["corpus", "from-video", str(GRID / "video"), "--out", str(out),
                 "--speaker", "grid-s1"]) == 0
    return out


def test_the_import_makes_a_corpus_the_reader_takes(imported):
    corpus = load_corpus(imported)
    assert [u.utt_id for u in corpus.utterances] == list(CLIPS)
    for u in corpus.utterances:
        assert u.speaker == "grid-s1" and u.expression == "neutral" and u.sample_rate == 22050
        assert abs(len(u.audio) / u.sample_rate - u.n_frames / 30) < 1 / 30
        assert u.quality.shape == (u.n_frames, 2) and np.all(u.quality[:, 0] > 0.5)
        assert u.phones[0].start_s == 0 and u.phones[-1].end_s == pytest.approx(
            len(u.audio) / u.sample_rate, abs=0.011)
    info = json.loads((imported / "corpus.json").read_text())
    assert info["detector"].startswith("mediapipe 0.10.21") and info["refused"] == 1
    assert info["words"]["utterances"] == len(CLIPS)
    assert info["admitted_by"] == {clip: "source word times" for clip in CLIPS}
    assert list(info["admission_rules"]) == ["source word times"]
    assert "no comparison with free phone recognition" in info["admission_rules"][
        "source word times"]
    with open(imported / "refused.csv", newline="") as f:
        (row,) = list(csv.DictReader(f))
    assert row["clip"] == "bbizzn"
    assert "12 of 75 frames without a face (16 %); allowed: at most 10 %" in row["reason"]
    assert not list(imported.parent.glob(".*partial*"))


def test_the_import_keeps_the_align_files_word_times(imported):
    """Each clip with a GRID .align gets words/<clip>.csv: the .align's words, silences left
    out, in seconds, which the reader returns and which join to the manifest's text."""
    corpus = load_corpus(imported)
    for u in corpus.utterances:
        t = read_align(GRID / "align" / f"{u.utt_id}.align")
        assert (imported / "words" / f"{u.utt_id}.csv").is_file()
        assert [(w.start_s, w.end_s, w.word) for w in u.words] == [
            (pytest.approx(s, abs=5e-6), pytest.approx(e, abs=5e-6), w) for s, e, w in t.words]
        assert " ".join(w.word for w in u.words) == u.text
        assert not {w.word for w in u.words} & {"sil", "sp"}
        assert u.words[-1].end_s <= len(u.audio) / u.sample_rate
    # the refused clip (bbizzn) leaves none behind
    assert sorted(p.stem for p in (imported / "words").iterdir()) == list(CLIPS)


def test_a_clip_with_a_text_transcript_only_has_no_words(tmp_path):
    src = tmp_path / "clips"
    src.mkdir()
    shutil.copy(GRID / "video" / "bbbf8p.mpg", src)
    (src / "bbbf8p.txt").write_text(read_align(GRID / "align" / "bbbf8p.align").text + "\n")
    res = corpus_from_video(src, tmp_path / "corpus", settings=FromVideoSettings(
        speaker="grid-s1"), progress=False)
    assert res["utterances"] == 1 and not (tmp_path / "corpus" / "words").exists()
    assert load_corpus(tmp_path / "corpus")["bbbf8p"].words is None
    info = json.loads((tmp_path / "corpus" / "corpus.json").read_text())
    assert "words" not in info and info["admitted_by"] == {"bbbf8p": "acoustic match"}
    assert f"more than {MAX_SCORE_GAP:g} per speech frame below free phone recognition" in info[
        "admission_rules"]["acoustic match"]


def test_a_text_transcript_that_does_not_match_the_audio_is_refused_as_before(tmp_path):
    """The acoustic check is kept for typed transcripts: bbbf8p said with sbbh2n's sentence is
    refused, with the message the import has always given."""
    src = tmp_path / "clips"
    src.mkdir()
    shutil.copy(GRID / "video" / "bbbf8p.mpg", src)
    (src / "bbbf8p.txt").write_text(read_align(GRID / "align" / "sbbh2n.align").text + "\n")
    with pytest.raises(CorpusError, match=(
            r"bbbf8p\.mpg: the transcript 'set blue by h two now' does not match the audio "
            r"\(alignment score -\d+\.\d per speech frame against -\d+\.\d for free phone "
            r"recognition; allowed gap 4\)$")):
        corpus_from_video(src, tmp_path / "corpus", settings=FromVideoSettings(
            speaker="grid-s1"), progress=False)
    assert not (tmp_path / "corpus").exists()


def _frame_labels(phones, n):
    labels = np.array(["sil"] * n, dtype=object)
    for p in phones:
        labels[int(round(p.start_s * 100)):int(round(p.end_s * 100))] = p.phone
    return labels


def test_the_import_reproduces_the_shipped_tracks(imported):
    """Tracks, audio, words and quality as shipped in grid-s1; the phones now lie inside GRID's
    word times, and agree with grid-s1's (aligned over the whole sentence) on most speech."""
    mine, shipped = load_corpus(imported), load_corpus(BUILTIN)
    for clip in CLIPS:
        a, b = mine[clip], shipped[clip]
        assert a.n_frames == b.n_frames and a.text == b.text
        np.testing.assert_allclose(a.markers, b.markers, atol=0.05)  # pixels
        np.testing.assert_allclose(a.audio, b.audio, atol=1 / 32767)
        assert a.words == b.words
        np.testing.assert_allclose(a.quality, b.quality, atol=1e-3)
        assert all(any(w.start_s - 1e-4 <= p.start_s and p.end_s <= w.end_s + 1e-4
                       for w in a.words) for p in a.phones if p.phone != "sil")
        n = int(len(a.audio) / a.sample_rate * 100)
        mine_l, theirs = _frame_labels(a.phones, n), _frame_labels(b.phones, n)
        speech = theirs != "sil"
        assert np.mean(mine_l[speech] == theirs[speech]) > 0.75, clip  # 0.80, 0.92, 0.85


def test_an_interrupted_import_resumes_from_the_landmarks_it_has(tmp_path, monkeypatch):
    out = tmp_path / "corpus"

    def interrupt(*_):
        raise KeyboardInterrupt

    monkeypatch.setattr(video_import, "_write_refusals", interrupt)
    with pytest.raises(KeyboardInterrupt):
        corpus_from_video(GRID / "video", out, settings=FromVideoSettings(speaker="grid-s1"),
                          progress=False)
    assert not out.exists()
    monkeypatch.undo()
    seen = []
    real = video_import.extract_landmarks

    def spy(jobs, **kw):
        replies = real(jobs, **kw)
        seen.extend(r.get("reused", False) for r in replies.values())
        return replies

    monkeypatch.setattr(video_import, "extract_landmarks", spy)
    res = corpus_from_video(GRID / "video", out, settings=FromVideoSettings(speaker="grid-s1"),
                            progress=False)
    assert seen == [True] * 4 and res["utterances"] == 3
    assert [u.utt_id for u in load_corpus(out).utterances] == list(CLIPS)


def test_an_existing_corpus_is_never_overwritten(imported, capsys):
    before = (imported / "manifest.csv").read_bytes()
    assert main(["corpus", "from-video", str(GRID / "video"), "--out", str(imported)]) == 2
    assert "already exists; give a new --out folder" in capsys.readouterr().err
    assert (imported / "manifest.csv").read_bytes() == before


def test_a_corpus_from_video_trains_with_the_same_commands(imported, tmp_path, monkeypatch):
    corpus = tmp_path / "real"
    shutil.copytree(imported, corpus)
    monkeypatch.chdir(tmp_path)
    assert main(["train", "--name", "r", "--corpus", str(corpus), "--set", "mlflow.enabled=false",
                 "--set", "mapping.baselines=[linear]", "--set",
                 "mapping.train.max_epochs=20"]) == 0
    done = json.loads((tmp_path / "runs" / "r" / "mapping" / "done.json").read_text())
    assert done and (tmp_path / "runs" / "r" / "mapping" / "tables.csv").is_file()
