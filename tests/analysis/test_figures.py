"""Every report figure is legible at the size the report prints it, and draws what it claims.

The report draws a PNG at ``width`` × the 17 cm text width (:meth:`analysis.report.Report.figure`),
so a text of ``s`` pt in a PNG ``w`` inches wide prints at ``s × width × 17 cm / w``. The widths
below are those the report sections pass for each figure.
"""
from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from matplotlib.collections import PathCollection
from matplotlib.colors import to_rgb
from matplotlib.container import ErrorbarContainer
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.text import Text
from PIL import Image
from statsmodels.stats.proportion import proportion_confint

from analysis import figures
from analysis.figures import IllegibleFigureError, report_figure, save
from analysis.perception_report import tally_figure
from analysis.perception_stats_report import fit_figure
from analysis.speech_eval import opening_figure
from analysis.study_data import FACE_CODE, PAPER_TALLIES, Tally
from face_model.layout import default_layout
from face_model.phones import PHONES
from face_model.render import face_grid
from study.design import AUDIO, EXPRESSIONS, FACES, RESPONSES
from talkingface.stages.ablations import lookahead_figure
from talkingface.stages.ceiling import PAPER_TEST_R, ceiling_figure

TEXT_WIDTH_IN = 17 / 2.54
LONG_SENTENCE = ("He turned sharply, and faced Gregson across the table, and then he said "
                 "nothing more for a long while.")  # a title wider than the page: wrapped
LONG_TITLE = f"gated_mlp_utterance on slt_a0009 (arctic-slt, unseen): \"{LONG_SENTENCE}\""
PHONE_SEGMENTS = [(0.0, 0.2, "sil"), *[(0.2 + 0.07 * i, 0.27 + 0.07 * i, p)
                                       for i, p in enumerate(PHONES[:30])], (2.3, 2.5, "sil")]


@pytest.fixture
def saved(monkeypatch):
    """Every figure written during the test as ``(png path, Figure)``, the figure kept whole
    for inspection after it is closed."""
    out = []
    original = Figure.savefig

    def record(self, fname, *args, **kwargs):
        original(self, fname, *args, **kwargs)
        out.append((Path(fname), self))

    monkeypatch.setattr(Figure, "savefig", record)
    return out


def texts(fig) -> list:
    return [t for t in fig.findobj(Text) if t.get_visible() and t.get_text().strip()]


def printed_sizes(png: Path, fig, drawn_width: float) -> list[tuple[float, str]]:
    """(printed size in pt, text) of every text of ``fig`` when ``png`` is drawn at
    ``drawn_width`` × the text width."""
    with Image.open(png) as im:
        width_in = im.size[0] / im.info["dpi"][0]
    scale = drawn_width * TEXT_WIDTH_IN / width_in
    return [(t.get_fontsize() * scale, t.get_text()) for t in texts(fig)]


def tally_tables(counts: dict) -> dict:
    face_cols = tuple((e, FACE_CODE[f]) for e in EXPRESSIONS for f in FACES)
    return {k: Tally(k, k, RESPONSES, tuple(AUDIO) if k == "IV" else face_cols,
                     np.asarray(v)) for k, v in counts.items()}


def _mup_items(rng):
    items = []
    for e in EXPRESSIONS:
        truth = np.cumsum(rng.standard_normal((60, 9)), 0)
        items.append({"title": f"s00_{e}_001 ({e}, utterance split): {LONG_SENTENCE}",
                      "truth": truth,
                      "n_utterance": 7, "estimates": {
                          "gated_mlp": truth + rng.standard_normal(truth.shape),
                          "tdnn": truth + rng.standard_normal(truth.shape)}})
    return items


def _fit_models(rng):
    def face():
        obs = rng.dirichlet(np.ones(4), size=(3, 3))
        return {"observed": {"bimodal": obs.tolist()},
                **{m: {"predicted": {"bimodal": (obs + 0.03 * rng.standard_normal(
                    obs.shape)).tolist()}, "rmsd": 0.03} for m in ("flmp", "wtav")}}
    return {"faces": {"synthetic": face(), "real": face()}}


def _ceiling_rows(ci_utterance, ci_frames):
    steps = ["ours", "tracked", "no-brow-motion", "no-marker-noise", "no-head-motion",
             "fixed-expressions", "all-off", "oracle", "all-off-oracle"]
    return [{"step": s, "utterance_R": 0.62 + 0.03 * i, "random_frames_R": 0.70 + 0.025 * i,
             "utterance_R_ci95": ci_utterance[i], "random_frames_R_ci95": ci_frames[i]}
            for i, s in enumerate(steps)]


def _lookahead_curve():
    curve = []
    for m in ("gated_mlp", "tdnn", "gru"):
        curve += [{"setting": f"lookahead-{m}-{f}", "method": m, "latency_ms": 33.3 * f,
                   "utterance_R": 0.55 + 0.02 * f, "utterance_closure": 0.3 + 0.05 * f,
                   "utterance_R_ci95": 0.01, "utterance_closure_ci95": ""} for f in range(6)]
        curve.append({"setting": "paper", "method": m, "latency_ms": 112.5,
                      "utterance_R": 0.62, "utterance_closure": 0.45})
    return curve


def _faces(n):
    return [np.full((240, 200, 3), 200 + 5 * i, np.uint8) for i in range(n)]


# (figure, the width its report section draws it at, how to draw it into a folder)
FIGURES = {
    "marker layout": (0.85, lambda d, rng: figures.marker_layout(d / "f.png")),
    "phone histogram": (1.0, lambda d, rng: figures.phone_histogram(
        {p: int(10 ** rng.uniform(1, 4)) for p in PHONES}, d / "f.png")),
    "MU variance": (0.75, lambda d, rng: figures.variance_curves(
        {k: np.sort(rng.uniform(0.6, 1.0, 20)) for k in ("neutral", *EXPRESSIONS[1:])},
        {"neutral": 7, **{k: 2 for k in EXPRESSIONS[1:]}},
        {"neutral": 0.9756, **{k: 0.9813 for k in EXPRESSIONS[1:]}}, d / "f.png")),
    "utterance MUs": (1.0, lambda d, rng: figures.motion_unit_arrows(
        default_layout().neutral, [rng.standard_normal((79, 2)) for _ in range(7)],
        [f"utterance MU {i + 1}" for i in range(7)], d / "f.png")),
    "expression MUs": (0.8, lambda d, rng: figures.motion_unit_arrows(
        default_layout().neutral, [rng.standard_normal((79, 2)) for _ in range(6)],
        [f"{k}: {t}" for k in ("smile", "sad") for t in ("mean $m_{k0}$", "MU 1", "MU 2")],
        d / "f.png", ncols=3, width=0.8)),
    "lip trajectories": (1.0, lambda d, rng: figures.lip_trajectories(
        [{"title": f"s00_{e}_000 ({e}): \"{LONG_SENTENCE}\"",
          "t": np.arange(75) / 30, "aperture": 5 + 4 * np.sin(np.arange(75) / 4),
          "phones": PHONE_SEGMENTS} for e in EXPRESSIONS], d / "f.png")),
    "MUP trajectories": (1.0, lambda d, rng: figures.mup_trajectories(
        _mup_items(rng), d / "f.png")),
    "gate confusion": (0.8, lambda d, rng: figures.confusion_matrix(
        rng.integers(0, 30, (44, 44)), list(PHONES), d / "f.png",
        title="Gate confusion, neutral test frames (utterance split)")),
    "tracking curve": (0.7, lambda d, rng: figures.tracking_curve(
        [{"noise_sd": s, "lk_px": 1 + s / 3, "measured_px": 0.8 + s / 4,
          "constrained_px": 0.5 + s / 10} for s in (0, 2, 4, 8, 16)], d / "f.png")),
    "tallies": (1.0, lambda d, rng: tally_figure(tally_tables(PAPER_TALLIES), d / "f.png")),
    "model fit": (0.8, lambda d, rng: fit_figure(_fit_models(rng), d / "f.png")),
    "lip opening": (1.0, lambda d, rng: opening_figure(
        SimpleNamespace(id="1234-5678-0001", tracks={
            "opening": rng.uniform(0, 10, 75), "reference": rng.uniform(0, 10, 75),
            "fps": 30}),
        [SimpleNamespace(start_s=s, end_s=e, phone=p) for s, e, p in PHONE_SEGMENTS],
        d / "f.png", title=LONG_TITLE)),
    "look-ahead": (1.0, lambda d, rng: lookahead_figure(_lookahead_curve(), d / "f.png")),
    "ceiling": (1.0, lambda d, rng: ceiling_figure(
        _ceiling_rows([0.01] * 9, [0.02] * 9), d / "f.png")),
    "keyframes": (0.8, lambda d, rng: face_grid(_faces(8), list("abcdefgh"), d / "f.png",
                                                ncols=4)),
    "Fig. 6": (0.95, lambda d, rng: face_grid(
        _faces(10), [f"{k / 30:.2f} s /ih/" for k in range(10)], d / "f.png", ncols=5)),
    "Fig. 7": (0.7, lambda d, rng: face_grid(_faces(3), ["neutral", "smile", "sad"],
                                             d / "f.png", ncols=3)),
    "stimulus sheet": (0.75, lambda d, rng: face_grid(
        _faces(6), [f"{f} {e}" for e in EXPRESSIONS for f in FACES], d / "f.png", ncols=2)),
}


@pytest.mark.parametrize("name", list(FIGURES))
def test_every_report_figure_prints_its_text_at_7_pt_or_more(name, tmp_path, saved, rng):
    drawn, draw = FIGURES[name]
    draw(tmp_path, rng)
    assert len(saved) == 1
    png, fig = saved[0]
    sizes = printed_sizes(png, fig, drawn)
    assert sizes, "a figure with no text at all"
    too_small = [(round(pt, 2), text) for pt, text in sizes if pt < 7.0]
    assert not too_small
    for _, text in sizes:  # Greek in mathtext, never spelled out
        assert not re.search(r"(?<!\\)\b(nu_d|Upsilon|zeta)|m_k0", text), text


def test_a_figure_drawn_too_large_for_its_place_is_refused(tmp_path):
    """The old way — 10 inches of figure with 8 pt text, shrunk to the 17 cm text width —
    prints below 7 pt (6.5 pt once cropped to its drawing): refused, no file written."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 3))
    ax.set_xlabel("time (s)", fontsize=8)
    with pytest.raises(IllegibleFigureError, match=r"'time \(s\)' at 6\.\d+ pt"):
        save(fig, tmp_path / "big.png", width=1.0)
    assert not (tmp_path / "big.png").exists()


def test_a_text_below_7_pt_is_refused_even_at_the_drawn_size(tmp_path):
    with pytest.raises(IllegibleFigureError, match="below 7.0 pt"):
        with report_figure(tmp_path / "small.png", width=0.5, height_in=2) as fig:
            fig.subplots().set_title("tiny", fontsize=6.5)
    assert not (tmp_path / "small.png").exists()
    with report_figure(tmp_path / "ok.png", width=0.5, height_in=2) as fig:
        fig.subplots().set_title("fine", fontsize=7)
    assert (tmp_path / "ok.png").is_file()


def _whiskers(ax) -> list[tuple[float, float, float]]:
    """(x, bottom, top) of every error bar drawn on ``ax``."""
    out = []
    for c in ax.containers:
        if isinstance(c, ErrorbarContainer) and c.has_yerr:
            for seg in c.lines[2][0].get_segments():
                (x, y0), (_, y1) = seg
                if np.isfinite([x, y0, y1]).all():
                    out.append((float(x), float(min(y0, y1)), float(max(y0, y1))))
    return out


def test_ceiling_points_carry_their_intervals_and_the_axis_shows_them_and_the_paper(
        tmp_path, saved):
    ci_utt = [0.01, 0.02, float("nan"), 0.015, 0.01, 0.01, 0.03, 0.02, 0.01]
    ci_frames = [0.02, "", 0.01, 0.01, 0.01, 0.01, 0.01, 0.01, None]
    rows = _ceiling_rows(ci_utt, ci_frames)
    ceiling_figure(rows, tmp_path / "ceiling.png")
    ax = saved[0][1].axes[0]
    bars = _whiskers(ax)
    expected = [(i + dx, r[f"{s}_R"], float(ci)) for s, dx, cis in
                (("utterance", -0.15, ci_utt), ("random_frames", 0.15, ci_frames))
                for i, (r, ci) in enumerate(zip(rows, cis))
                if ci not in ("", None) and np.isfinite(float(ci))]
    assert len(bars) == len(expected) == 15  # none where the interval is NaN or missing
    for (x, y, ci), (bx, lo, hi) in zip(sorted(expected), sorted(bars)):
        assert bx == pytest.approx(x) and lo == pytest.approx(y - ci)
        assert hi == pytest.approx(y + ci)
    # every step's point is drawn, with or without its interval
    points = np.concatenate([ln.get_xydata() for ln in ax.get_lines()
                             if ln.get_marker() in ("o", "s") and len(ln.get_xydata())])
    assert len(points) == 2 * len(rows)
    lo, hi = ax.get_ylim()
    assert lo > 0.5  # not from 0: the differences between steps stay visible
    assert lo <= min(b[1] for b in bars) and hi >= max(b[2] for b in bars)
    assert lo < PAPER_TEST_R < hi
    assert any(np.allclose(ln.get_ydata(), PAPER_TEST_R) for ln in ax.get_lines())


def test_tally_figure_has_all_five_tables_and_no_whisker_without_responses(tmp_path, saved):
    counts = {k: np.array(v) for k, v in PAPER_TALLIES.items()}
    counts["III"][:, 1] = 0  # nobody judged the real neutral face
    counts["IV"][:, 2] = 0  # nor audio track 3
    tabs = tally_tables(counts)
    tally_figure(tabs, tmp_path / "tallies.png")
    fig = saved[0][1]
    panels = {ax.get_title().split(":")[0]: ax for ax in fig.axes if ax.get_title()}
    assert list(panels) == [f"Table {n}" for n in ("III", "IV", "V", "VI", "VII")]
    for name, t in tabs.items():
        ax = panels[f"Table {name}"]
        n = t.column_totals()
        bars = [r for r in ax.patches if isinstance(r, Rectangle)]
        whiskers = _whiskers(ax)
        for j in range(len(t.columns)):  # the bars of column j sit within 0.4 of x = j
            mine = [b for b in bars if round(b.get_x() + b.get_width() / 2) == j]
            ticks = [w for w in whiskers if round(w[0]) == j]
            if n[j] == 0:  # no responses: nothing drawn at all
                assert mine == [] and ticks == []
                continue
            assert len(mine) == len(ticks) == len(t.rows)
            for k, (b, w) in enumerate(zip(sorted(mine, key=Rectangle.get_x),
                                           sorted(ticks))):
                lo, hi = proportion_confint(t.counts[k, j], n[j], method="wilson")
                assert b.get_height() == pytest.approx(t.counts[k, j] / n[j])
                assert w[1] == pytest.approx(max(lo, 0), abs=1e-12)
                assert w[2] == pytest.approx(hi)
                if t.counts[k, j] == 0:  # proportion 0: the whisker rises from 0
                    assert w[1] == 0 and w[2] > 0


def test_stars_of_a_shared_paper_value_sit_side_by_side(tmp_path, saved):
    """Every expression's paper value is the same "at least 98.13 %" at 2 MUs: the stars are
    set apart by more than their own size, each in its curve's colour."""
    curves = {"neutral": np.linspace(0.6, 0.98, 20), "smile": np.linspace(0.8, 0.9, 20),
              "sad": np.linspace(0.7, 0.8, 20)}
    figures.variance_curves(curves, {"neutral": 7, "smile": 2, "sad": 2},
                            {"neutral": 0.9756, "smile": 0.9813, "sad": 0.9813},
                            tmp_path / "v.png")
    fig = saved[0][1]
    ax = fig.axes[0]
    stars = [c for c in ax.collections if isinstance(c, PathCollection)
             and len(c.get_offsets()) and np.isclose(c.get_offsets()[0][1], 98.13)]
    assert len(stars) == 2
    xy = [ax.transData.transform(c.get_offsets()[0]) for c in stars]
    apart_pt = abs(xy[0][0] - xy[1][0]) * 72 / fig.dpi
    size_pt = max(np.sqrt(c.get_sizes()[0]) for c in stars)  # marker size in points
    assert apart_pt > size_pt
    lines = {ln.get_label(): ln.get_color() for ln in ax.get_lines()}
    assert {tuple(np.round(c.get_facecolor()[0][:3], 3)) for c in stars} == {
        tuple(np.round(to_rgb(lines[k]), 3)) for k in ("smile", "sad")}
    assert ax.get_xlim()[0] < min(x for x, _ in (c.get_offsets()[0] for c in stars))


def test_the_confusion_matrix_names_every_class(tmp_path, saved):
    """44 classes at a printable size: every name once, alternating sides."""
    figures.confusion_matrix(np.eye(44, dtype=int) * 5, list(PHONES), tmp_path / "c.png")
    fig = saved[0][1]
    names = [t.get_text() for t in texts(fig) if t.get_text() in PHONES]
    assert sorted(names) == sorted(list(PHONES) * 2)  # each once along x and once along y
