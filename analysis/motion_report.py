"""The face-in-motion part of the PDF: keyframes (Eqs. 3–4, Fig. 4), the round trip, the
animated sentence (Fig. 6), the three expressions (Fig. 7) and the tracker evaluation (§V).
Reads the stage folders only; what a stage skipped (the keyframes and Fig. 7 on a corpus
without smile and sad) is said in words."""
from __future__ import annotations

import json
from pathlib import Path

from analysis.report import escape


def motion_section(report, keyframes_dir: Path, render_dir: Path | None,
                   tracking_dir: Path | None = None) -> None:
    report.heading("The face in motion", stage="keyframes", key="motion")
    kf = json.loads((keyframes_dir / "done.json").read_text())
    if kf.get("skipped"):
        report.paragraph(escape(kf["skipped"]))
    else:
        _keyframes(report, kf, keyframes_dir)
    if render_dir is not None and (render_dir / "done.json").is_file():
        r = json.loads((render_dir / "done.json").read_text())
        text = escape(r["text"])
        report.paragraph("{label:fig6} animates a held-out sentence from its audio alone"
                         + (" and {label:fig7} shows one moment of it in each expression."
                            if r.get("fig7") else "."))
        report.figure(render_dir / r["fig6"], f"Fig. 6 style: a held-out sentence animated from "
                      f"its audio alone by the trained mapping ({r['utterance']}: \"{text}\"), "
                      "ten frames with the phone under way.", width=0.95, key="fig6")
        if r.get("fig7"):
            shown = ", ".join(r.get("fig7_expressions") or ("neutral", "smile", "sad"))
            report.figure(render_dir / r["fig7"], "Fig. 7 style: the same moment of that "
                          f"sentence animated in each expression ({shown}).", width=0.7,
                          key="fig7")
        for what in r.get("skipped", []):
            report.paragraph(f"Skipped: {escape(what)}")
    if tracking_dir is not None and (tracking_dir / "done.json").is_file():
        t = json.loads((tracking_dir / "done.json").read_text())
        report.paragraph(t.get("summary", ""))
        report.paragraph("{label:tracker} gives the tracker's mean marker error against the "
                         "ground truth at each image noise level"
                         + (", {label:tracker_fig} draws it." if t.get("figure") else "."))
        report.table("Tracker error against ground truth (mean marker error, pixels)",
                     ["image noise sd", "raw Lucas-Kanade", "measurements", "MU-constrained"],
                     [[f"{r['noise_sd']:.0f}", f"{r['lk_px']:.2f}", f"{r['measured_px']:.2f}",
                       f"{r['constrained_px']:.2f}"] for r in t["rows"]], key="tracker")
        if t.get("figure"):
            report.figure(tracking_dir / t["figure"], t.get("caption", ""), width=0.7,
                          key="tracker_fig")


def _keyframes(report, kf: dict, keyframes_dir: Path) -> None:
    """The keyframes' paragraph, round-trip table and figure, from the stage's record."""
    samples = ", ".join(f"{k} {v}" for k, v in kf["samples"].items())
    report.paragraph(
        "Keyframes (§IV-B, §VII-B): smile, sad and the visemes i, a, o, f, u, m, each the median "
        "deformation of training frames that correspond to it semantically: the centres of the "
        "viseme's most strongly articulated phones in neutral speech, and the hold of each "
        "expression with a closed mouth. Frames per keyframe: "
        f"{samples}. Conversion by Eq. 4; condition number of K {kf['condition']:.0f}. "
        "{label:keyframes} shows the eight keyframes; {label:keyframe_roundtrip} measures what "
        "the conversion loses.")
    rows = [[r["expression"], r["frames"], f"{100 * r['mup_relative']:.1f} %",
             f"{r['pixel_rmse']:.3f}", f"{r['pixel_max']:.2f}",
             f"{100 * r['shape_relative']:.1f} %"] for r in kf["roundtrip"]]
    report.table("Keyframe round trip: MUPs -> keyframe weights -> MUPs (Eq. 4), every frame",
                 ["expression", "frames", "MUP error", "px RMS", "px max", "shape error"], rows,
                 note="Eight keyframes span 8 dimensions; an expression's MU shapes span A0 + Ak "
                      "= 9 (plus its mean), so the conversion loses a little, as measured here.",
                 key="keyframe_roundtrip")
    report.figure(keyframes_dir / "keyframes.png", "The eight keyframes (cf. the paper's Fig. 4) "
                  "drawn on the neutral face.", width=0.8, key="keyframes")
