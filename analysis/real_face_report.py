"""The report's "A real speaker (GRID s1)" section: the pipeline run again on a real face.

The ``real_speaker`` stage fits Motion Units and trains the mapping on a corpus made from a real
speaker's video (79 markers from MediaPipe landmarks), then scores models on its held-out
sentences with :mod:`analysis.face_eval`. Its folder holds ``summary.json`` (every number shown
here), ``strip.npz`` (one held-out sentence: real and predicted aligned markers and normalised
openings) and ``units.npz`` (the utterance MUs on the speaker's neutral face). This module draws
the two figures and lays the section out, and a missing file or value becomes a sentence, not
an error. The tables' rows, their cells' formatting and the target verdicts come from
:mod:`analysis.real_face_tables`, so a findings page that uses them prints the section's numbers
character for character.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from matplotlib.lines import Line2D

from analysis import figures
from analysis.config import TARGET_TEXT, TargetsConfig
from analysis.real_face_tables import (METHOD, SCORE_ROWS, face_rows, lip_rows, mapping_rows,
                                       models_text, num, pct, peer_sentences, pooled_of,
                                       rate_rows, tables_rows)
from analysis.report import escape
from face_model.layout import LEFT_INNER_CORNER, LEFT_OUTER_CORNER, LOWER_INNER, default_layout
from mapping.peers import OCULUS_TABLE, ULIPSYNC_TABLE, peer_versions

STAGE = "real_speaker"
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


def video_strip_figure(video_npz, path, *, width: float = 1.0) -> Path:
    """The held-out clip's video, real | predicted, at the stage's chosen frames.

    Parameters
    ----------
    video_npz : path-like
        ``clip``, ``fps``, ``frames`` (k,), ``reasons`` (k,) and ``images`` (k, h, w, 3) uint8:
        each the video frame with the tracked markers (left) beside the same frame with the
        speaker-trained model's markers (right)
        (:func:`talkingface.stages.side_by_side.strip_frames`).
    path : path-like
        The PNG to write.
    width : float
        Fraction of the text width the report draws it at.

    Returns
    -------
    Path
        ``path``: the stills in a row, each titled with its time and why it was chosen.
    """
    with np.load(video_npz) as z:
        clip, fps = str(z["clip"]), float(z["fps"])
        frames, reasons, images = list(z["frames"]), list(z["reasons"]), z["images"]
    k = max(1, len(images))
    h, w = images.shape[1:3] if len(images) else (1, 2)
    panel_h = figures.TEXT_WIDTH_IN * width / k * h / w + 0.45
    with figures.report_figure(path, width=width, height_in=panel_h) as fig:
        axes = np.atleast_1d(fig.subplots(1, k))
        for ax, f, why, img in zip(axes, frames, reasons, images):
            ax.imshow(img)
            ax.set_title(f"{int(f) / fps:.2f} s: {why}", fontsize=7)
            ax.set_axis_off()
        fig.suptitle(f"held-out clip {clip}: real (tracked, green) | predicted (magenta)",
                     fontsize=7.5)
    return Path(path)


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
        f"at {escape(c.get('fps', FPS))} fps) whose video became the 79 markers of the layout "
        f"through MediaPipe face landmarks, aligned by the glasses markers; {escape(refused)} clips "
        "were refused by the import. Motion Units and the neutral face were fitted on "
        + ("the training sentences only" if num((summary.get("units") or {}).get("held_out")) > 0
           else "the whole corpus, held-out sentences included")
        + " and the mapping trained on the training sentences (a nested run), and scored "
        "on the held-out sentences. "
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


def real_speaker_section(rep, stage_dir, figs_dir,
                         targets: TargetsConfig = TargetsConfig()) -> None:
    """Add the section "A real speaker (GRID s1)" from the ``real_speaker`` stage's folder.

    Parameters
    ----------
    rep : analysis.report.Report
        The report the section is added to.
    stage_dir : path-like
        The stage's folder: ``summary.json``, ``strip.npz``, ``units.npz`` (module docstring).
    figs_dir : path-like
        Where the two figures are drawn (``real_units.png``, ``real_strip.png``).
    targets : analysis.config.TargetsConfig
        The run's targets (``face_speaker_r``, ``face_synthetic_r``, ``face_closures``,
        ``rate_tolerance`` are quoted and checked).

    Notes
    -----
    Keys for a findings page: section ``real_speaker``; tables ``real_tables`` (Tables I–II,
    real vs synthetic vs the paper), ``real_lips``, ``real_face_scores``, ``real_rates``,
    ``real_peer_oculus`` and ``real_peer_ulipsync``; figures ``real_units``, ``real_strip``
    and ``real_video_strip``.
    Anything absent is said in a sentence.
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
    if (stage_dir / "units.npz").is_file():
        rep.paragraph("{label:real_units} draws the first utterance MUs on the speaker's "
                      "neutral face.")
    _figure(rep, mu_figure, stage_dir / "units.npz", figs_dir / "real_units.png",
            f"The first {N_MUS_SHOWN} utterance MUs of the real speaker on the speaker's "
            "neutral face (aligned frame): each MU times a typical size of its MUP on "
            "the corpus (units.npz scale), added (red) and taken away (blue), with the "
            "mesh of the layout; all arrows are lengthened by one factor (in the legend) and "
            "each title gives the largest true displacement.", "Motion Unit figure", "real_units")
    tables = tables_rows(summary)
    lips = lip_rows(summary)
    if tables or lips:
        rep.paragraph(" ".join(t for t, ok in (
            ("{label:real_tables} sets Tables I–II on the real speaker beside this run's "
             "synthetic corpus and the paper.", tables),
            ("{label:real_lips} gives the lip metrics on the testing set.", lips)) if ok))
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
    _face_scores(rep, summary, targets, (stage_dir / "strip.npz").is_file())
    _figure(rep, frame_strip_figure, stage_dir / "strip.npz", figs_dir / "real_strip.png",
            "A held-out sentence: the lips (outer and inner contours) of the real face "
            "(black), the speaker-trained prediction (blue) and the synthetic-trained one "
            "(red) at evenly spread frames, and the three openings over time (z on the "
            "sentence's speech frames) with those frames marked.", "frame strip", "real_strip")
    side = summary.get("side_by_side") or {}
    if side.get("videos"):
        rep.paragraph(
            "The stage wrote " + ", ".join(escape(v) for v in side["videos"]) + " (in its "
            "folder): the held-out clip's video with its tracked markers | the markers the "
            "speaker-trained model predicts from the audio, drawn on the same frame | the "
            "default model's face, the audio muxed. {label:real_video_strip} shows stills "
            "of the first.")
        _figure(rep, video_strip_figure, stage_dir / "video_strip.npz",
                figs_dir / "real_video_strip.png",
                "A held-out clip's video: left of each pair the tracked markers (green), right "
                "the speaker-trained model's markers predicted from the audio (magenta), at the "
                "middle of the first /p b m/ segments and of the vowels the real lips open "
                "widest.", "video strip", "real_video_strip")
    elif "side_by_side" in summary:
        rep.paragraph("No side-by-side video: no held-out clip has a video in "
                      "real_speaker.videos.")


def _no_interval(p: dict) -> str:
    text = str(p.get("interval_r_speech") or "not given")
    return text.strip("()").replace("no interval: ", "")


def _face_scores(rep, summary: dict, targets: TargetsConfig, has_strip: bool) -> None:
    """The lip scores on the real face: models and peers, rates, the peers' tables."""
    scores = summary.get("face_scores") or {}
    if not scores:
        rep.paragraph("No face scores in the stage's summary.")
        return
    p = next((pooled_of(summary, k) for k, _ in SCORE_ROWS if pooled_of(summary, k)), {})
    rate = escape(summary.get("input_rate", "?"))
    rule = next(((v or {}).get("rule") or {} for v in scores.values() if v), {})
    speech = ("speech frames (phones other than silence)" if p.get("speech_known", True)
              else "all valid frames (no phones: speech frames unknown)")
    strip = " {label:real_strip} shows one held-out sentence." if has_strip else ""
    rep.paragraph(
        f"{{label:real_face_scores}} scores every model and peer on {escape(p.get('clips', '?'))} "
        f"held-out sentences of {escape(p.get('speakers', '?'))} speaker "
        f"({escape(p.get('speech_frames', '?'))} speech and "
        f"{escape(p.get('silence_frames', '?'))} silence frames; "
        f"{escape(p.get('excluded_frames', '?'))} frames without a detected face excluded), "
        f"audio at {rate} Hz, with analysis.face_eval: r of the inner-lip opening, each clip "
        f"z-scored on its own frames, over the {speech}, silence apart; a /p b m/ segment or "
        f"a control (non-bilabial speech phone) segment counts as closed when, within "
        f"{escape(rule.get('half_window_s', '?'))} s of its centre, the opening falls within "
        f"{escape(rule.get('close_fraction', '?'))} of its speech-frame range above its "
        f"speech-frame minimum (the same rule for the real lips: they close "
        f"{pct(p.get('real_closed_rate'), 0)} of the /p b m/ segments and "
        f"{pct(p.get('real_false_closure_rate'), 0)} of the controls). In brackets, chance: "
        "the same prediction circularly shifted by a third and two thirds of its clip. "
        f"No interval: {escape(_no_interval(p))}."
        + strip)
    sentences = peer_sentences(summary)
    if sentences:
        rep.paragraph("The synthetic-trained default does not beat every peer: "
                      + "; ".join(sentences) + ".")
    rep.table(f"Lips against the real face on the held-out sentences, input {rate} Hz",
              ["model", "r speech (chance)", "r silence (chance)", "median r per clip",
               "/p b m/ closed (chance)", "false closures (chance)", "LVE (px)", "target"],
              face_rows(summary, targets),
              note="Targets quoted from the run's targets: "
                   + "; ".join(f"{k} {getattr(targets, k):g} ({escape(TARGET_TEXT[k])})"
                               for k in ("face_speaker_r", "face_synthetic_r", "face_closures"))
                   + ". LVE only for the model trained on this speaker (aligned pixels). "
                   + models_text(summary.get("models") or {}), key="real_face_scores")
    rows, order = rate_rows(summary, targets)
    if len(order) > 1:
        rep.paragraph(f"{{label:real_rates}} gives the two models' speech-frame r with the same "
                      "audio resampled to each rate (the models hear it at that rate), and the "
                      f"drop from {escape(order[0])} Hz to 16000 Hz against the target "
                      f"rate_tolerance {targets.rate_tolerance:g}.")
        rep.table("Speech-frame r by input rate",
                  ["model", *[f"{escape(r)} Hz" for r in order], "drop to 16 kHz", "target"],
                  rows, note=escape(TARGET_TEXT["rate_tolerance"]) + ".", key="real_rates")
    peers = summary.get("peers") or {}
    versions = peers.get("versions") or peer_versions()
    rep.paragraph(
        "The peers give no opening in pixels: each channel maps to an opening and a viseme by "
        "one table fixed a priori (mapping.peers): {label:real_peer_oculus} for openfacefx "
        f"{escape(versions.get('openfacefx') or 'not installed')}, {{label:real_peer_ulipsync}} "
        f"for pylipsync {escape(versions.get('pylipsync') or 'not installed')}. openfacefx's "
        f"transcript mode was given the "
        f"{escape(peers.get('openfacefx_text_words', 'transcript'))}. The loudness envelope is "
        "dB of the RMS in 40 ms windows.")
    rep.table("openfacefx (Oculus-15 channels): opening and viseme of each channel",
              ["channel", "opening", "viseme"], mapping_rows(OCULUS_TABLE),
              key="real_peer_oculus")
    rep.table("pylipsync (uLipSync templates): opening and viseme of each channel",
              ["channel", "opening", "viseme"], mapping_rows(ULIPSYNC_TABLE),
              key="real_peer_ulipsync")
