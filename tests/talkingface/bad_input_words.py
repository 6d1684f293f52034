"""The bad-input table's part: malformed word-time files (``words/<utt_id>.csv``) of a corpus
made from video.

``CASES`` are ``(argv, names)`` as in :mod:`tests.talkingface.bad_input_cases`;
:func:`add_inputs` makes the folders they name in the suite's working folder: copies of the
first utterance of the shipped GRID s26 corpus (``face_model/real_faces/grid-s26``: audio,
markers, phones, quality and its words file, ~0.2 MB each), each with its words file damaged
one way. Every command that reads a corpus (``units --corpus``, ``train --corpus``, the real
speaker's corpus of ``replicate``, ``evaluate-face`` on a corpus folder) refuses it through the
one reader, in one line naming the file, the line and what is allowed, before anything is
written. A corpus without ``words/`` is valid (tests/face_model/test_corpus.py).
"""
from __future__ import annotations

import csv
import shutil
from pathlib import Path

from tests.talkingface.bad_input_cases import QUICK, RUN, TFMAP

SOURCE = Path(__file__).resolve().parents[2] / "face_model" / "real_faces" / "grid-s26"
UTT = "bgbsza"  # "bin green by s zero again", the corpus's first utterance
WORDS = f"words/{UTT}.csv"
ALLOWED_TEXT = "allowed: the text's words in order, one per line"


def _units(corpus: str) -> list:
    return ["units", "--corpus", corpus, "--out", "u"]


CASES: list = [
    (_units("wd_header"), [f"wd_header/{WORDS}, line 1", "header 'start,end,word'",
                           "allowed: start_s,end_s,word"]),
    (_units("wd_times"), [f"wd_times/{WORDS}, line 2", "times 'soon'",
                          "allowed: numbers of seconds with 0 <= start_s < end_s"]),
    (_units("wd_overlap"), [f"wd_overlap/{WORDS}, line 3", "before the previous word ends",
                            "allowed: words in time order, not overlapping"]),
    (_units("wd_silence"), [f"wd_silence/{WORDS}, line 2", "word 'sil'",
                            "silences (sil, sp) left out"]),
    (_units("wd_fields"), [f"wd_fields/{WORDS}, line 2", "2 fields", "allowed: 3"]),
    (_units("wd_late"), [f"wd_late/{WORDS}, line 7", "word 'again' ends at 9 s, after the audio",
                         "allowed: up to 0.1 s after its end"]),
    (_units("wd_empty"), [f"wd_empty/{WORDS}", "no words under the header"]),
    (_units("wd_text"), [f"wd_text/{WORDS}, line 6", "word 'one'",
                         "'bin green by s zero again' has word 5 'zero'", ALLOWED_TEXT]),
    (["train", "--name", "G", *RUN, "--corpus", "wd_text"],
     ["corpus.source", f"wd_text/{WORDS}, line 6", ALLOWED_TEXT]),
    (["replicate", "--name", "N", *QUICK, "--set", "real_speaker.corpus=wd_short"],
     ["real_speaker.corpus", f"wd_short/{WORDS}", "5 words", ALLOWED_TEXT]),
    (["evaluate-face", "--model", TFMAP, "wd_silence"],
     [f"wd_silence/{WORDS}, line 2", "word 'sil'"]),
]


def _copy(root: Path, name: str) -> Path:
    """The first utterance of :data:`SOURCE` as the corpus folder ``root/name``."""
    dst = root / name
    dst.mkdir()
    shutil.copy(SOURCE / "corpus.json", dst)
    with open(SOURCE / "manifest.csv", newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    row = next(r for r in rows if r["utt_id"] == UTT)
    with open(dst / "manifest.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        w.writerow(row)
    for rel in (row["audio"], row["markers"], row["phones"], row["quality"], WORDS):
        (dst / rel).parent.mkdir(exist_ok=True)
        shutil.copy(SOURCE / rel, dst / rel)
    return dst


def _damage(root: Path, name: str, edit) -> None:
    """A copy whose words file's lines (header first) are replaced by ``edit(lines)``."""
    path = _copy(root, name) / WORDS
    lines = path.read_text(encoding="utf-8").splitlines()
    path.write_text("\n".join(edit(lines)) + "\n", encoding="utf-8")


def _set(i: int, field: int, value: str):
    def edit(lines):
        cells = lines[i].split(",")
        cells[field] = value
        return lines[:i] + [",".join(cells)] + lines[i + 1:]
    return edit


def add_inputs(root: Path) -> None:
    """Make the inputs of :data:`CASES` in ``root``."""
    _damage(root, "wd_header", lambda lines: ["start,end,word", *lines[1:]])
    _damage(root, "wd_times", _set(1, 0, "soon"))
    _damage(root, "wd_overlap", lambda lines: _set(2, 0, lines[1].split(",")[0])(lines))
    _damage(root, "wd_silence", lambda lines: [lines[0], "0.00000,0.10000,sil", *lines[1:]])
    _damage(root, "wd_fields", lambda lines: [lines[0], ",".join(lines[1].split(",")[:2]),
                                              *lines[2:]])
    _damage(root, "wd_late", _set(6, 1, "9.00000"))
    _damage(root, "wd_empty", lambda lines: lines[:1])
    _damage(root, "wd_text", _set(5, 2, "one"))
    _damage(root, "wd_short", lambda lines: lines[:-1])
