"""Per speaker first (issue 51): the tally of unseen sentence speakers on which the default is at
least pocketsphinx's (seen speakers, digits and the other rate left out), the report's
per-speaker tables at the native rate and at 16 kHz, and page 1's sentence."""
from __future__ import annotations

import csv
from pathlib import Path

import pytest

from analysis import findings
from analysis import speech_report as speech

KEY = "viseme_acc_stream_100ms"
PS = "pocketsphinx-5.1.1 allphone"
DEFAULT = "voices-x"
COLUMNS = ("model", "speaker", "seen", "kind", "input_rate", "files", "seconds", "frames",
           "viseme_acc", "chance_viseme_acc", KEY, "bilabial_closed_frac",
           "chance_bilabial_closed_frac", "r_reference", "chance_r_reference",
           "bilabial_segments")


def _write(folder: Path, rows: list[tuple]) -> Path:
    """``rows``: (model, speaker, seen, kind, rate, stream figure)."""
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "per_speaker.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, COLUMNS)
        w.writeheader()
        for model, spk, seen, kind, rate, v in rows:
            w.writerow({"model": model, "speaker": spk, "seen": seen, "kind": kind,
                        "input_rate": rate, "files": 2, "seconds": 3.0, "frames": 90,
                        "viseme_acc": v, "chance_viseme_acc": 0.2, KEY: v,
                        "bilabial_closed_frac": 0.5, "chance_bilabial_closed_frac": 0.4,
                        "r_reference": 0.3, "chance_r_reference": 0.0, "bilabial_segments": 2})
    return folder


@pytest.fixture
def speech_dir(tmp_path):
    return _write(tmp_path / "speech_eval", [
        (model, spk, seen, kind, rate, v)
        for spk, seen, kind, rate, mine, ps in (
            ("a", False, "sentences", "native", 0.70, 0.60),
            ("b", False, "sentences", "native", 0.50, 0.70),
            ("c", False, "sentences", "native", 0.65, 0.65),
            ("s", True, "sentences", "native", 0.90, 0.10),
            ("d", False, "digits", "native", 0.90, 0.10),
            ("a", False, "sentences", "16000", 0.10, 0.60),
            ("b", False, "sentences", "16000", 0.80, 0.70))
        for model, v in ((DEFAULT, mine), (PS, ps))
    ])


def test_the_tally_counts_unseen_sentence_speakers_with_ties_as_at_least(speech_dir):
    t = speech.speaker_tally(speech_dir, DEFAULT, KEY)
    assert t == {"better": ["a", "c"], "speakers": ["a", "b", "c"], "pocketsphinx": PS}
    assert speech.tally_text(t, "unseen sentence speakers") == (
        "at least pocketsphinx's on 2 of 3 unseen sentence speakers (a, c)")
    t16 = speech.speaker_tally(speech_dir, DEFAULT, KEY, input_rate="16000")
    assert t16["better"] == ["b"] and t16["speakers"] == ["a", "b"]
    assert speech.speaker_tally(speech_dir, DEFAULT, KEY, kind="digits")["better"] == ["d"]


def test_no_pocketsphinx_no_tally(tmp_path):
    d = _write(tmp_path / "s", [(DEFAULT, "a", False, "sentences", "native", 0.7)])
    assert speech.speaker_tally(d, DEFAULT, KEY) is None
    assert speech.tally_text(None, "x") == ""


class _Rep:
    def __init__(self):
        self.paragraphs, self.tables = [], []

    def paragraph(self, text):
        self.paragraphs.append(text)

    def table(self, title, header, body, note="", key=""):
        self.tables.append((title, header, body, key))


def test_the_report_has_a_per_speaker_table_per_rate_sentences_first(speech_dir):
    rep = _Rep()
    speech._per_speaker(rep, speech_dir, DEFAULT)
    assert [t[3] for t in rep.tables] == ["speech_per_speaker", "speech_per_speaker_16000"]
    native = rep.tables[0]
    assert [row[0] for row in native[2]] == ["a", "b", "c", "s", "d"]
    assert [row[1] for row in native[2]] == ["sentences"] * 4 + ["digits"]
    assert native[1][-1] == "pocketsphinx-5.1.1 stream 100ms"
    assert "at least pocketsphinx's on 2 of 3 unseen sentence speakers (a, c)" in \
        rep.paragraphs[0]
    assert "on 1 of 2 unseen sentence speakers (b)" in rep.paragraphs[1]


def test_page_one_states_the_tally(speech_dir):
    with open(speech_dir / "results.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, ["model", "split", "input_rate", "files", "speakers", KEY,
                               "bilabial_closed_frac"])
        w.writeheader()
        w.writerow({"model": DEFAULT, "split": "unseen-test", "input_rate": "native",
                    "files": 8, "speakers": 4, KEY: 0.6, "bilabial_closed_frac": 0.5})
    text = findings.speech_finding(speech_dir, "x")
    assert "per speaker, streaming it is at least pocketsphinx's on 2 of 3 unseen sentence " \
           "speakers (a, c)" in text
