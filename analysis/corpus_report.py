"""Corpus and Motion-Unit results for the report: summaries, figures and report sections.

``summarize_corpus`` and ``summarize_units`` return plain dicts (saved as JSON by the pipeline);
``make_figures`` draws from the corpus and the fitted units; the ``*_section`` functions lay the
saved results out in the report and never compute anything themselves.
"""
from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from analysis import figures
from analysis.report import escape
from face_model.alignment import align_markers, unflatten
from face_model.layout import default_layout, mouth_opening
from face_model.phones import PHONES

# Published values (Hong, Wen & Huang 2002, §IV-A and §VII-A).
PAPER = {
    "utterance_variance": 0.9756,  # 7 utterance MUs
    "expression_variance_min": 0.9813,  # 2 expression MUs, at least, every expression
    "n_frames": 19563,
    "n_sentences": 100,
}


def summarize_corpus(corpus) -> dict:
    """Counts a reader of the report wants: utterances, frames, seconds, frames per phone."""
    frames_per_phone: Counter = Counter()
    per_expr: dict = {}
    for u in corpus.utterances:
        idx = u.phone_per_frame()
        frames_per_phone.update(PHONES[i] for i in idx)
        e = per_expr.setdefault(u.expression, {"utterances": 0, "frames": 0, "seconds": 0.0})
        e["utterances"] += 1
        e["frames"] += u.n_frames
        e["seconds"] += len(u.audio) / u.sample_rate
    return {
        "root": str(corpus.root),
        "n_utterances": len(corpus),
        "n_sentences": len({u.text for u in corpus.utterances}),
        "n_speakers": len({u.speaker for u in corpus.utterances}),
        "n_frames": corpus.n_frames,
        "sample_rates": sorted({u.sample_rate for u in corpus.utterances}),
        "per_expression": per_expr,
        "frames_per_phone": {p: int(frames_per_phone.get(p, 0)) for p in PHONES},
        "phones_present": int(sum(1 for p in PHONES if frames_per_phone.get(p, 0) > 0)),
        "seed": corpus.info.get("seed"),
        "backend": corpus.info.get("backend"),
    }


def noise_floor_share(variance: np.ndarray, skip: int = 20) -> float:
    """Share of the total variance in an isotropic noise floor, estimated from the spectrum alone.

    The floor per axis is the median eigenvalue beyond the first ``skip`` axes (among the axes that
    are not exactly zero: alignment removes a few degrees of freedom), times the number of such
    axes. With white marker noise, no k MUs can explain more than about
    ``1 − share · (n_axes − k) / n_axes`` of the variance.
    """
    v = np.asarray(variance, dtype=np.float64)
    live = v[v > v[0] * 1e-12]
    if len(live) <= skip:
        return 0.0
    return float(np.median(live[skip:]) * len(live) / v.sum())


def summarize_units(units) -> dict:
    """Variance explained (ours and the paper's), the noise-floor share, the cumulative curves."""
    kept = units.variance_explained()
    spectra = {"neutral": units.variance_, **units.expression_variance_}
    return {
        "noise_share": {k: noise_floor_share(v) for k, v in spectra.items()},
        "n_utterance": units.n_utterance,
        "n_expression": units.n_expression,
        "explained": kept,
        "curves": {k: units.explained_variance_ratio(k)[:20].tolist()
                   for k in ("neutral", *units.expressions_)},
        "paper": {"neutral": PAPER["utterance_variance"],
                  **{k: PAPER["expression_variance_min"] for k in units.expressions_}},
    }


def lip_aperture(markers: np.ndarray) -> np.ndarray:
    """Mean vertical distance (px) between the inner lower and inner upper lip, per frame, after
    alignment by the glasses."""
    return mouth_opening(align_markers(markers))


def make_figures(corpus, units, summary: dict, out_dir) -> dict:
    """Draw every corpus/MU figure into ``out_dir``; returns name → path."""
    out = Path(out_dir)
    lay = default_layout()
    figs = {
        "layout": figures.marker_layout(out / "marker_layout.png"),
        "phones": figures.phone_histogram(summary["corpus"]["frames_per_phone"],
                                          out / "phone_histogram.png"),
        "variance": figures.variance_curves(
            summary["units"]["curves"],
            {k: (units.n_utterance if k == "neutral" else units.n_expression)
             for k in summary["units"]["curves"]},
            summary["units"]["paper"], out / "mu_variance.png"),
    }
    neutral = lay.neutral
    # Each MU is drawn as the displacement of one standard deviation of its MUP.
    sd = np.sqrt(units.variance_)
    utt = [unflatten(units.components_[i][None])[0] * sd[i] for i in range(units.n_utterance)]
    figs["utterance_mus"] = figures.motion_unit_arrows(
        neutral, utt, [f"utterance MU {i + 1}" for i in range(len(utt))],
        out / "utterance_mus.png")
    expr_units, titles = [], []
    for k in units.expressions_:
        expr_units.append(unflatten(units.expression_mean_[k][None])[0])
        titles.append(f"{k}: mean $m_{{k0}}$")
        for j in range(units.n_expression):
            sd_k = np.sqrt(units.expression_variance_[k][j])
            expr_units.append(unflatten(units.expression_components_[k][j][None])[0] * sd_k)
            titles.append(f"{k}: MU {j + 1}")
    if expr_units:
        figs["expression_mus"] = figures.motion_unit_arrows(
            neutral, expr_units, titles, out / "expression_mus.png",
            ncols=units.n_expression + 1, colour="#1f77b4", width=0.8)
    items = []
    by_text = {}
    for u in corpus.utterances:
        by_text.setdefault((u.speaker, u.text), []).append(u)
    first = next(iter(by_text.values()))
    for u in first:
        items.append({"title": f"{u.utt_id} ({u.expression}): \"{u.text}\"",
                      "t": np.arange(u.n_frames) / u.fps, "aperture": lip_aperture(u.markers),
                      "phones": [(s.start_s, s.end_s, s.phone) for s in u.phones]})
    figs["trajectories"] = figures.lip_trajectories(items, out / "lip_trajectories.png")
    return {k: str(v) for k, v in figs.items()}


def _pct(x) -> str:
    return f"{100 * x:.2f} %"


def _expressions_text(per_expression: dict) -> str:
    """``neutral and with expressions (smile, sad)``, or ``neutral speech only``."""
    others = [e for e in per_expression if e != "neutral"]
    if not others:
        return "neutral speech only"
    return f"neutral and with expressions ({', '.join(others)})"


def corpus_section(report, corpus_summary: dict, figs: dict, *, given: dict | None = None,
                   scope: str | None = None, switched_off: dict | None = None) -> None:
    """The corpus part of the report: what it holds, its summary table and figures.

    Parameters
    ----------
    report : analysis.report.Report
        The report the section is added to.
    corpus_summary : dict
        :func:`summarize_corpus` of the run's corpus.
    figs : dict
        :func:`make_figures`' figures.
    given : dict or None
        For a given corpus (not synthesised): ``source`` (the folder it was taken from) and
        ``info`` (its ``corpus.json``: where it came from, detector, licence, when it says).
    scope : str or None
        What the stages skip on this corpus (a corpus without smile or sad), said as it is.
    switched_off : dict or None
        ``{stage: why}`` of the stages the corpus switches off, shown as a table.
    """
    s = corpus_summary
    exprs = _expressions_text(s["per_expression"])
    if given is None:
        report.heading("The synthetic audio-visual corpus", stage="corpus", key="corpus")
        report.paragraph(
            f"{s['n_sentences']} sentences read by {s['n_speakers']} synthetic speaker(s), "
            f"{exprs}: {s['n_utterances']} utterances, {s['n_frames']} frames at 30 fps (the "
            f"paper: {PAPER['n_sentences']} TIMIT sentences, {PAPER['n_frames']} frames). Speech "
            f"by {s['backend']}; {s['phones_present']} of the 44 phone classes occur. Seed "
            f"{s['seed']}.")
    else:
        info = given.get("info") or {}
        origin = "; ".join(f"{k} {escape(str(info[k]))}" for k in
                           ("source", "detector", "version", "licence", "license") if info.get(k))
        report.heading("The given audio-visual corpus", stage="corpus", key="corpus")
        report.paragraph(
            f"A given corpus, taken from {escape(given['source'])} (not synthesised): "
            f"{s['n_sentences']} sentences by {s['n_speakers']} speaker(s), {exprs}: "
            f"{s['n_utterances']} utterances, {s['n_frames']} frames at 30 fps (the paper: "
            f"{PAPER['n_sentences']} TIMIT sentences, {PAPER['n_frames']} frames); "
            f"{s['phones_present']} of the 44 phone classes occur."
            + (f" Its corpus.json: {origin}." if origin else ""))
    if scope:
        report.paragraph(f"<b>{escape(scope)}</b>")
    if switched_off:
        report.paragraph("{label:switched_off} lists the stages this corpus switches off, and "
                         "why.")
        report.table("Stages this corpus switches off", ["stage", "why"],
                     [[k, escape(v)] for k, v in switched_off.items()], key="switched_off")
    rows = [[e, v["utterances"], v["frames"], f"{v['seconds']:.1f}"]
            for e, v in s["per_expression"].items()]
    rows.append(["total", s["n_utterances"], s["n_frames"],
                 f"{sum(v['seconds'] for v in s['per_expression'].values()):.1f}"])
    report.paragraph("{label:corpus_summary} counts the utterances, frames and seconds per "
                     "expression; {label:corpus_phones} the frames of each phone class; "
                     "{label:corpus_layout} shows the marker layout and {label:corpus_lips} the "
                     "inner-lip aperture of one sentence per expression.")
    report.table("Corpus summary", ["expression", "utterances", "frames", "seconds"], rows,
                 key="corpus_summary")
    report.figure(figs["phones"], "Frames per phone class (log scale), all 44 classes.",
                  key="corpus_phones")
    report.figure(figs["layout"], "The marker layout and mesh in the style of the paper's Fig. 2: "
                  "22 forehead, 24 cheek and 30 lip markers, and 3 on the glasses.", width=0.85,
                  key="corpus_layout")
    report.figure(figs["trajectories"], "Inner-lip aperture of one sentence in each expression, "
                  "after alignment by the glasses, with the phones under it (grey: silence).",
                  key="corpus_lips")


def units_section(report, units_summary: dict, figs: dict, *, note: str | None = None) -> None:
    """The Motion Units part of the report; ``note``: what was skipped (no expression MUs for
    an expression the corpus does not hold)."""
    s = units_summary
    report.heading("Motion Units", stage="units", key="units")
    report.paragraph(
        "Deformations are aligned marker positions minus the speaker's neutral face. Utterance "
        f"MUs: PCA of the neutral deformations (A0 = {s['n_utterance']}). Expression MUs: PCA of "
        f"the residual beyond the utterance MUs, per expression (A<sub>k</sub> = {s['n_expression']}). "
        "{label:mu_variance} sets the variance they explain beside the paper's, "
        "{label:mu_variance_fig} draws it; {label:utterance_mus} shows the utterance MUs"
        + (" and {label:expression_mus} the expression MUs." if "expression_mus" in figs
           else "."))
    noise = s["noise_share"]
    rows = [["Utterance MUs (neutral speech)", s["n_utterance"], _pct(s["explained"]["neutral"]),
             _pct(s["paper"]["neutral"]), _pct(noise["neutral"])]]
    for k, v in s["explained"].items():
        if k != "neutral":
            rows.append([f"Expression MUs: {k} (of the residual)", s["n_expression"], _pct(v),
                         ">= " + _pct(s["paper"][k]), _pct(noise[k])])
    report.table("MU variance explained: ours vs the paper's", ["Motion Units", "number",
                 "ours", "paper", "noise floor"], rows,
                 note="Paper: Hong, Wen &amp; Huang (2002), §IV-A: 97.56 % with 7 utterance MUs; "
                      "2 expression MUs capture at least 98.13 % of the residual. Noise floor: "
                      "the share of the variance in a flat tail of the spectrum (median eigenvalue "
                      "beyond axis 20 times the number of axes), which no few MUs can explain. "
                      "The expression residuals are small, so marker noise weighs more in them.",
                 key="mu_variance")
    if note:
        report.paragraph(escape(note))
    report.figure(figs["variance"], "Cumulative variance explained; circles: the number kept; "
                  "stars: the paper's values.", width=0.75, key="mu_variance_fig")
    report.figure(figs["utterance_mus"], "The utterance MUs as displacement arrows on the "
                  "neutral face: each MU times one standard deviation of its MUP (common scale).",
                  key="utterance_mus")
    if "expression_mus" in figs:
        report.figure(figs["expression_mus"], "Expression MUs: the residual mean m<sub>k0</sub> and the "
                      "principal axes (times one standard deviation), per expression.", width=0.8,
                      key="expression_mus")
