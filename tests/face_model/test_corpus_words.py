"""tools/corpus_words.py: GRID's word times added to a corpus made from video without tracking
the faces again — the files it writes are what the import writes, they match the shipped GRID s1
corpus, ``--check`` sees a difference, and an alignment of another sentence writes nothing."""
from __future__ import annotations

import csv
import json
import shutil
import sys
from pathlib import Path

import pytest

from face_model.corpus import load_corpus
from face_model.transcripts import read_align

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tools"))
import corpus_words  # noqa: E402

GRID_ALIGN = REPO / "tests" / "data" / "grid" / "align"
BUILTIN = REPO / "face_model" / "real_faces" / "grid-s1"
CLIPS = ("bbaf3s", "bbbf8p", "lbbk4n", "sbbh2n")  # in the shipped corpus, with an .align here


def _part_without_words(dst: Path) -> Path:
    """The shipped GRID s1 corpus's rows of :data:`CLIPS`, without words/ and its json entry."""
    with open(BUILTIN / "manifest.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    keep = [r for r in rows if r["utt_id"] in CLIPS]
    assert [r["utt_id"] for r in keep] == list(CLIPS)
    for r in keep:
        for column in ("audio", "markers", "phones", "quality"):
            (dst / r[column]).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(BUILTIN / r[column], dst / r[column])
    with open(dst / "manifest.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(keep)
    info = json.loads((BUILTIN / "corpus.json").read_text())
    info.pop("words")
    (dst / "corpus.json").write_text(json.dumps(info, indent=1) + "\n")
    return dst


def test_the_tool_writes_the_shipped_words_files(tmp_path, capsys):
    part = _part_without_words(tmp_path / "part")
    assert all(u.words is None for u in load_corpus(part).utterances)
    assert corpus_words.main([str(part), "--align-dir", str(GRID_ALIGN), "--check"]) == 1
    assert corpus_words.main([str(part), "--align-dir", str(GRID_ALIGN)]) == 0
    for clip in CLIPS:
        assert (part / "words" / f"{clip}.csv").read_bytes() == \
            (BUILTIN / "words" / f"{clip}.csv").read_bytes()
    corpus = load_corpus(part)
    for u in corpus.utterances:
        t = read_align(GRID_ALIGN / f"{u.utt_id}.align")
        assert [w.word for w in u.words] == [w for _, _, w in t.words]
        assert " ".join(w.word for w in u.words) == u.text
    info = json.loads((part / "corpus.json").read_text())
    assert info["words"]["utterances"] == len(CLIPS) and "corpus_words.py" in \
        info["words"]["added_by"]
    assert {k: v for k, v in info.items() if k != "words"} == \
        {k: v for k, v in json.loads((BUILTIN / "corpus.json").read_text()).items()
         if k != "words"}
    capsys.readouterr()
    assert corpus_words.main([str(part), "--align-dir", str(GRID_ALIGN), "--check"]) == 0
    assert "words files match" in capsys.readouterr().out
    # a words file changed by hand is a difference
    path = part / "words" / f"{CLIPS[0]}.csv"
    path.write_text(path.read_text().replace("0.71000", "0.72000"))
    assert corpus_words.main([str(part), "--align-dir", str(GRID_ALIGN), "--check"]) == 1
    assert f"{path}: differs" in capsys.readouterr().out


def test_an_alignment_of_another_sentence_writes_nothing(tmp_path, capsys):
    part = _part_without_words(tmp_path / "part")
    aligns = tmp_path / "align"
    shutil.copytree(GRID_ALIGN, aligns)
    shutil.copy(GRID_ALIGN / "bbbf8p.align", aligns / "sbbh2n.align")  # another sentence
    before = (part / "corpus.json").read_bytes()
    assert corpus_words.main([str(part), "--align-dir", str(aligns)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.startswith(f"error: {aligns / 'sbbh2n.align'}: words 'bin blue by f eight please'")
    assert "for sbbh2n; allowed: the alignment of the utterance's own sentence" in err
    assert not (part / "words").exists() and (part / "corpus.json").read_bytes() == before


def test_the_shipped_grid_s1_words_are_grids_own(tmp_path):
    """Independent of the tool: the shipped files of the clips with an .align here hold that
    .align's times (1/25000 s → s), and every shipped utterance has one."""
    corpus = load_corpus(BUILTIN)
    for clip in CLIPS:
        t = read_align(GRID_ALIGN / f"{clip}.align")
        assert [(w.start_s, w.end_s, w.word) for w in corpus[clip].words] == [
            (pytest.approx(s, abs=5e-6), pytest.approx(e, abs=5e-6), w) for s, e, w in t.words]
    assert all(u.words for u in corpus.utterances)
