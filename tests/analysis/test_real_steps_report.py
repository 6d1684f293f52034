"""The report's "Where the real speaker's R goes" subsection: the real_steps stage's rows as
written (JSON keys as strings), the sentence computed from them, a missing file a sentence."""
from __future__ import annotations

import json

from pypdf import PdfReader

from analysis.real_steps_report import real_steps_section, step_rows, units_sentence
from analysis.report import Report

STEPS = {
    "corpus": "c", "training_sentences": 157, "frames": 13971, "reconstruction_r": 0.947,
    "smoothing_floor": {"3": 0.992, "5": 0.978},
    "offset": {"r": {"-1": 0.512, "0": 0.513, "1": 0.514}, "best": 1},
    "context": {"0": 0.438, "3": 0.513, "15": 0.543},
    "oracle": {"3": 0.537, "6": 0.541}, "oracle_and_audio": 0.566,
    "learning_curve": {"25": 0.47, "50": 0.49, "78": 0.501},
    "learning_projection": {"per_doubling": 0.0194, "sentences": 156, "r": 0.5204},
    "definition": {"paper": 0.36, "markers": 0.348, "pixels": 0.5134},
    "regions": {"lips": {"weight": 0.306, "r": 0.48}, "forehead": {"weight": 0.303, "r": 0.219}},
    "units": [
        {"unit": 0, "variance_share": 0.466, "lips": 0.84, "cheeks": 0.14, "forehead": 0.02,
         "x": 0.07, "r_audio": 0.692},
        {"unit": 1, "variance_share": 0.216, "lips": 0.23, "cheeks": 0.61, "forehead": 0.16,
         "x": 0.68, "r_audio": 0.308},
        {"unit": 2, "variance_share": 0.144, "lips": 0.25, "cheeks": 0.63, "forehead": 0.11,
         "x": 0.28, "r_audio": 0.237}],
}


def _pdf_text(rep, tmp_path) -> str:
    pdf = rep.build(tmp_path / "r.pdf")
    return " ".join(" ".join(p.extract_text() for p in PdfReader(pdf).pages).split())


def test_the_rows_are_the_stages_figures_each_with_its_question():
    rows = {r[0]: r for r in step_rows(STEPS)}
    assert rows["Motion Units"][2] == "0.947" and rows["Landmark jitter"][2] == "0.992"
    assert rows["Probe at the pipeline's context"][2] == "0.513"
    assert rows["Audio–video offset"][2] == "0.514" and "+1" in rows["Audio–video offset"][1]
    assert rows["Wider audio context"][2] == "0.543" and "±15" in rows["Wider audio context"][1]
    assert rows["Oracle phones"][2] == "0.541" and rows["Oracle phones and audio"][2] == "0.566"
    assert rows["More data"][2] == "0.501" and "25: 0.470, 50: 0.490, 78: 0.501 sentences; " \
        "+0.019 per doubling, so 156 sentences would give about 0.520" in rows["More data"][1]
    assert rows["Lips only"][2] == "0.480" and "(31 % of what Eq. 6 weighs)" in \
        rows["Lips only"][1]
    assert rows["Brows and forehead only"][2] == "0.219" and "brows and forehead'" in \
        rows["Brows and forehead only"][1]
    assert rows["Truth: the markers"][2] == "0.348" and rows["Eq. 6 undivided"][2] == "0.513"
    assert all(r[1].strip() for r in rows.values())  # every step says what it asks


def test_the_sentence_is_computed_from_the_units():
    text = units_sentence(STEPS)
    assert "unit 0 best (R 0.692; 47 % of the variance, 84 % of its loading on the lips)" in text
    assert "Units 1, 2, mostly on the cheeks, hold 36 % of the variance and reach at most " \
           "R 0.308" in text
    assert units_sentence({"units": []}) == ""


def test_the_subsection_in_a_pdf_and_a_missing_file(tmp_path):
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "steps.json").write_text(json.dumps(STEPS))
    rep = Report("T")
    real_steps_section(rep, tmp_path / "s")
    text = _pdf_text(rep, tmp_path)
    for s in ("Where the real speaker's R goes", "157 training sentences", "13,971 frames",
              "0.947", "0.992", "0.514", "0.566", "46.6 %", "0.692", "Units 1, 2"):
        assert s in text, s
    rep = Report("T")
    real_steps_section(rep, tmp_path / "nowhere")
    assert "No steps: the stage's steps.json could not be read" in _pdf_text(rep, tmp_path)
