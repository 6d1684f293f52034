"""The real-speech set's manifest (issue 37): one speaker-id scheme shared with the built-in real
corpus and the synthetic voices, a development part of speakers absent from the test part whose
labels come from neither recogniser, refusals of an old or broken manifest naming the file, and
audio of any rate loaded at 16 kHz with its native rate kept."""
from __future__ import annotations

import csv
import re

import numpy as np
import pytest
import soundfile as sf

from analysis.speech_set import (ALIGNED, GRID_WORDS, INDEPENDENT_SOURCES, SAMPLE_RATE, SET_DIR,
                                 load_speech_set, read_manifest)
from data_synth.backends import voice_speakers
from face_model.corpus import read_manifest as read_corpus_manifest
from groundwork.errors import CorpusError

REAL_CORPUS = SET_DIR.parents[1] / "face_model" / "real_faces" / "grid-s1" / "manifest.csv"
# lowercase <collection>-<speaker>; ``espeak`` for voices with no real speaker
SCHEME = re.compile(r"^(espeak|(arctic|grid|fsdd|librivox|praatio|pocketsphinx|festvox)"
                    r"-[a-z0-9]+)$")
HEAD = "id,wav,labels,speaker,label_source,label_origin,part,transcript,licence\n"


@pytest.fixture(scope="module")
def rows():
    return read_manifest()


def _write_set(tmp_path, lines, head=HEAD, seconds=0.5, sr=SAMPLE_RATE):
    sf.write(tmp_path / "a.wav", np.zeros(int(seconds * sr)), sr, subtype="PCM_16")
    (tmp_path / "a.csv").write_text(f"start_s,end_s,phone\n0,{seconds:.4f},sil\n")
    (tmp_path / "manifest.csv").write_text(head + "".join(lines))
    return tmp_path


def test_every_speaker_id_follows_the_scheme(rows):
    bad = sorted({r["speaker"] for r in rows if not SCHEME.match(r["speaker"])})
    assert bad == []
    bad_voices = sorted({s for s in voice_speakers().values() if not SCHEME.match(s)})
    assert bad_voices == []
    # the synthetic voices built from ARCTIC speakers carry the ids the set's recordings do
    assert voice_speakers()["flite:slt"] == next(r["speaker"] for r in rows
                                                 if r["id"] == "slt_a0009") == "arctic-slt"


def test_the_grid_rows_carry_the_real_corpus_speaker_id(rows):
    grid = {r["speaker"] for r in rows if r["label_source"] == GRID_WORDS}
    assert grid == {"grid-s1", "grid-s26", "grid-s31"}
    for speaker in grid:  # each row's speaker is the id of the corpus its audio comes from
        root = REAL_CORPUS.parents[1] / speaker / "manifest.csv"
        corpus = {r["speaker"] for r in read_corpus_manifest(root, ("utt_id", "speaker"))}
        assert corpus == {speaker}
        assert all(f"real_faces/{speaker}/audio/" in r["wav"]
                   for r in rows if r["speaker"] == speaker)


def test_the_dev_part_is_independently_labelled_and_its_speakers_are_not_in_test(rows):
    dev = [r for r in rows if r["part"] == "dev"]
    test = [r for r in rows if r["part"] == "test"]
    assert dev and test and len(dev) + len(test) == len(rows)
    assert all(r["label_source"] in INDEPENDENT_SOURCES for r in dev)
    assert {r["speaker"] for r in dev} & {r["speaker"] for r in test} == set()
    assert {r["speaker"] for r in dev} == {"fsdd-jackson", "fsdd-lucas", "grid-s26"}
    # the pocketsphinx test recordings are one (conservative) speaker, reported in test
    ps = {r["part"] for r in rows if r["speaker"] == "pocketsphinx-test"}
    assert ps == {"test"}


def test_an_old_manifest_with_speaker_source_is_refused_naming_the_column(tmp_path):
    head = ("id,wav,labels,speaker,speaker_source,label_source,label_origin,part,transcript,"
            "licence\n")
    d = _write_set(tmp_path, ["a,a.wav,a.csv,arctic_slt,arctic_slt,hts,,test,a,MIT\n"], head)
    with pytest.raises(CorpusError, match=re.escape(str(d / "manifest.csv")) +
                       r": has the old column speaker_source; the speaker id is now the column "
                       r"speaker"):
        read_manifest(d)


def test_a_dev_row_labelled_by_the_aligner_is_refused_naming_the_line(tmp_path):
    d = _write_set(tmp_path, [f"a,a.wav,a.csv,fsdd-theo,{GRID_WORDS},,test,a,MIT\n",
                              f"b,a.wav,a.csv,fsdd-theo,{ALIGNED},,dev,b,MIT\n"])
    with pytest.raises(CorpusError, match=r"manifest\.csv, line 3: dev recording 'b' has labels "
                       r"from 'pocketsphinx-5\.1\.1 forced alignment'"):
        read_manifest(d)
    # the same row in test is allowed
    _write_set(tmp_path, [f"b,a.wav,a.csv,fsdd-theo,{ALIGNED},,test,b,MIT\n"])
    assert read_manifest(d)[0]["part"] == "test"


@pytest.mark.parametrize("speaker", ["arctic_slt", "Grid-s1", "grid", "grid-s1 ", "ps-test-x"])
def test_a_speaker_id_outside_the_scheme_is_refused(tmp_path, speaker):
    d = _write_set(tmp_path, [f'a,a.wav,a.csv,"{speaker}",{GRID_WORDS},,test,a,MIT\n'])
    with pytest.raises(CorpusError, match=rf"line 2: speaker {re.escape(repr(speaker))}; "
                       r"allowed: a lowercase id <collection>-<speaker>"):
        read_manifest(d)


def test_an_8k_file_loads_at_16k_keeping_its_native_rate(tmp_path):
    sr, f0 = 8000, 1000.0
    t = np.arange(int(0.5 * sr)) / sr
    sf.write(tmp_path / "a.wav", 0.5 * np.sin(2 * np.pi * f0 * t), sr, subtype="PCM_16")
    (tmp_path / "a.csv").write_text("start_s,end_s,phone\n0,0.5000,sil\n")
    (tmp_path / "manifest.csv").write_text(HEAD + f"a,a.wav,a.csv,fsdd-theo,{GRID_WORDS},,test,"
                                           "a,MIT\n")
    it = load_speech_set(tmp_path)[0]
    assert (it.native_sr, it.sr, len(it.audio)) == (8000, 16000, 8000)
    # the tone survives the resampling at its own frequency
    spec = np.abs(np.fft.rfft(it.audio))
    assert np.fft.rfftfreq(len(it.audio), 1 / it.sr)[spec.argmax()] == pytest.approx(f0, abs=2)


def test_the_shipped_fsdd_items_load_with_their_native_rate():
    ids = [r["id"] for r in read_manifest() if r["speaker"].startswith("fsdd-")][:3]
    items = load_speech_set(ids=ids)
    assert len(items) == 3
    for it in items:
        assert (it.native_sr, it.sr) == (8000, 16000)
        assert abs(it.phones[-1].end_s - it.duration_s) < 1e-3, it.id
        assert sf.info(it.wav).samplerate == 8000
    slt = load_speech_set(ids=["slt_a0009", "grid_s1_bbaf3s"])
    assert [it.native_sr for it in slt] == [16000, 22050]


def test_the_manifest_columns_name_the_speaker_once():
    with open(SET_DIR / "manifest.csv", newline="", encoding="utf-8") as f:
        header = next(csv.reader(f))
    assert "speaker" in header and "speaker_source" not in header
