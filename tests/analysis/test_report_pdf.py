"""The report builder writes real, searchable text; figures are files it embeds."""
import numpy as np
from pypdf import PdfReader

from analysis import figures
from analysis.report import Report


def test_tables_are_real_text(tmp_path):
    fig = figures.variance_curves({"neutral": np.linspace(0.5, 1, 10)}, {"neutral": 7},
                                  {"neutral": 0.9756}, tmp_path / "v.png")
    rep = Report("A title")
    rep.heading("Section")
    rep.table("TABLE X. Numbers", ["name", "value"], [["alpha", "12.34 %"], ["beta", 5]])
    rep.figure(fig, "a caption")
    out = rep.build(tmp_path / "r.pdf")
    text = "\n".join(p.extract_text() for p in PdfReader(out).pages)
    for s in ("A title", "TABLE X. Numbers", "alpha", "12.34 %", "beta", "a caption"):
        assert s in text
    assert len(PdfReader(out).pages[0].images) == 1


def test_same_content_gives_the_same_pdf(tmp_path):
    def build(name):
        rep = Report("T")
        rep.table("c", ["a"], [["1"]])
        return (rep.build(tmp_path / name)).read_bytes()

    assert build("a.pdf") == build("b.pdf")
