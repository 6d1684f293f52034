"""Report figures, one function per figure; each takes arrays and writes one PNG.

Faces are drawn in image coordinates (y down), so every face plot inverts its y axis. Grids of
rendered faces are drawn by :func:`face_model.render.face_grid`.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from face_model.layout import default_layout  # noqa: E402
from face_model.phones import PHONES  # noqa: E402

_REGION_COLOURS = {"forehead": "#1f77b4", "cheeks": "#2ca02c", "lips": "#d62728",
                   "glasses": "#9467bd"}


def _save(fig, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=150, bbox_inches="tight")
    plt.close(fig)
    return path


def _face_axes(ax, neutral):
    ax.set_aspect("equal")
    ax.invert_yaxis()
    ax.set_xticks([])
    ax.set_yticks([])
    pad = 25
    ax.set_xlim(neutral[:, 0].min() - pad, neutral[:, 0].max() + pad)
    ax.set_ylim(neutral[:, 1].max() + pad, neutral[:, 1].min() - pad)


def marker_layout(path) -> Path:
    """Fig. 2 style: (a) the 79 markers by region, (b) the mesh over the skin markers."""
    lay = default_layout()
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.6))
    ax = axes[0]
    for region, colour in _REGION_COLOURS.items():
        m = lay.region_mask(region)
        ax.scatter(*lay.neutral[m].T, s=14, c=colour, label=f"{region} ({m.sum()})")
    ax.legend(loc="lower center", fontsize=7, ncol=2, bbox_to_anchor=(0.5, -0.22))
    ax.set_title("(a) markers")
    _face_axes(ax, lay.neutral)
    ax = axes[1]
    ax.triplot(lay.neutral[:, 0], lay.neutral[:, 1], lay.triangles, lw=0.6, c="0.3")
    ax.scatter(*lay.neutral[76:].T, s=14, c=_REGION_COLOURS["glasses"])
    ax.set_title(f"(b) mesh ({len(lay.triangles)} triangles)")
    _face_axes(ax, lay.neutral)
    return _save(fig, path)


def phone_histogram(counts: dict, path) -> Path:
    """Frames per phone class (all 44, in the class-table order)."""
    values = [counts.get(p, 0) for p in PHONES]
    fig, ax = plt.subplots(figsize=(10, 3.0))
    ax.bar(range(len(PHONES)), values, color="#4c72b0")
    ax.set_xticks(range(len(PHONES)))
    ax.set_xticklabels(PHONES, rotation=90, fontsize=7)
    ax.set_ylabel("frames")
    ax.set_yscale("log")
    ax.set_xlim(-0.6, len(PHONES) - 0.4)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def variance_curves(curves: dict, kept: dict, paper: dict, path) -> Path:
    """Cumulative explained variance of D_0 and of each residual R_k, with the paper's values.

    ``curves``: name → cumulative ratios; ``kept``: name → number of MUs kept; ``paper``: name →
    the published fraction at that number (or None).
    """
    fig, ax = plt.subplots(figsize=(6.5, 3.6))
    for name, c in curves.items():
        n = min(len(c), 12)
        line, = ax.plot(np.arange(1, n + 1), 100 * np.asarray(c[:n]), marker="o", ms=3,
                        label=name)
        k = kept[name]
        ax.scatter([k], [100 * c[k - 1]], s=60, facecolors="none", edgecolors=line.get_color())
        if paper.get(name) is not None:
            ax.scatter([k], [100 * paper[name]], marker="*", s=90, color=line.get_color(),
                       edgecolors="k", linewidths=0.4, zorder=5)
    ax.scatter([], [], marker="*", s=90, color="w", edgecolors="k", label="paper")
    ax.set_xlabel("number of MUs")
    ax.set_ylabel("variance explained (%)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def _arrows(ax, neutral, disp, colour, scale):
    ax.triplot(neutral[:, 0], neutral[:, 1], default_layout().triangles, lw=0.3, c="0.75")
    ax.quiver(neutral[:, 0], neutral[:, 1], disp[:, 0] * scale, disp[:, 1] * scale,
              angles="xy", scale_units="xy", scale=1, color=colour, width=0.006)
    _face_axes(ax, neutral)


def motion_unit_arrows(neutral: np.ndarray, units: list, titles: list, path, *, ncols=4,
                       colour="#d62728") -> Path:
    """Each unit (79, 2) as displacement arrows on the neutral face, all at one common scale
    (the largest arrow 25 px long)."""
    n = len(units)
    nrows = int(np.ceil(n / ncols))
    fig, axes = plt.subplots(nrows, ncols, figsize=(2.6 * ncols, 2.8 * nrows), squeeze=False)
    biggest = max(float(np.linalg.norm(u, axis=1).max()) for u in units) or 1.0
    for ax, u, title in zip(axes.flat, units, titles):
        _arrows(ax, neutral, u, colour, 25.0 / biggest)
        ax.set_title(title, fontsize=9)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    return _save(fig, path)


def lip_trajectories(items: list, path) -> Path:
    """Inner-lip aperture (px) over time with the phone labels under it.

    ``items``: dicts with ``title``, ``t`` (s), ``aperture`` (px) and ``phones`` (list of
    ``(start_s, end_s, phone)``).
    """
    fig, axes = plt.subplots(len(items), 1, figsize=(10, 2.6 * len(items)), squeeze=False,
                             layout="constrained")
    for ax, it in zip(axes[:, 0], items):
        ax.plot(it["t"], it["aperture"], c="#d62728", lw=1.4)
        ax.set_ylabel("lip aperture (px)", fontsize=8)
        ax.set_title(it["title"], fontsize=9, loc="left")
        ax.grid(alpha=0.3)
        lo, hi = ax.get_ylim()
        for s, e, p in it["phones"]:
            if p == "sil":
                ax.axvspan(s, e, color="0.92", lw=0)
                continue
            ax.axvline(s, c="0.8", lw=0.5)
            ax.text((s + e) / 2, lo, p, ha="center", va="bottom", fontsize=6.5, color="0.25")
        ax.set_xlim(it["t"][0], it["t"][-1])
    axes[-1, 0].set_xlabel("time (s)")
    return _save(fig, path)


def mup_trajectories(items: list, path, *, fps: int = 30, n_show: int = 3) -> Path:
    """Predicted vs true MUPs over time: one row per item, the first ``n_show`` utterance MUPs
    and (for an expression) the first expression MUP.

    ``items``: dicts with ``title``, ``truth`` (n_frames, n_mups), ``n_utterance`` (A0) and
    ``estimates`` ({method: (n_frames, n_mups)}).
    """
    styles = ["--", ":", "-."]
    ncols = n_show + 1
    fig, axes = plt.subplots(len(items), ncols, figsize=(3.0 * ncols, 2.2 * len(items)),
                             squeeze=False, layout="constrained")
    for row, it in zip(axes, items):
        truth = np.asarray(it["truth"])
        t = np.arange(len(truth)) / fps
        n_utt = it.get("n_utterance", truth.shape[1])
        cols = list(range(n_show)) + [n_utt]
        for ax, j in zip(row, cols):
            if j >= truth.shape[1]:
                ax.axis("off")
                continue
            ax.plot(t, truth[:, j], c="k", lw=1.3, label="true")
            for (name, est), ls in zip(it["estimates"].items(), styles):
                ax.plot(t, np.asarray(est)[:, j], ls, lw=1.1, label=name)
            ax.set_title(f"{'c0' if j < n_utt else 'ck'}[{j if j < n_utt else j - n_utt}]",
                         fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
        row[0].set_ylabel(it["title"], fontsize=7)
    axes[0, 0].legend(fontsize=7, loc="best")
    for ax in axes[-1]:
        ax.set_xlabel("time (s)", fontsize=8)
    return _save(fig, path)


def confusion_matrix(counts: np.ndarray, names: list, path, *, title: str = "") -> Path:
    """Row-normalised confusion of the gate (true class per row, chosen class per column)."""
    counts = np.asarray(counts, dtype=float)
    rows = counts.sum(1, keepdims=True)
    frac = np.divide(counts, rows, out=np.zeros_like(counts), where=rows > 0)
    fig, ax = plt.subplots(figsize=(7.5, 6.8), layout="constrained")
    im = ax.imshow(frac, cmap="Blues", vmin=0, vmax=1)
    ax.set_xticks(range(len(names)), names, rotation=90, fontsize=6)
    ax.set_yticks(range(len(names)), names, fontsize=6)
    ax.set_xlabel("class chosen by the gate")
    ax.set_ylabel("true class")
    if title:
        ax.set_title(title, fontsize=9)
    fig.colorbar(im, ax=ax, shrink=0.7, label="fraction of the true class's frames")
    return _save(fig, path)


def tracking_curve(rows: list, path) -> Path:
    """Tracker error (px) against image noise: raw LK, measurements, MU-constrained."""
    fig, ax = plt.subplots(figsize=(5.5, 3.4), layout="constrained")
    x = [r["noise_sd"] for r in rows]
    for key, label, style in (("lk_px", "raw Lucas-Kanade", "o-"),
                              ("measured_px", "measurements ζ(t)", "s--"),
                              ("constrained_px", "MU-constrained (Eq. 5)", "D-")):
        ax.plot(x, [r[key] for r in rows], style, label=label)
    ax.set_xlabel("image noise sd (grey levels)")
    ax.set_ylabel("mean marker error (px)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)
