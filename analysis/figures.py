"""Report figures, one function per figure; each takes arrays and writes one PNG.

Every figure is made at the size the report draws it — ``width`` × the text width (17 cm; the
``width`` of :meth:`analysis.report.Report.figure`) — so a font size in points is the printed
size, and :func:`save` refuses a figure whose smallest text would print below
:data:`MIN_TEXT_PT`. Figures are drawn inside :func:`report_figure`, which applies the report's
type sizes (:data:`STYLE`) and saves.

Faces are drawn in image coordinates (y down), so every face plot inverts its y axis. Grids of
rendered faces are drawn by :func:`face_model.render.face_grid`.
"""
from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.text import Text  # noqa: E402

from face_model.layout import default_layout  # noqa: E402
from face_model.phones import PHONES  # noqa: E402
from groundwork.errors import TalkingFaceError  # noqa: E402

TEXT_WIDTH_IN = 17 / 2.54  # the report's text width: A4 less two 2 cm margins
MIN_TEXT_PT = 7.0  # the smallest text a report figure may print
DPI = 200
PAD_IN = 0.03  # white border kept around the drawing when the figure is cropped to it
STYLE = {"font.size": 8, "axes.titlesize": 8.5, "axes.labelsize": 8, "xtick.labelsize": 7.5,
         "ytick.labelsize": 7.5, "legend.fontsize": 7.5, "legend.title_fontsize": 7.5,
         "figure.titlesize": 9, "axes.titlepad": 4.0, "lines.linewidth": 1.2,
         "lines.markersize": 4, "errorbar.capsize": 2, "legend.handlelength": 1.8}

_REGION_COLOURS = {"forehead": "#1f77b4", "cheeks": "#2ca02c", "lips": "#d62728",
                   "glasses": "#9467bd"}


class IllegibleFigureError(TalkingFaceError):
    """A figure's text would print smaller than :data:`MIN_TEXT_PT` in the report."""


def printed_texts(fig) -> list:
    """The visible, non-empty :class:`~matplotlib.text.Text` artists of ``fig``."""
    return [t for t in fig.findobj(Text) if t.get_visible() and t.get_text().strip()]


def saved_width_in(fig) -> float:
    """Width (in) of the PNG :func:`save` writes: the figure cropped to its drawing."""
    fig.canvas.draw()
    return float(fig.get_tightbbox(fig.canvas.get_renderer()).padded(PAD_IN).width)


def save(fig, path, *, width: float = 1.0) -> Path:
    """Write ``fig`` as a PNG at :data:`DPI`, cropped to what is drawn, and close it.

    ``width`` is the fraction of the text width the report draws the PNG at; every text must
    then print at :data:`MIN_TEXT_PT` or more (font size × drawn width / PNG width), else
    :class:`IllegibleFigureError` names the offending texts and no file is written.
    """
    path = Path(path)
    try:
        scale = width * TEXT_WIDTH_IN / saved_width_in(fig)
        small = sorted({(round(t.get_fontsize() * scale, 2), t.get_text())
                        for t in printed_texts(fig)
                        if t.get_fontsize() * scale < MIN_TEXT_PT - 1e-9})
        if small:
            shown = "; ".join(f"{text!r} at {pt} pt" for pt, text in small[:5])
            raise IllegibleFigureError(
                f"{path.name}: {len(small)} text(s) would print below {MIN_TEXT_PT} pt when "
                f"drawn at {width} x the text width: {shown}")
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=DPI, bbox_inches="tight", pad_inches=PAD_IN)
    finally:
        plt.close(fig)
    return path


@contextmanager
def report_figure(path, *, width: float = 1.0, height_in: float = 3.0):
    """An empty figure of ``width`` × the text width by ``height_in`` inches (constrained
    layout, the report's type sizes); on leaving the block it is checked and saved to ``path``
    (:func:`save`), and closed either way."""
    with plt.rc_context(STYLE):
        fig = plt.figure(figsize=(width * TEXT_WIDTH_IN, height_in), layout="constrained")
        try:
            yield fig
        except BaseException:
            plt.close(fig)
            raise
        save(fig, path, width=width)


def phone_labels(ax, phones, *, y: float, dy: float, va: str = "bottom", **kw) -> None:
    """Each non-silent phone's name over the middle of its segment (``phones``: ``(start_s,
    end_s, phone)``), alternately at heights ``y`` and ``y + dy`` (axes fraction) so that
    neighbours do not overlap."""
    k = 0
    for s, e, p in phones:
        if p == "sil":
            continue
        ax.text((s + e) / 2, y + dy * (k % 2), p, ha="center", va=va, fontsize=7.5,
                color="0.25", transform=ax.get_xaxis_transform(), clip_on=False, **kw)
        k += 1


def _face_axes(ax, neutral):
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    pad = 25
    ax.set_xlim(neutral[:, 0].min() - pad, neutral[:, 0].max() + pad)
    ax.set_ylim(neutral[:, 1].max() + pad, neutral[:, 1].min() - pad)  # y down


def _face_aspect(neutral, pad: float = 25) -> float:
    """Height / width of a face panel drawn by :func:`_face_axes`."""
    span = np.ptp(neutral, axis=0) + 2 * pad
    return float(span[1] / span[0])


def marker_layout(path, *, width: float = 0.85) -> Path:
    """Fig. 2 style: (a) the 79 markers by region, (b) the mesh over the skin markers."""
    lay = default_layout()
    with report_figure(path, width=width, height_in=3.4) as fig:
        axes = fig.subplots(1, 2)
        ax = axes[0]
        for region, colour in _REGION_COLOURS.items():
            m = lay.region_mask(region)
            ax.scatter(*lay.neutral[m].T, s=9, c=colour, label=f"{region} ({m.sum()})")
        ax.legend(loc="upper center", ncol=2, bbox_to_anchor=(0.5, 0.0), frameon=False,
                  columnspacing=1.0, handletextpad=0.3)
        ax.set_title("(a) markers")
        _face_axes(ax, lay.neutral)
        ax = axes[1]
        ax.triplot(lay.neutral[:, 0], lay.neutral[:, 1], lay.triangles, lw=0.5, c="0.3")
        ax.scatter(*lay.neutral[76:].T, s=9, c=_REGION_COLOURS["glasses"])
        ax.set_title(f"(b) mesh ({len(lay.triangles)} triangles)")
        _face_axes(ax, lay.neutral)
    return Path(path)


def phone_histogram(counts: dict, path, *, width: float = 1.0) -> Path:
    """Frames per phone class (all 44, in the class-table order)."""
    values = [counts.get(p, 0) for p in PHONES]
    with report_figure(path, width=width, height_in=2.3) as fig:
        ax = fig.subplots()
        ax.bar(range(len(PHONES)), values, color="#4c72b0")
        ax.set_xticks(range(len(PHONES)), PHONES, rotation=90, fontsize=7.5)
        ax.tick_params(axis="x", length=2, pad=1.5)
        ax.set_xlabel("phone class")
        ax.set_ylabel("frames (count)")
        ax.set_yscale("log")
        ax.set_xlim(-0.6, len(PHONES) - 0.4)
        ax.grid(axis="y", alpha=0.3)
    return Path(path)


def _dodge(keys: list, step: float) -> list:
    """An x offset per item so that items with equal ``keys`` sit side by side, centred."""
    out = []
    for i, k in enumerate(keys):
        same = [j for j, q in enumerate(keys) if q == k]
        out.append(step * (same.index(i) - (len(same) - 1) / 2))
    return out


def variance_curves(curves: dict, kept: dict, paper: dict, path, *,
                    width: float = 0.75) -> Path:
    """Cumulative explained variance of D_0 and of each residual R_k, with the paper's values.

    ``curves``: name → cumulative ratios; ``kept``: name → number of MUs kept; ``paper``: name →
    the published fraction at that number (or None). Stars of curves that share the paper's
    value (every expression's is "at least 98.13 %") are set side by side, not on each other.
    """
    names = [n for n in curves if paper.get(n) is not None]
    offsets = dict(zip(names, _dodge([(kept[n], paper[n]) for n in names], 0.35)))
    with report_figure(path, width=width, height_in=2.7) as fig:
        ax = fig.subplots()
        for name, c in curves.items():
            n = min(len(c), 12)
            line, = ax.plot(np.arange(1, n + 1), 100 * np.asarray(c[:n]), marker="o", ms=3,
                            label=name)
            k = kept[name]
            ax.scatter([k], [100 * c[k - 1]], s=50, facecolors="none",
                       edgecolors=line.get_color())
            if name in offsets:
                ax.scatter([k + offsets[name]], [100 * paper[name]], marker="*", s=80,
                           color=line.get_color(), edgecolors="k", linewidths=0.4, zorder=5)
        ax.scatter([], [], marker="*", s=80, color="w", edgecolors="k", label="paper")
        ax.set_xlabel("number of MUs")
        ax.set_ylabel("variance explained (%)")
        ax.margins(y=0.08)  # the stars near the top drawn whole
        ax.grid(alpha=0.3)
        ax.legend()
    return Path(path)


def _arrows(ax, neutral, disp, colour, scale):
    ax.triplot(neutral[:, 0], neutral[:, 1], default_layout().triangles, lw=0.3, c="0.75")
    ax.quiver(neutral[:, 0], neutral[:, 1], disp[:, 0] * scale, disp[:, 1] * scale,
              angles="xy", scale_units="xy", scale=1, color=colour, width=0.006)
    _face_axes(ax, neutral)


def motion_unit_arrows(neutral: np.ndarray, units: list, titles: list, path, *, ncols=4,
                       colour="#d62728", width: float = 1.0) -> Path:
    """Each unit (79, 2) as displacement arrows on the neutral face, all at one common scale
    (the largest arrow 25 px long). Titles may use mathtext (``$m_{k0}$``)."""
    n = len(units)
    nrows = int(np.ceil(n / ncols))
    cell = width * TEXT_WIDTH_IN / ncols
    with report_figure(path, width=width,
                       height_in=nrows * (cell * _face_aspect(neutral) + 0.25)) as fig:
        axes = fig.subplots(nrows, ncols, squeeze=False)
        biggest = max(float(np.linalg.norm(u, axis=1).max()) for u in units) or 1.0
        for ax, u, title in zip(axes.flat, units, titles):
            _arrows(ax, neutral, u, colour, 25.0 / biggest)
            ax.set_title(title, fontsize=8)
        for ax in list(axes.flat)[n:]:
            ax.axis("off")
    return Path(path)


def lip_trajectories(items: list, path, *, width: float = 1.0) -> Path:
    """Inner-lip aperture (px) over time with the phone labels in a strip under it.

    ``items``: dicts with ``title``, ``t`` (s), ``aperture`` (px) and ``phones`` (list of
    ``(start_s, end_s, phone)``).
    """
    with report_figure(path, width=width, height_in=1.95 * len(items)) as fig:
        for sub, it in zip(fig.subfigures(len(items), 1, squeeze=False)[:, 0], items):
            ax, strip = sub.subplots(2, 1, sharex=True, height_ratios=[3.2, 1])
            ax.plot(it["t"], it["aperture"], c="#d62728", lw=1.2, zorder=3)
            ax.set_ylabel("lip aperture (px)")
            ax.set_title(it["title"], loc="left", wrap=True)
            ax.grid(alpha=0.3)
            for a in (ax, strip):
                for s, e, p in it["phones"]:
                    if p == "sil":
                        a.axvspan(s, e, color="0.92", lw=0)
                    else:
                        a.axvline(s, c="0.8", lw=0.5)
            phone_labels(strip, it["phones"], y=0.08, dy=0.45)
            strip.set_yticks([])
            strip.set_xlabel("time (s)")
            ax.set_xlim(it["t"][0], it["t"][-1])
    return Path(path)


def _mup_name(j: int, n_utt: int) -> str:
    return f"$c_0[{j}]$" if j < n_utt else f"$c_k[{j - n_utt}]$"


def mup_trajectories(items: list, path, *, fps: int = 30, n_show: int = 3,
                     width: float = 1.0) -> Path:
    """Predicted vs true MUPs over time: one row per item, the first ``n_show`` utterance MUPs
    and (for an expression) the first expression MUP.

    ``items``: dicts with ``title``, ``truth`` (n_frames, n_mups), ``n_utterance`` (A0) and
    ``estimates`` ({method: (n_frames, n_mups)}).
    """
    styles = ["--", ":", "-."]
    ncols = n_show + 1
    with report_figure(path, width=width, height_in=1.75 * len(items) + 0.3) as fig:
        rows = fig.subfigures(len(items), 1, squeeze=False)[:, 0]
        legend = None
        for sub, it in zip(rows, items):
            sub.suptitle(it["title"], x=0.01, ha="left", fontsize=8, wrap=True)
            axes = sub.subplots(1, ncols)
            truth = np.asarray(it["truth"])
            t = np.arange(len(truth)) / fps
            n_utt = it.get("n_utterance", truth.shape[1])
            cols = list(range(n_show)) + [n_utt]
            for ax, j in zip(axes, cols):
                if j >= truth.shape[1]:
                    ax.axis("off")
                    continue
                ax.plot(t, truth[:, j], c="k", lw=1.2, label="true")
                for (name, est), ls in zip(it["estimates"].items(), styles):
                    ax.plot(t, np.asarray(est)[:, j], ls, lw=1.0, label=name)
                ax.set_title(_mup_name(j, n_utt), fontsize=8)
                ax.grid(alpha=0.3)
                if sub is rows[-1]:
                    ax.set_xlabel("time (s)")
                legend = legend or ax.get_legend_handles_labels()
            axes[0].set_ylabel("MUP (px)")
        if legend:
            fig.legend(*legend, loc="outside lower center", ncol=len(legend[1]))
    return Path(path)


def confusion_matrix(counts: np.ndarray, names: list, path, *, title: str = "",
                     width: float = 0.8) -> Path:
    """Row-normalised confusion of the gate (true class per row, chosen class per column).

    With 44 classes a row is about 7 pt high, so the class names alternate sides: even rows
    (columns) named on the left (bottom), odd ones on the right (top).
    """
    counts = np.asarray(counts, dtype=float)
    rows = counts.sum(1, keepdims=True)
    frac = np.divide(counts, rows, out=np.zeros_like(counts), where=rows > 0)
    n = len(names)
    even, odd = list(range(0, n, 2)), list(range(1, n, 2))
    w = width * TEXT_WIDTH_IN
    with report_figure(path, width=width, height_in=w + 0.45) as fig:
        ax = fig.subplots()
        im = ax.imshow(frac, cmap="Blues", vmin=0, vmax=1)
        ax.set_xticks(even, [names[i] for i in even], rotation=90, fontsize=7.5)
        ax.set_yticks(even, [names[i] for i in even], fontsize=7.5)
        top = ax.secondary_xaxis("top")
        top.set_xticks(odd, [names[i] for i in odd], rotation=90, fontsize=7.5)
        right = ax.secondary_yaxis("right")
        right.set_yticks(odd, [names[i] for i in odd], fontsize=7.5)
        for a in (ax, top, right):
            a.tick_params(length=2, pad=1)
        ax.set_xlabel("class chosen by the gate")
        ax.set_ylabel("true class")
        if title:
            ax.set_title(title, wrap=True)
        fig.colorbar(im, ax=ax, location="bottom", shrink=0.6, aspect=40,
                     label="fraction of the true class's frames")
    return Path(path)


def tracking_curve(rows: list, path, *, width: float = 0.7) -> Path:
    """Tracker error (px) against image noise: raw LK, measurements, MU-constrained."""
    with report_figure(path, width=width, height_in=2.7) as fig:
        ax = fig.subplots()
        x = [r["noise_sd"] for r in rows]
        for key, label, style in (("lk_px", "raw Lucas–Kanade", "o-"),
                                  ("measured_px", r"measurements $\zeta(t)$", "s--"),
                                  ("constrained_px", "MU-constrained (Eq. 5)", "D-")):
            ax.plot(x, [r[key] for r in rows], style, label=label)
        ax.set_xlabel("image noise sd (grey levels)")
        ax.set_ylabel("mean marker error (px)")
        ax.grid(alpha=0.3)
        ax.legend()
    return Path(path)
