"""The report's "A real speaker (GRID s1)" section: the pipeline run again on a real face.

The ``real_speaker`` stage fits Motion Units and trains the mapping on a corpus made from a real
speaker's video (79 markers from MediaPipe landmarks), then scores models on its held-out
sentences with :mod:`analysis.face_eval`. Its folder holds ``summary.json`` (every number shown
here), ``strip.npz`` (one held-out sentence: real and predicted aligned markers and normalised
openings) and ``units.npz`` (the utterance MUs on the speaker's neutral face). This module draws
the two figures and lays the section out; it computes nothing but the target verdicts, and a
missing file or value becomes a sentence, not an error.

Cells are formatted by :func:`fmt` and the verdicts come from :func:`target_checks`, so a
findings page that uses them prints the section's numbers character for character.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from matplotlib.lines import Line2D

from analysis import figures
from analysis.report import escape
from face_model.layout import LEFT_INNER_CORNER, LEFT_OUTER_CORNER, LOWER_INNER, default_layout

STAGE = "real_speaker"
METHOD = "gated_mlp"  # the paper's mapping, shown in the Tables I-II comparison
N_MUS_SHOWN = 4
ARROW_PX = 25.0  # the largest MU arrow drawn, px of the face
N_STRIP_FRAMES = 8
FPS = 30.0  # the corpus contract's frame rate (strip.npz may carry its own ``fps``)
COLOURS = {"real": "black", "speaker": "#1f77b4", "synthetic": "#d62728"}
LABELS = {"real": "real (landmarks)", "speaker": "speaker-trained",
          "synthetic": "synthetic-trained"}
# Outer lip 46-63 and inner lip 64-75 run round their contour in index order (the lower lips
# right -> left), so each closes back on its first marker.
OUTER = list(range(LEFT_OUTER_CORNER, LEFT_INNER_CORNER)) + [LEFT_OUTER_CORNER]
INNER = list(range(LEFT_INNER_CORNER, LOWER_INNER.stop)) + [LEFT_INNER_CORNER]
GRID_ATTRIBUTION = ("GRID corpus: M. Cooke, J. Barker, S. Cunningham, X. Shao (2006), An "
                    "audio-visual corpus for speech perception and automatic speech "
                    "recognition, JASA 120(5):2421–2424; Zenodo 3625687; CC BY 4.0")
SCORE_ROWS = (("speaker_model", "speaker-trained model"),
              ("synthetic_model", "synthetic-trained default model"),
              ("loudness", "loudness envelope (floor)"))


def num(v) -> float:
    """``v`` as a float; NaN for None, ``""`` or anything that is not a number."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def fmt(v, digits: int = 3) -> str:
    """``v`` with ``digits`` decimals, or ``–`` when absent."""
    x = num(v)
    return "–" if math.isnan(x) else f"{x:.{digits}f}"


def pct(v, digits: int = 2) -> str:
    """A fraction as a percentage (``97.56 %``), or ``–`` when absent."""
    x = num(v)
    return "–" if math.isnan(x) else f"{100 * x:.{digits}f} %"


def mu_figure(units_npz, path, *, width: float = 1.0) -> Path:
    """The first :data:`N_MUS_SHOWN` utterance MUs drawn on the real speaker's neutral face.

    Parameters
    ----------
    units_npz : path-like
        ``components`` (7, 158), x/y interleaved per marker; ``scale`` (7,), a typical MUP
        magnitude per MU; ``neutral`` (79, 2), the speaker's neutral face (aligned frame).
    path : path-like
        The PNG to write.
    width : float
        Fraction of the text width the report draws it at.

    Returns
    -------
    Path
        ``path``: per MU, the markers (dots) and the layout's mesh on the neutral face, and
        ``neutral ± scale · component`` as arrows from each marker (red +, blue −), all MUs
        lengthened by one common factor (in the legend) so that the largest arrow is
        :data:`ARROW_PX` px; each title gives the MU's largest true displacement.
    """
    with np.load(units_npz) as z:
        comps, scale, neutral = z["components"], z["scale"], np.asarray(z["neutral"], float)
    k = min(N_MUS_SHOWN, len(comps))
    disp = [np.asarray(comps[i], float).reshape(-1, 2) * float(scale[i]) for i in range(k)]
    sizes = [float(np.linalg.norm(d, axis=1).max()) for d in disp]
    gain = ARROW_PX / (max(sizes) or 1.0)
    lo, hi = neutral.min(0) - 20, neutral.max(0) + 20
    cell = width * figures.TEXT_WIDTH_IN / max(k, 1)
    tri = default_layout().triangles
    with figures.report_figure(path, width=width,
                               height_in=cell * (hi - lo)[1] / (hi - lo)[0] + 0.55) as fig:
        axes = np.atleast_1d(fig.subplots(1, k))
        for i, (ax, d) in enumerate(zip(axes, disp)):
            ax.triplot(neutral[:, 0], neutral[:, 1], tri, lw=0.3, c="0.78")
            ax.scatter(*neutral.T, s=1.2, c="0.25", zorder=3)
            for sign, colour in ((1, "#d62728"), (-1, "#1f77b4")):
                ax.quiver(neutral[:, 0], neutral[:, 1], sign * gain * d[:, 0],
                          sign * gain * d[:, 1], angles="xy", scale_units="xy", scale=1,
                          color=colour, width=0.005)
            _face_axes(ax, lo, hi)
            ax.set_title(f"MU {i + 1} (largest {sizes[i]:.1f} px)", fontsize=8)
        handles = [Line2D([], [], c="#d62728", label=f"+ scale · MU (arrows × {gain:.0f})"),
                   Line2D([], [], c="#1f77b4", label="− scale · MU"),
                   Line2D([], [], ls="", marker="o", ms=2, c="0.25", label="neutral markers")]
        fig.legend(handles=handles, loc="outside lower center", ncol=3)
    return Path(path)


def _face_axes(ax, lo, hi) -> None:
    """Equal scale, no ticks, image coordinates (y down) over the box ``lo``–``hi``."""
    ax.set(xlim=(lo[0], hi[0]), ylim=(hi[1], lo[1]), aspect="equal", xticks=[], yticks=[])


def strip_frames(n: int, k: int = N_STRIP_FRAMES) -> list[int]:
    """``k`` frame indices evenly spread over ``n`` frames: the centres of ``k`` equal parts."""
    k = max(1, min(k, n))
    return sorted({int((i + 0.5) * n / k) for i in range(k)})


def frame_strip_figure(strip_npz, path, *, width: float = 1.0) -> Path:
    """The lips of one held-out sentence, real vs predicted, and the openings under them.

    Parameters
    ----------
    strip_npz : path-like
        ``clip``, aligned markers ``real``, ``speaker``, ``synthetic`` (n, 79, 2), and the
        normalised openings ``real_opening``, ``speaker_opening``, ``synthetic_opening`` (n,);
        optionally ``fps`` (default :data:`FPS`).
    path : path-like
        The PNG to write.
    width : float
        Fraction of the text width the report draws it at.

    Returns
    -------
    Path
        ``path``: top, :data:`N_STRIP_FRAMES` frames (:func:`strip_frames`), each the outer and
        inner lip contours (markers 46–75) of the real face (black), the speaker-trained
        prediction (blue) and the synthetic-trained one (red), on one common scale; bottom, the
        three normalised openings over time with the chosen frames marked.
    """
    with np.load(strip_npz) as z:
        clip = str(z["clip"])
        fps = float(z["fps"]) if "fps" in z.files else FPS
        marks = {k: np.asarray(z[k], float) for k in COLOURS}
        opens = {k: np.asarray(z[f"{k}_opening"], float) for k in COLOURS}
    n = min(len(v) for v in (*marks.values(), *opens.values()))
    chosen = strip_frames(n)
    lips = np.concatenate([m[chosen][:, OUTER] for m in marks.values()]).reshape(-1, 2)
    lo, hi = np.nanmin(lips, 0) - 3, np.nanmax(lips, 0) + 3
    t = np.arange(n) / fps
    span = hi - lo
    panel_h = figures.TEXT_WIDTH_IN * width / len(chosen) * span[1] / span[0] + 0.2
    with figures.report_figure(path, width=width, height_in=panel_h + 2.3) as fig:
        top, bottom = fig.subfigures(2, 1, height_ratios=[panel_h, 2.3])
        axes = np.atleast_1d(top.subplots(1, len(chosen)))
        for j, (ax, f) in enumerate(zip(axes, chosen)):
            for key, m in marks.items():
                lw = 1.3 if key == "real" else 1.0
                ax.plot(*m[f][OUTER].T, c=COLOURS[key], lw=lw)
                ax.plot(*m[f][INNER].T, c=COLOURS[key], lw=0.7 * lw)
            _face_axes(ax, lo, hi)
            ax.set_title(f"{j + 1}: {t[f]:.2f} s", fontsize=7.5)
        ax = bottom.subplots()
        for key, o in opens.items():
            ax.plot(t, o[:n], c=COLOURS[key], lw=1.3 if key == "real" else 1.0,
                    label=LABELS[key])
        for j, f in enumerate(chosen):
            ax.axvline(t[f], c="0.5", lw=0.6, ls=":")
            ax.text(t[f], 1.01, str(j + 1), ha="center", va="bottom", fontsize=7.5,
                    transform=ax.get_xaxis_transform())
        ax.set_xlim(t[0], t[-1])
        ax.set_xlabel("time (s)")
        ax.set_ylabel("lip opening (z)")
        ax.set_title(f"held-out sentence {clip}", loc="left", fontsize=7.5, pad=12)
        ax.grid(alpha=0.3)
        handles = [Line2D([], [], c=COLOURS[k], label=LABELS[k]) for k in COLOURS]
        fig.legend(handles=handles, loc="outside lower center", ncol=3)
    return Path(path)


def target_checks(summary: dict) -> list[dict]:
    """The targets of ``summary["targets"]`` each checked against the face scores.

    Returns
    -------
    list of dict
        ``model`` (a key of :data:`SCORE_ROWS`), ``what`` (``r`` or ``closures``), ``target``,
        ``value`` (pooled r, or the fraction of real closures agreed; NaN when absent) and
        ``verdict``: ``met`` (value ≥ target), ``not met``, or ``not measured``.
    """
    targets = summary.get("targets") or {}
    scores = summary.get("face_scores") or {}
    out = []
    for key, model, what, field in (("speaker_r", "speaker_model", "r", "r_pooled"),
                                    ("synthetic_r", "synthetic_model", "r", "r_pooled"),
                                    ("synthetic_closures", "synthetic_model", "closures",
                                     "closure_agreed_frac")):
        target = num(targets.get(key))
        if math.isnan(target):
            continue
        value = num(((scores.get(model) or {}).get("pooled") or {}).get(field))
        verdict = ("not measured" if math.isnan(value) else
                   "met" if value >= target else "not met")
        out.append({"model": model, "what": what, "target": target, "value": value,
                    "verdict": verdict})
    return out


def _models_text(models: dict) -> str:
    """The model files (their last three path parts) in a sentence."""
    named = [f"{label} {escape('/'.join(Path(str(models[key])).parts[-3:]))}"
             for key, label in SCORE_ROWS if models.get(key)]
    return f"Models: {'; '.join(named)}." if named else "The summary names no model files."


def _check_text(c: dict) -> str:
    if c["what"] == "r":
        return f"r ≥ {c['target']:.2f}: {c['verdict']}"
    return f"closures ≥ {100 * c['target']:.0f} %: {c['verdict']}"


def _face_rows(summary: dict) -> list[list]:
    scores = summary.get("face_scores") or {}
    checks = target_checks(summary)
    rows = []
    for key, label in SCORE_ROWS:
        p = (scores.get(key) or {}).get("pooled") or {}
        k, n = p.get("closures_agreed"), p.get("closure_events")
        agreed = (f"{int(num(k))}/{int(num(n))} ({pct(p.get('closure_agreed_frac'), 0)})"
                  if not (math.isnan(num(k)) or math.isnan(num(n))) else "–")
        false = pct(p.get("false_closure_frac"), 1)
        lve = fmt(p.get("lve_px"), 2) if key == "speaker_model" else "–"
        target = "; ".join(_check_text(c) for c in checks if c["model"] == key)
        rows.append([label, fmt(p.get("r_pooled")), fmt(p.get("r_clip_median")), agreed,
                     false, lve, target or ("floor" if key == "loudness" else "–")])
    return rows


def _rows_by(rows: list, method: str = METHOD) -> dict:
    """``{(split, part): row}`` of the neutral rows of ``method``."""
    return {(r.get("split"), r.get("part")): r for r in rows or []
            if r.get("method") == method and r.get("expression", "neutral") == "neutral"}


def _tables_rows(summary: dict) -> list[list]:
    real, syn = (_rows_by((summary.get("tables") or {}).get(k)) for k in ("real", "synthetic"))
    out = []
    for split in ("random_frames", "utterance"):
        for part in ("train", "test"):
            r, s = real.get((split, part), {}), syn.get((split, part), {})
            if not (r or s):
                continue
            row = [split, part]
            for m, d in (("R", 3), ("nu_d", 3), ("nu_d_est", 3), ("MSE", 4)):
                paper = r.get(f"paper_{m}", "") or s.get(f"paper_{m}", "")
                row += [fmt(r.get(m), d), fmt(s.get(m), d), fmt(paper, d)]
            out.append(row)
    return out


def _lip_rows(summary: dict) -> list[list]:
    real, syn = (_rows_by((summary.get("tables") or {}).get(k)) for k in ("real", "synthetic"))

    def closed(r):
        n = num(r.get("bilabial_segments"))
        return (f"{fmt(r.get('closure'), 2)} of {int(n)}" if not math.isnan(n) and n > 0
                else "–")
    out = []
    for split in ("random_frames", "utterance"):
        r, s = real.get((split, "test"), {}), syn.get((split, "test"), {})
        cells = [fmt(r.get("LVE"), 2), fmt(s.get("LVE"), 2), fmt(r.get("R_lips")),
                 fmt(s.get("R_lips")), closed(r), closed(s)]
        if any(c != "–" for c in cells):
            out.append([split, *cells])
    return out


def _corpus_paragraph(rep, summary: dict) -> None:
    c = summary.get("corpus") or {}
    if not c:
        rep.paragraph("The stage's summary says nothing about the corpus.")
        return
    refused = c.get("refused", "?")
    refused = len(refused) if isinstance(refused, (list, tuple, dict)) else refused
    grid = "grid" in f"{c.get('speaker', '')} {c.get('source', '')}".lower()
    rep.paragraph(
        f"The pipeline run again on a real speaker: {escape(c.get('speaker', '?'))}, "
        f"{escape(c.get('utterances', '?'))} utterances ({escape(c.get('frames', '?'))} frames "
        f"at 30 fps) whose video became the 79 markers of the layout through MediaPipe face "
        f"landmarks, aligned by the glasses markers; {escape(refused)} clips "
        "were refused by the import. Motion Units were fitted and the mapping trained on this "
        "corpus alone (a nested run), and scored on its held-out sentences. "
        f"Source: {escape(c.get('source', 'not given'))}. "
        f"Licence: {escape(str(c.get('licence') or 'not given').rstrip('.'))}."
        + (f" {escape(GRID_ATTRIBUTION)}." if grid else ""))


def _units_paragraph(rep, summary: dict) -> None:
    u = summary.get("units") or {}
    real, syn = num(u.get("variance_explained")), num(u.get("synthetic"))
    n = escape(u.get("n_utterance", "?"))
    paper = pct(u.get("paper", 0.9756))
    if math.isnan(real):
        rep.paragraph(f"The variance explained by the {n} utterance MUs on the real corpus is "
                      f"absent from the stage's summary (the paper: {paper}).")
        return
    rep.paragraph(
        f"The {n} utterance MUs explain {pct(real)} of the variance of the real speaker's "
        "neutral-speech deformations, against "
        + (f"{pct(syn)} on this run's synthetic corpus" if not math.isnan(syn) else
           "a figure absent from the summary for this run's synthetic corpus")
        + f" and {paper} in the paper (§IV-A).")


def _figure(rep, draw, src: Path, out: Path, caption: str, what: str, key: str) -> None:
    if not src.is_file():
        rep.paragraph(f"No {what}: the stage left no {escape(src.name)}.")
        return
    rep.figure(draw(src, out), caption, key=key)


def real_speaker_section(rep, stage_dir, figs_dir) -> None:
    """Add the section "A real speaker (GRID s1)" from the ``real_speaker`` stage's folder.

    Parameters
    ----------
    rep : analysis.report.Report
        The report the section is added to.
    stage_dir : path-like
        The stage's folder: ``summary.json``, ``strip.npz``, ``units.npz`` (module docstring).
    figs_dir : path-like
        Where the two figures are drawn (``real_units.png``, ``real_strip.png``).

    Notes
    -----
    Keys for a findings page: section ``real_speaker``; tables ``real_tables`` (Tables I–II,
    real vs synthetic vs the paper), ``real_lips`` and ``real_face_scores``; figures
    ``real_units`` and ``real_strip``. Anything absent is said in a sentence.
    """
    stage_dir, figs_dir = Path(stage_dir), Path(figs_dir)
    rep.heading("A real speaker (GRID s1)", stage=STAGE, key="real_speaker")
    try:
        summary = json.loads((stage_dir / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        rep.paragraph(f"No results: the stage's summary.json could not be read "
                      f"({escape(type(e).__name__)}).")
        return
    _corpus_paragraph(rep, summary)
    if summary.get("note"):
        rep.paragraph(escape(summary["note"]))
    _units_paragraph(rep, summary)
    _figure(rep, mu_figure, stage_dir / "units.npz", figs_dir / "real_units.png",
            f"The first {N_MUS_SHOWN} utterance MUs of the real speaker on the speaker's "
            "neutral face (aligned frame): each MU times a typical size of its MUP on "
            "the corpus (units.npz scale), added (red) and taken away (blue), with the "
            "mesh of the layout; all arrows are lengthened by one factor (in the legend) and "
            "each title gives the largest true displacement.", "Motion Unit figure", "real_units")
    tables = _tables_rows(summary)
    if tables:
        header = ["split", "part"]
        for m in ("R", "ν<sub>d</sub>", "ν<sub>d</sub>′", "MSE"):
            header += [f"{m} real", f"{m} synth.", f"{m} paper"]
        rep.table(f"Tables I–II on the real speaker: {METHOD}, neutral speech, real corpus vs "
                  "this run's synthetic corpus vs the paper", header, tables,
                  note="Paper: Hong, Wen &amp; Huang (2002), Tables I (train) and II (test), "
                       "neutral; their split draws frames at random. ν<sub>d</sub>′: ν of the "
                       "estimate. random_frames: 80 % of the frames at random; utterance: 80 % "
                       "of the sentences, none on both sides.", key="real_tables")
    else:
        rep.paragraph(f"No Tables I–II rows of {METHOD} in the stage's summary.")
    lips = _lip_rows(summary)
    if lips:
        rep.table(f"Lips on the testing set: {METHOD}, real corpus vs synthetic corpus",
                  ["split", "LVE real (px)", "LVE synth. (px)", "R lips real",
                   "R lips synth.", "/p b m/ closed real", "/p b m/ closed synth."], lips,
                  note="LVE: per frame the largest error over the 30 lip markers, averaged, "
                       "in pixels of each corpus's own aligned face. R lips: Eq. 6 on the lip "
                       "markers. /p b m/ closed: the fraction of bilabial segments whose inner "
                       "lips meet in the estimate.", key="real_lips")
    else:
        rep.paragraph("No lip metrics (LVE, R lips, closure) in the stage's summary.")
    scores = summary.get("face_scores") or {}
    if scores:
        pooled = next(((v or {}).get("pooled") or {} for v in scores.values() if v), {})
        clips = pooled.get("clips", len(summary.get("test_utterances") or []))
        rep.paragraph(
            f"Scored on {escape(clips)} held-out sentences ({escape(pooled.get('frames', '?'))} "
            "frames) "
            "with analysis.face_eval: each model's inner-lip opening against the real one, "
            "both normalised per speaker; pooled r over all frames, the median r per clip, the "
            "real closures (runs of at least two frames at the speaker's closed level) the "
            "prediction agrees with, and its false closures. The loudness envelope, which knows "
            "no phones, is the floor.")
        rep.table("Lips against the real face on the held-out sentences",
                  ["model", "pooled r", "median r per clip", "closures agreed",
                   "false closures", "LVE (px)", "target"], _face_rows(summary),
                  note="Target: the project's aims for each model (summary.json), met when the "
                       "pooled r (or the share of real closures agreed) shown reaches it. LVE "
                       "only for the model trained on this speaker (aligned pixels). "
                       + _models_text(summary.get("models") or {}),
                  key="real_face_scores")
    else:
        rep.paragraph("No face scores in the stage's summary.")
    _figure(rep, frame_strip_figure, stage_dir / "strip.npz", figs_dir / "real_strip.png",
            "A held-out sentence: the lips (outer and inner contours) of the real face "
            "(black), the speaker-trained prediction (blue) and the synthetic-trained one "
            "(red) at evenly spread frames, and the three normalised openings over time with "
            "those frames marked.", "frame strip", "real_strip")
