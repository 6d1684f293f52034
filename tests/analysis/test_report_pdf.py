"""The report builder writes real, searchable text; figures are files it embeds."""
import numpy as np
from pypdf import PdfReader

from analysis import figures, stats
from analysis.corpus_report import noise_floor_share
from analysis.mapping_report import mapping_section
from analysis.perception_stats_report import stats_section
from analysis.report import Report, escape
from analysis.study_data import PAPER_TALLIES, trials_from_tallies
from study.design import EMOTION_OF


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
    rng = np.random.default_rng(3)
    n, d, rank, sd = 20000, 158, 5, 0.2
    basis = np.linalg.qr(rng.standard_normal((d, rank)))[0].T
    signal = (rng.standard_normal((n, rank)) * [5, 4, 3, 2, 1]) @ basis
    X = signal + sd * rng.standard_normal((n, d))
    var = np.linalg.svd(X - X.mean(0), compute_uv=False) ** 2 / (n - 1)
    true_share = d * sd**2 / var.sum()
    assert abs(noise_floor_share(var) - true_share) < 0.1 * true_share
    assert noise_floor_share(np.array([3.0, 2.0, 1.0])) == 0.0  # too few axes to tell


def pdf_text(path) -> str:
    """The PDF's text with every run of white space (line breaks included) as one space."""
    return " ".join(" ".join(p.extract_text() for p in PdfReader(path).pages).split())


def _mapping_summary() -> dict:
    """The least of a train stage's summary that :func:`mapping_section` reads."""
    mapping = {"method": "gated_mlp", "cascade_hidden": 5, "expression_model": "cascade",
               "n_mfcc": 10, "deltas": False, "context_back": 2, "context_forward": 2,
               "gate_components": 4, "gate_covariance": "diag", "n_classes": 44,
               "hidden_min": 5, "hidden_max": 20, "min_class_frames": 50,
               "visual_source": "markers"}
    ranking = [{"rank": 1, "method": "gated_mlp", "reference": "Hong, Wen & Huang (2002), §VI",
                "R": 0.9, "MSE": 0.01, "fit_seconds": 1.0}]
    return {"config": {"mapping": mapping}, "rows": [], "gate": {},
            "ranking": {"utterance": ranking}, "trajectories": "none.png"}


def test_an_ampersand_prints_once_in_paragraphs_and_table_cells(tmp_path):
    """Report text is markup everywhere: '&amp;' in a paragraph, a note or a table cell
    prints as '&'; the method ranking's reference (a cell) once printed a literal '&amp;'."""
    rep = Report("T")
    rep.paragraph("Paragraph: Hong, Wen " + escape("&") + " Huang.")
    rep.table("c", ["a " + escape("&") + " b"], [[escape("R&D <1>")]], note="Note: x &amp; y.")
    mapping_section(rep, _mapping_summary(), tmp_path, None)
    text = pdf_text(rep.build(tmp_path / "amp.pdf"))
    assert "&amp;" not in text
    for s in ("Paragraph: Hong, Wen & Huang.", "a & b", "R&D <1>", "Note: x & y.",
              "gated_mlp Hong, Wen & Huang (2002), §VI"):
        assert s in text


def _gee_sentence(text: str) -> str:
    return text[text.index("GEE logistic model"):text.index("Visual capture")]


def test_a_gee_that_is_not_estimable_says_why_in_words(tmp_path):
    """Separation in the bimodal cells: the report names the cells in a sentence (it once
    printed a Python list of dicts)."""
    df = trials_from_tallies(PAPER_TALLIES, seed=0)
    bim = df["block"] == "bimodal"
    real, neutral_syn = bim & (df["face"] == "real"), \
        bim & (df["face"] == "synthetic") & (df["expression"] == "neutral")
    df.loc[real, "response"] = df.loc[real, "expression"].map(EMOTION_OF)  # all consistent
    df.loc[neutral_syn, "response"] = "not_sure"  # none consistent
    summary = stats.summary(df, seed=0)
    assert not summary["gee"].estimable
    rep = Report("T")
    stats_section(rep, summary)
    sentence = _gee_sentence(pdf_text(rep.build(tmp_path / "gee.pdf")))
    assert not set("[]{}'") & set(sentence), sentence
    assert "not estimable" in sentence
    assert "all face-consistent in 6 of the 12 face × expression × sequence cells" in sentence
    assert "real face, smile expression, sequence RS" in sentence
    assert ", and none face-consistent in 2 (synthetic face, neutral expression, sequence SR; "\
        "synthetic face, neutral expression, sequence RS)." in sentence


def test_a_table_wider_than_the_page_is_set_smaller_to_fit(tmp_path):
    from analysis.report import _WIDTH, Report

    head = ["setting", "method", "classes", "context", "MFCC", "hidden", "expressions",
            "R (utterance)", "MSE (utterance)", "R (random_frames)", "MSE (random_frames)"]
    rows = [["baseline-gmm-regression", "gmm_regression", "44", "3+1+3", "13 +delta", "15-25",
             "cascade", "0.123", "0.0123", "0.456", "0.0456"]] * 3
    rep = Report("t", "s")
    rep.table("Ablations", head, rows)
    table = rep.story[-1]._content[1]
    assert table.wrap(_WIDTH, 1e4)[0] <= _WIDTH
    rep.table("Narrow", ["a", "b"], [["1", "2"]])
    assert rep.story[-1]._content[1]._cellStyles[0][0].fontsize == 8.5  # untouched
    assert min(c.fontsize for r in table._cellStyles for c in r) >= 7  # legible at 100 %
    pdf = rep.build(tmp_path / "wide.pdf")
    # every cell's text is there, wrapped within its column where it must be
    text = "".join(PdfReader(pdf).pages[0].extract_text().split())
    assert "baseline-gmm-regression" in text and "R(random_frames)" in text
    assert not list(tmp_path.glob(".*"))  # no temporary file left beside it


def _ablation_results(tmp_path, rows):
    """``tmp_path/ablations/results.csv`` of ``rows``, as the ablations stage writes it."""
    import csv

    ab_dir = tmp_path / "ablations"
    ab_dir.mkdir()
    with open(ab_dir / "results.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return ab_dir


def test_the_look_ahead_curve_is_a_table_and_a_figure_titled_look_ahead(tmp_path):
    """The ablation rows of the curve (``lookahead-*``) and the paper's setting beside them, with
    a 0 ms row, from the stage's results.csv and figure."""
    from talkingface.stages.ablations import lookahead_figure

    def row(setting, method, f, align, latency, r, closure):
        return {"setting": setting, "method": method, "n_classes": 44, "context": f"3+1+{f}",
                "n_mfcc": 10, "deltas": False, "hidden": "15-25", "expression_model": "cascade",
                "look_ahead": f, "window_align": align, "latency_ms": latency,
                "utterance_R": r, "utterance_MSE": 0.01, "utterance_LVE": 3.0,
                "utterance_closure": closure, "utterance_gate_acc": 0.5}

    rows = [row("paper", "gated_mlp", 3, "centre", 112.47, 0.675, 0.4),
            row("classes-1", "gated_mlp", 3, "centre", 112.47, 0.6, 0.3),
            row("lookahead-gated-0", "gated_mlp", 0, "right", 0.0, 0.601, 0.25),
            row("lookahead-gated-3", "gated_mlp", 3, "right", 100.0, 0.671, 0.35)]
    ab_dir = _ablation_results(tmp_path, rows)
    lookahead_figure(rows[2:] + rows[:1], ab_dir / "lookahead.png")
    rep = Report("T")
    mapping_section(rep, _mapping_summary(), tmp_path, ab_dir / "results.csv")
    out = rep.build(tmp_path / "la.pdf")
    text = pdf_text(out)
    assert "Accuracy against look-ahead" in text
    assert "lookahead-gated-0 gated_mlp 0 right 0.0 0.601" in text
    assert "paper gated_mlp 3 centre 112.5 0.675" in text
    assert "classes-1 gated_mlp 3 centre" not in text.split("Accuracy against look-ahead")[1]
    assert sum(len(p.images) for p in PdfReader(out).pages) >= 1


WIDE = (0.050, 0.052, 0.048)


def test_the_ablation_table_gives_each_setting_its_interval_and_marks_real_differences(tmp_path):
    """Seed replicates in, the report's ablation table out: mean ± 95 % half-width per setting,
    the difference from the paper's with its paired interval, and the verdict: better for the
    setting the paired test separates from the paper's, no difference for the other."""
    from scipy.stats import t as t_dist

    from analysis.grid_summary import fmt_p
    from analysis.replicates import interval, paired_tests, summarise_replicates
    from talkingface.stages.base import write_csv

    def rep(setting, seed, r):
        return {"setting": setting, "method": "gated_mlp", "n_classes": 44, "context": "3+1+3",
                "n_mfcc": 10, "deltas": False, "hidden": "15-25", "expression_model": "cascade",
                "utterance_R": r, "utterance_MSE": 0.01, "replicate": (seed - 2002) // 1000,
                "seed": seed}

    paper = {2002: 0.670, 3002: 0.680, 4002: 0.675}
    noise = {2002: 0.671, 3002: 0.676, 4002: 0.679}  # differences +.001 -.004 +.004
    reps = ([rep("paper", s, v) for s, v in paper.items()]
            # +0.050, +0.052, +0.048: t = 43.3 on 2 df, p = 5e-4, Holm x 2: still below 5 %
            + [rep("wide-hidden", s, v + d) for (s, v), d in zip(paper.items(), WIDE)]
            + [rep("classes-8", s, v) for s, v in noise.items()])
    rows = summarise_replicates(reps, reference="paper")
    ab_dir = _ablation_results(tmp_path, rows)
    write_csv(ab_dir / "replicates.csv", reps)
    report = Report("T")
    mapping_section(report, _mapping_summary(), tmp_path, ab_dir / "results.csv")
    text = pdf_text(report.build(tmp_path / "ab.pdf"))
    tests = paired_tests({n: {r["seed"]: r["utterance_R"] for r in reps if r["setting"] == n}
                          for n in ("paper", "wide-hidden", "classes-8")}, "paper")
    mean, half = interval(list(paper.values()))
    assert f"paper gated_mlp 3 {mean:.3f} ± {half:.3f} – – – reference" in text
    # Δ's interval is Holm-adjusted: wide-hidden (rank 1 of 2, rejected) at 1 − 0.05/2,
    # classes-8 (rank 2, kept) at 1 − 0.05/1; so the printed interval excludes 0 iff it differs
    for name, values, verdict, level in (
            ("wide-hidden", [v + d for v, d in zip(paper.values(), WIDE)], "better", 0.975),
            ("classes-8", noise.values(), "no difference", 0.95)):
        mean, half = interval(list(values))
        t = tests[name]
        d = np.array(list(values)) - np.array(list(paper.values()))
        holm = t_dist.ppf(0.5 + level / 2, 2) * d.std(ddof=1) / np.sqrt(3)
        assert (abs(t["diff"]) > holm) == (verdict != "no difference")
        assert (f"{name} gated_mlp 3 {mean:.3f} ± {half:.3f} {t['diff']:+.3f} ± "
                f"{holm:.3f} {100 * level:.1f} % {fmt_p(t['p_holm'])} {verdict}") in text, name
    assert "Holm-corrected" in text and "1 of the 2 rows tested here" in text
    assert "higher (lower) than 'paper'" in text
    assert "The best setting is wide-hidden (better than the reference)." in text
    assert report.uncited() == []  # every table of the mapping section is cited in its text


def test_a_table_too_wide_even_in_small_type_wraps_its_widest_column(tmp_path):
    """A column of long text (the ceiling steps' changes) does not push the figures off the
    page: the table is set in the width of the page, that column wraps, every figure prints."""
    from analysis.report import _WIDTH, Report

    changes = "; ".join(f"synth.setting_number_{k}=[0.375, 0.375]" for k in range(12))
    head = ["step", "changes", "R (utterance)", "R (frame split)", "MSE (utterance)",
            "LVE (px)", "/p b m/ closed"]
    rows = [[f"step-{k}", escape(changes + " & more"), "0.675 ± 0.017", "0.700 ± 0.020",
             "0.0183 ± 0.0012", "1.64 ± 0.10", f"0.8{k} ± 0.15"] for k in range(3)]
    rep = Report("t", "s")
    rep.table("Ceiling", head, rows)
    table = rep.story[-1]._content[1]
    assert table.wrap(_WIDTH, 1e4)[0] <= _WIDTH + 1e-6
    pdf = rep.build(tmp_path / "wrapped.pdf")
    text = " ".join(PdfReader(pdf).pages[0].extract_text().split())
    for k in range(3):
        assert f"0.8{k} ± 0.15" in text
    assert "synth.setting_number_11=[0.375, 0.375] & more" in text


def test_every_table_and_figure_is_cited_or_listed_as_uncited(tmp_path):
    """A paragraph may cite a table before it is added (filled in at layout); a table no text
    cites, or one without a key, is listed by ``uncited``; a citation of a missing key is an
    error naming it."""
    import pytest

    rep = Report("T")
    rep.heading("Results", stage="mapping")
    rep.paragraph("{label:b} and {label:fig} come later; see p. {page:b}.")
    rep.table("Cited", ["x"], [["1"]], key="b")
    rep.table("Not cited", ["x"], [["2"]], key="a")
    rep.table("No key", ["x"], [["3"]])
    png = _png(tmp_path / "f.png")
    rep.figure(png, "A figure, cited above.", key="fig")
    text = pdf_text(rep.build(tmp_path / "r.pdf"))
    assert "Table 1 and Figure 1 come later; see p. 1." in text
    assert rep.uncited() == ["Table 2 (a)", "Table 3 (no key)"]
    rep.paragraph("{label:a} is cited now.")
    assert rep.uncited() == ["Table 3 (no key)"]
    rep.paragraph("And {label:nowhere}.")
    with pytest.raises(KeyError, match="'nowhere'"):
        rep.build(tmp_path / "r2.pdf")


def _png(path):
    from PIL import Image

    Image.new("RGB", (40, 20), "white").save(path)
    return path


def test_the_small_runs_report_cites_everything_and_states_what_made_it(small_run_dir, tmp_path):
    """The report of the test suite's small run (tests/conftest.py), built again from a copy:
    every table and figure is cited in the text, the targets are the run config's, the versions
    table lists every package and program (also in report/versions.json), and each number of
    the first page is on the page it cites."""
    import json
    import shutil

    from talkingface.config import load_config
    from talkingface.paths import RunPaths
    from talkingface.stages.report import build_report
    from tests.analysis.findings_check import mismatches
    from tests.talkingface.test_provenance import REQUIRED

    shutil.copytree(small_run_dir / "runs" / "R", tmp_path / "R")
    paths = RunPaths.at(tmp_path / "R", reports_dir=tmp_path / "reports")
    cfg = load_config(paths.root / "config.yaml")
    record = build_report(paths, cfg)
    assert record["uncited"] == []
    assert (paths.report_dir / "uncited.txt").read_text() == ""
    saved = json.loads((paths.report_dir / "versions.json").read_text())
    assert [n for n, _, _ in saved] == [n for n, _, _ in record["versions"]]
    assert set(REQUIRED) <= {n for n, _, _ in saved}
    text = pdf_text(paths.pdf)
    assert "Targets on real data" in text
    for key, value, _ in cfg.targets.rows():
        assert f"{key} {value:g}" in text
    for name, version, _ in saved:
        assert f"{name} {version}" in " ".join(text.split()), name
    assert mismatches(paths.pdf) == []
