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


def test_noise_floor_share_recovers_white_noise():
    """Low-rank signal + white noise of known variance: the estimated share matches the truth."""
    from analysis.foundation import noise_floor_share

    rng = np.random.default_rng(3)
    n, d, rank, sd = 20000, 158, 5, 0.2
    basis = np.linalg.qr(rng.standard_normal((d, rank)))[0].T
    signal = (rng.standard_normal((n, rank)) * [5, 4, 3, 2, 1]) @ basis
    X = signal + sd * rng.standard_normal((n, d))
    var = np.linalg.svd(X - X.mean(0), compute_uv=False) ** 2 / (n - 1)
    true_share = d * sd**2 / var.sum()
    assert abs(noise_floor_share(var) - true_share) < 0.1 * true_share
    assert noise_floor_share(np.array([3.0, 2.0, 1.0])) == 0.0  # too few axes to tell
