"""The real faces' section and its first-page finding: the default first, the candidates, then
the peers; the seen speaker marked; every figure of the finding a cell of the test table, on the
page it cites."""
from __future__ import annotations

from analysis.real_faces_report import (best_peer, ordered_models, real_faces_finding,
                                        real_faces_section, speakers_tested)
from analysis.report import Report
from tests.analysis.findings_check import findings_of, mismatches, page_texts

DEFAULT = "voices-fitted"


def _row(model, part, speaker, r, closed, *, rate="native", seen=False):
    return {"model": model, "part": part, "speaker": speaker, "rate": rate,
            "seen": str(seen), "r_speech": str(r), "chance_r_speech": "0.01",
            "closure_rate": str(closed), "chance_closure_rate": "0.40",
            "real_closed_rate": "1.0"}


def _rows():
    out = []
    figures = {DEFAULT: (0.61, 0.8, 0.65), "voices-real": (0.58, 0.7, 0.81),
               "loudness": (0.45, 0.3, 0.47), "pylipsync": (0.52, 0.9, 0.44),
               "openfacefx-text": (0.40, 0.8, 0.41), "openfacefx-energy": (0.39, 0.2, 0.42)}
    for m, (r31, closed, r1) in figures.items():
        for rate in ("native", "16000", "8000"):
            out.append(_row(m, "test", "grid-s31", r31, closed, rate=rate))
            out.append(_row(m, "test", "grid-s1", r1, closed, rate=rate,
                            seen=m == "voices-real"))
            out.append(_row(m, "dev", "grid-s26", r31 - 0.05, closed, rate=rate))
    return out


SUMMARY = {"default": DEFAULT, "parts": {"dev": {"clips": {"grid-s26": 10}},
                                         "test": {"clips": {"grid-s31": 10, "grid-s1": 39}}}}


def test_order_of_speakers_and_models_and_the_best_peer():
    rows = _rows()
    assert speakers_tested(rows) == ["grid-s31", "grid-s1"]  # the unseen speaker first
    assert ordered_models(rows, DEFAULT) == [DEFAULT, "voices-real", "loudness",
                                             "openfacefx-text", "openfacefx-energy",
                                             "pylipsync"]
    assert best_peer(rows, "grid-s31") == "pylipsync" and best_peer(rows, "grid-s1") == "loudness"


def test_the_finding_reads_the_test_table_on_the_page_it_cites(tmp_path):
    rows = _rows()
    line = real_faces_finding(rows, SUMMARY)
    assert "on grid-s31 (never seen) r 0.61 (0.01) ahead of the best peer, pylipsync, at " \
           "0.52 (0.01)" in line
    assert "on grid-s1 (never seen) r 0.65 (0.01) ahead of the best peer, loudness envelope, " \
           "at 0.47 (0.01)" in line
    rep = Report("t")
    real_faces_section(rep, rows, SUMMARY)
    rep.findings([line])
    assert rep.uncited() == []
    pdf = rep.build(tmp_path / "r.pdf")
    pages = page_texts(pdf)
    assert len(findings_of(pages[0])) == 1 and mismatches(pdf) == []
    body = " ".join(pages[1:])
    assert "0.81 (0.01)*" in body  # the seen speaker is marked
    assert f"{DEFAULT} (default)" in body and "<b>" not in body  # a cell prints no markup
    assert "Lips of the development speaker" in body


def test_a_default_behind_a_peer_says_so():
    rows = [r if r["model"] != "pylipsync" or r["speaker"] != "grid-s31" else
            {**r, "r_speech": "0.70"} for r in _rows()]
    assert "grid-s31 (never seen) r 0.61 (0.01) <b>behind</b> the best peer, pylipsync, at " \
           "0.70 (0.01)" in real_faces_finding(rows, SUMMARY)
