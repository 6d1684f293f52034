"""The GRID parts of the real-speech set (s1 and s31 test, s26 development): its shipped files
are what the tool makes, its items load as 16 kHz audio (from the built-in corpora's 22,050 Hz
FLAC) with labels covering it, its labels keep GRID's word boundaries, and only labels made
without a recogniser count as independent."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

from analysis.speech_set import (ALIGNED, FSDD_WORDS, GRID_WORDS, INDEPENDENT_SOURCES, SET_DIR,
                                 load_speech_set, read_manifest)
from face_model.transcripts import read_align
from groundwork.errors import CorpusError

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import grid_speech_labels as tool  # noqa: E402


@pytest.fixture(scope="module")
def built():
    return tool.build()


@pytest.fixture(scope="module")
def grid_items():
    ids = [r["id"] for r in read_manifest() if r["label_source"] == GRID_WORDS]
    return load_speech_set(ids=ids)


def test_the_shipped_grid_files_are_what_the_tool_makes(built):
    assert tool.differences(files=built) == []
    assert len(tool.subset_ids()) == 40 == sum(k.startswith("grid/") and k.endswith(".csv")
                                              for k in built)
    for sub in ("grid-s26", "grid-s31"):
        assert sum(k.startswith(f"{sub}/") and k.endswith(".csv") for k in built) == 10
        assert f"{sub}/NOTICE.md" in built and b"CC BY 4.0" not in built[f"{sub}/NOTICE.md"]
        assert b"Creative Commons Attribution 4.0" in built[f"{sub}/NOTICE.md"]


def test_s26_is_development_and_s31_test_with_their_own_faces_audio(grid_items):
    by = {}
    for it in grid_items:
        by.setdefault(it.speaker, set()).add(it.part)
    assert by == {"grid-s1": {"test"}, "grid-s26": {"dev"}, "grid-s31": {"test"}}
    for it in grid_items:
        assert it.wav.parent.parent.name == it.speaker  # face_model/real_faces/<speaker>/audio
        assert it.id == f"grid_{it.speaker.split('-')[1]}_{it.wav.stem}"


def test_an_extra_file_in_a_new_speakers_folder_is_named(built, tmp_path):
    import shutil
    set_dir = tmp_path / "set"
    shutil.copytree(tool.SET_DIR, set_dir, ignore=shutil.ignore_patterns("fsdd", "*.wav"))
    (set_dir / "grid-s31" / "stray.csv").write_text("x")
    assert tool.differences(set_dir, files=built) == ["grid-s31/stray.csv (not made by the tool)"]


def test_a_missing_word_alignment_is_one_line_naming_it(tmp_path, capsys):
    import shutil
    set_dir = tmp_path / "set"
    shutil.copytree(tool.SET_DIR, set_dir, ignore=shutil.ignore_patterns("fsdd", "*.wav"))
    (set_dir / "grid-s26" / "bgbsza.align").unlink()
    assert tool.main(["--set-dir", str(set_dir), "--check"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "grid-s26/bgbsza.align" in err[0]


def test_a_changed_file_is_named_and_the_check_fails(built, monkeypatch, capsys):
    utt = tool.subset_ids()[3]
    changed = dict(built)
    changed[f"grid/{utt}.csv"] = built[f"grid/{utt}.csv"].replace(b"sil", b"sil ", 1)
    assert tool.differences(files=changed) == [f"grid/{utt}.csv"]
    monkeypatch.setattr(tool, "build", lambda *a, **k: changed)
    assert tool.main(["--check"]) == 1
    assert f"grid/{utt}.csv: differs from what the tool makes" in capsys.readouterr().err


def test_every_grid_item_is_16k_audio_as_long_as_its_labels(grid_items):
    assert len(grid_items) == 60
    for it in grid_items:
        assert it.sr == 16000 and it.audio.ndim == 1
        assert it.phones[0].start_s == 0
        assert abs(it.phones[-1].end_s - it.duration_s) < 1e-3, it.id
        assert it.wav.suffix == ".flac" and it.wav.is_file()
        assert it.transcript == read_align(SET_DIR / it.label_origin).text


def test_the_labels_keep_grids_word_boundaries_with_espeaks_phones(grid_items):
    words = tool.word_phones(w for it in grid_items for w in it.transcript.split())
    assert [p for p, _ in words["l"]] == ["eh", "l"]  # espeak's /l/ without a duration
    for it in grid_items:
        starts = {round(s.start_s, 4): i for i, s in enumerate(it.phones)}
        for start, end, word in read_align(SET_DIR / it.label_origin).words:
            i = starts[round(start, 4)]
            inside = it.phones[i:i + len(words[word])]
            assert [s.phone for s in inside] == [p for p, _ in words[word]], (it.id, word)
            assert inside[-1].end_s == pytest.approx(end, abs=1e-4)


def test_only_labels_made_without_a_recogniser_are_independent():
    items = load_speech_set()
    assert INDEPENDENT_SOURCES == {"hts", "textgrid", GRID_WORDS, FSDD_WORDS}
    assert ALIGNED not in INDEPENDENT_SOURCES
    for it in items:
        assert it.independent == (it.label_source in ("hts", "textgrid", GRID_WORDS,
                                                      FSDD_WORDS)), it.id
    assert {it.id for it in items if it.independent
            and it.label_source not in (GRID_WORDS, FSDD_WORDS)} == {"slt_a0009", "praatio_bobby"}
    assert sum(it.label_source == GRID_WORDS for it in items) == 60
    assert {it.speaker for it in items if it.label_source == GRID_WORDS} == {"grid-s1", "grid-s26",
                                                                             "grid-s31"}


def test_a_word_alignment_that_stops_short_of_the_audio_is_refused(tmp_path):
    utt = tool.subset_ids()[0]
    lines = (SET_DIR / "grid" / f"{utt}.align").read_text().splitlines()
    short = tmp_path / f"{utt}.align"
    short.write_text("\n".join(lines[:-1]) + "\n")  # the final silence left out
    with pytest.raises(CorpusError, match=rf"{short.name}: its word alignment ends at "
                       r"1\.\d+ s but the audio lasts 2\.967 s; it must cover the audio"):
        tool.sentence_labels(short, 89 / 30, tool.word_phones(read_align(short).text.split()))


def test_a_label_file_that_stops_short_of_the_flac_is_refused_naming_it(tmp_path):
    row = next(r for r in read_manifest() if r["label_source"] == GRID_WORDS)
    flac = (SET_DIR / row["wav"]).resolve()
    labels = tmp_path / "short.csv"
    labels.write_text("start_s,end_s,phone\n0,1.5,sil\n")
    head = "id,wav,labels,speaker,label_source,label_origin,transcript,licence\n"
    (tmp_path / "manifest.csv").write_text(
        head + f"x,{flac},short.csv,grid-s1,{GRID_WORDS},,bin blue,CC BY 4.0\n")
    with pytest.raises(CorpusError, match=r"short\.csv: the last phone ends at 1\.5000 s but "
                       r"the audio lasts 2\.9667 s"):
        load_speech_set(tmp_path)
