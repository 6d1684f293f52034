"""Transcript readers: GRID .align files (real ones from tests/data/grid), one-line .txt files
and clip,text tables; every malformed file is refused with one line naming the file, the line
and what is allowed; find_transcript looks where GRID and users keep them."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from face_model.transcripts import (Transcript, find_transcript, read_align, read_transcript,
                                    read_transcript_csv, read_txt)
from groundwork.errors import CorpusError

GRID = Path(__file__).resolve().parents[1] / "data" / "grid"
FORMAT = "'start end word' with times in 1/25000 s"


def test_a_grid_align_file_gives_its_words_their_times_and_its_text():
    t = read_align(GRID / "align" / "bbaf3s.align")  # CRLF line ends, as GRID ships them
    assert (GRID / "align" / "bbaf3s.align").read_bytes().count(b"\r\n") == 8
    assert t.text == "bin blue at f three soon"
    assert t.words == ((0.71, 0.9, "bin"), (0.9, 1.08, "blue"), (1.08, 1.12, "at"),
                       (1.12, 1.24, "f"), (1.24, 1.45, "three"), (1.45, 1.87, "soon"))
    assert t.end_s == pytest.approx(2.98)  # the closing sil: 74500 / 25000
    assert t.source == str(GRID / "align" / "bbaf3s.align")


def test_every_shipped_grid_file_reads():
    files = sorted((GRID / "align").glob("*.align"))
    assert len(files) >= 3
    for f in files:
        t = read_align(f)
        assert len(t.text.split()) == 6 and "sil" not in t.text.split()
        starts = [s for s, _, _ in t.words]
        assert starts == sorted(starts) and all(e > s for s, e, _ in t.words)


def test_sp_is_silence_and_gaps_between_words_are_allowed(tmp_path):
    f = tmp_path / "x.align"
    f.write_text("0 1000 sil\n1000 5000 bin\n5000 6000 sp\n7000 9000 blue\n")
    t = read_align(f)
    assert t.text == "bin blue"
    assert t.words == ((0.04, 0.2, "bin"), (0.28, 0.36, "blue"))
    assert t.end_s == pytest.approx(0.36)


@pytest.mark.parametrize("text, message", [
    ("", "{f}: no lines; a transcript needs the words spoken, one " + FORMAT + " per line"),
    ("\n  \n", "{f}: no lines; a transcript needs the words spoken, one " + FORMAT + " per line"),
    ("0 1000 sil\n1000 2000 sp\n",
     "{f}: only silence (sil, sp); a transcript needs the words spoken, one " + FORMAT
     + " per line"),
    ("0 1000 sil\n1000 bin\n", "{f}, line 2: '1000 bin' has 2 fields; each line is " + FORMAT),
    ("0 1000 sil\n1000 2000 bin blue\n",
     "{f}, line 2: '1000 2000 bin blue' has 4 fields; each line is " + FORMAT),
    ("0 1000 sil\n1000 2x00 bin\n",
     "{f}, line 2: end time '2x00' is not a number of 0 or more; each line is " + FORMAT),
    ("zero 1000 sil\n", "{f}, line 1: start time 'zero' is not a number of 0 or more; each line "
                        "is " + FORMAT),
    ("-5 1000 bin\n", "{f}, line 1: start time '-5' is not a number of 0 or more; each line is "
                      + FORMAT),
    ("0 nan bin\n", "{f}, line 1: end time 'nan' is not a number of 0 or more; each line is "
                    + FORMAT),
    ("0 1000 sil\n3000 2000 bin\n",
     "{f}, line 2: end 2000 is not after start 3000; a word must end after it starts"),
    ("0 1000 sil\n1000 1000 bin\n",
     "{f}, line 2: end 1000 is not after start 1000; a word must end after it starts"),
    ("0 1000 sil\n1000 5000 bin\n4000 6000 blue\n",
     "{f}, line 3: start 4000 is before the end of the previous line (5000); times must "
     "increase line by line"),
])
def test_a_malformed_align_file_is_refused_by_line(tmp_path, text, message):
    f = tmp_path / "clip.align"
    f.write_text(text)
    with pytest.raises(CorpusError) as err:
        read_align(f)
    assert str(err.value) == message.format(f=f)


def test_an_align_file_that_is_not_text_is_refused(tmp_path):
    f = tmp_path / "clip.align"
    f.write_bytes(b"0 1000 \xff\xfe\n")
    with pytest.raises(CorpusError) as err:
        read_align(f)
    assert str(err.value) == f"{f}: not UTF-8 text (byte 7); a transcript is a UTF-8 text file"
    with pytest.raises(CorpusError) as err:
        read_align(tmp_path / "missing.align")
    assert str(err.value) == f"{tmp_path / 'missing.align'}: transcript file not found"


def test_a_txt_file_gives_its_one_line(tmp_path):
    f = tmp_path / "clip.txt"
    f.write_text("\n  Bin  blue at F two now.  \n\n")
    assert read_txt(f) == Transcript("Bin blue at F two now.", str(f))
    assert read_transcript(f) == read_txt(f)
    assert read_transcript(f).words == () and read_transcript(f).end_s is None


@pytest.mark.parametrize("text, message", [
    ("", "{f}: empty; a transcript file holds one line of text, the words spoken"),
    (" \n\t\n", "{f}: empty; a transcript file holds one line of text, the words spoken"),
    ("bin blue\n\nat f two now\n",
     "{f}, line 3: a second line of text; a transcript file holds one line, the words spoken"),
])
def test_a_malformed_txt_file_is_refused(tmp_path, text, message):
    f = tmp_path / "clip.txt"
    f.write_text(text)
    with pytest.raises(CorpusError) as err:
        read_txt(f)
    assert str(err.value) == message.format(f=f)


def test_another_extension_is_refused(tmp_path):
    f = tmp_path / "clip.lab"
    f.write_text("bin")
    with pytest.raises(CorpusError) as err:
        read_transcript(f)
    assert str(err.value) == (f"{f}: transcript extension '.lab'; allowed: .align (GRID word "
                              f"alignment) or .txt (one line of text)")


def test_a_csv_table_maps_clips_to_their_text(tmp_path):
    f = tmp_path / "t.csv"
    f.write_text('speaker,clip,text\ns1,bbaf3s,bin blue at f three soon\n\n'
                 's1,x1,"hello,  world"\n')
    assert read_transcript_csv(f) == {"bbaf3s": "bin blue at f three soon",
                                      "x1": "hello, world"}


@pytest.mark.parametrize("text, message", [
    ("", "{f}: empty; a transcript table is a CSV with columns clip,text, one row per clip"),
    ("clip,words\na,b\n",
     "{f}, line 1: header 'clip,words' lacks text; required columns: clip,text"),
    ("clip,text\n", "{f}: no rows; a transcript table has one row per clip under the header "
                    "clip,text"),
    ("clip,text\na,bin blue\nb,bin, blue\n",
     '{f}, line 3: 3 fields, the header has 2; quote a text holding commas ("a, b")'),
    ("clip,text\na,bin blue\n,bin\n",
     "{f}, line 3: empty clip; every row names a clip and the words spoken"),
    ("clip,text\na,  \n", "{f}, line 2: empty text; every row names a clip and the words spoken"),
    ("clip,text\na,bin\nb,blue\na,at\n",
     "{f}, line 4: clip 'a' is listed twice; one row per clip"),
])
def test_a_malformed_csv_table_is_refused_by_line(tmp_path, text, message):
    f = tmp_path / "t.csv"
    f.write_text(text)
    with pytest.raises(CorpusError) as err:
        read_transcript_csv(f)
    assert str(err.value) == message.format(f=f)


@pytest.fixture
def grid_copy(tmp_path):
    """GRID's layout: grid/video/<id>.mpg beside grid/align/<id>.align."""
    (tmp_path / "grid" / "video").mkdir(parents=True)
    shutil.copytree(GRID / "align", tmp_path / "grid" / "align")
    for clip in ("bbaf3s", "lwbl7s", "other"):
        (tmp_path / "grid" / "video" / f"{clip}.mpg").write_bytes(b"")
    return tmp_path / "grid"


def test_find_transcript_in_grids_layout_beside_the_video_in_a_folder_or_a_table(grid_copy,
                                                                                 tmp_path):
    video = grid_copy / "video" / "bbaf3s.mpg"
    t = find_transcript(video)
    assert t.text == "bin blue at f three soon" and len(t.words) == 6
    assert t.source == str(grid_copy / "align" / "bbaf3s.align")
    assert find_transcript(grid_copy / "video" / "other.mpg") is None
    # beside the video: preferred to the align/ folder; .align before .txt
    (grid_copy / "video" / "bbaf3s.txt").write_text("bin blue at f three soon\n")
    assert find_transcript(video).source == str(grid_copy / "video" / "bbaf3s.txt")
    (grid_copy / "video" / "bbaf3s.align").write_text("0 2500 bin\n")
    assert find_transcript(video).text == "bin"
    # a table, and a folder given, come before the files found by the video
    table = {"bbaf3s": "lay  white", "x": "y"}
    assert find_transcript(video, csv_map=table) == Transcript("lay white",
                                                               "transcript table, clip bbaf3s")
    csv_file = tmp_path / "t.csv"
    csv_file.write_text("clip,text\nother,set red\n")
    assert find_transcript(grid_copy / "video" / "other.mpg", csv_map=csv_file) == Transcript(
        "set red", f"{csv_file}, clip other")
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "bbaf3s.txt").write_text("place green\n")
    assert find_transcript(video, transcripts_dir=folder, csv_map=table).text == "place green"
    assert find_transcript(grid_copy / "video" / "lwbl7s.mpg", transcripts_dir=folder,
                           csv_map=table).text == "lay white by l seven soon"


def test_find_transcript_refuses_a_malformed_file_it_finds(grid_copy):
    bad = grid_copy / "align" / "lwbl7s.align"
    bad.write_text("0 1000 sil\n1000 oops lay\n")
    with pytest.raises(CorpusError) as err:
        find_transcript(grid_copy / "video" / "lwbl7s.mpg")
    assert str(err.value) == (f"{bad}, line 2: end time 'oops' is not a number of 0 or more; "
                              f"each line is {FORMAT}")


def test_a_transcript_running_past_the_audio_is_refused():
    t = read_align(GRID / "align" / "bbaf3s.align")  # ends at 2.98 s
    t.check_duration(2.978)  # the clip's audio: 47648 samples at 16 kHz
    t.check_duration(2.89)  # up to 0.1 s short is allowed
    with pytest.raises(CorpusError) as err:
        t.check_duration(2.5, source="bbaf3s.mpg")
    assert str(err.value) == (f"bbaf3s.mpg: the transcript {t.source} ends at 2.980 s but the "
                              f"audio lasts 2.500 s (allowed: up to 0.1 s after its end); it "
                              f"does not match the audio")
    with pytest.raises(CorpusError) as err:
        t.check_duration(1.0)
    assert str(err.value).startswith(f"{t.source}: the transcript ends at 2.980 s but the audio "
                                     f"lasts 1.000 s")
    Transcript("bin blue", "x.txt").check_duration(0.1)  # no times: nothing to check
