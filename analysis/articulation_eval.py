"""How well a coarticulation model draws a real speaker's lips from the true phones, before any
mapping is trained: the hand table against the one fitted on the speaker's training sentences,
on its held-out sentences.

Each model (:class:`data_synth.articulation.Articulation`) coarticulates a clip's forced-aligned
phones; the generator's articulation map around the speaker's rest face
(:class:`data_synth.articulation_fit.FaceMap`) turns the parameters into markers; their mouth
opening (:func:`face_model.layout.mouth_opening`) and width (outer corner to outer corner) are
scored against the tracked markers' by the rules of :mod:`analysis.face_eval`: speech frames
apart from silence, z-scored per clip before pooling, closures on the /p b m/ segments, a chance
figure from circular shifts, frames without a detected face left out. The row ``articulatory
space`` is the real markers' own projection into the seven parameters (step 1 of the fit): the
most any coarticulation model on this face map can reach.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.face_eval import ClipTrack, score_clips
from analysis.report import escape
from data_synth.articulation import coarticulate
from face_model.layout import LEFT_OUTER_CORNER, RIGHT_OUTER_CORNER, mouth_opening

FIGURES = ("r_opening", "chance_r_opening", "r_width", "chance_r_width", "closed",
           "chance_closed", "bilabial_segments", "real_closed", "false_closed",
           "chance_false_closed")


@dataclass(frozen=True)
class HeldOutClip:
    """One held-out clip: its id, speaker, markers aligned into the layout's frame (n, 79, 2),
    phone segments, frame rate and valid-frame mask (None: all)."""

    clip: str
    speaker: str
    aligned: np.ndarray
    phones: tuple
    fps: float
    valid: np.ndarray | None = None


def mouth_width(markers) -> np.ndarray:
    """Outer-corner to outer-corner distance per frame (px), markers (n, 79, 2)."""
    m = np.asarray(markers, dtype=np.float64)
    return np.linalg.norm(m[:, RIGHT_OUTER_CORNER] - m[:, LEFT_OUTER_CORNER], axis=1)


def _row(clips: list, drawn: list) -> dict:
    """The figures of one model: ``drawn`` markers per clip beside the real ones."""
    def tracks(measure):
        return [ClipTrack(c.clip, c.speaker, measure(c.aligned), measure(d), c.fps,
                          phones=c.phones, valid=c.valid) for c, d in zip(clips, drawn)]

    opening = score_clips(tracks(mouth_opening)).pooled
    width = score_clips(tracks(mouth_width)).pooled
    return {"r_opening": opening["r_speech"], "chance_r_opening": opening["chance_r_speech"],
            "r_width": width["r_speech"], "chance_r_width": width["chance_r_speech"],
            "closed": opening["closure_rate"], "chance_closed": opening["chance_closure_rate"],
            "bilabial_segments": opening["bilabial_segments"],
            "real_closed": opening["real_closed_rate"],
            "false_closed": opening["false_closure_rate"],
            "chance_false_closed": opening["chance_false_closure_rate"],
            "speech_frames": opening["speech_frames"], "clips": len(clips)}


def articulation_table(clips: list, face, models: dict, *, projection=None) -> list[dict]:
    """One row per model (``name`` and :data:`FIGURES`), in the order given.

    Parameters
    ----------
    clips : list of HeldOutClip
    face : FaceMap
        The articulation map around the speaker's rest face.
    models : dict name → Articulation
    projection : list of ndarray (n, 7), optional
        Step 1's parameters of each clip: adds the row ``articulatory space`` first.
    """
    rows = []
    if projection is not None:
        rows.append({"model": "articulatory space",
                     **_row(clips, [face.markers(a) for a in projection])})
    for name, model in models.items():
        drawn = [face.markers(coarticulate(c.phones, np.arange(len(c.aligned)) / c.fps, model))
                 for c in clips]
        rows.append({"model": name, **_row(clips, drawn)})
    return rows


def _f(x, digits: int = 2) -> str:
    return "–" if x is None or (isinstance(x, float) and not np.isfinite(x)) else \
        f"{x:.{digits}f}"


def articulation_section(rep, stage_dir) -> None:
    """Add the subsection "The articulation fitted on the real mouth" from the
    ``articulation`` stage's ``summary.json`` (key ``articulation``, table
    ``articulation_table``); a missing or unreadable summary is said in a sentence."""
    rep.heading("The articulation fitted on the real mouth", level=2, stage="articulation",
                key="articulation")
    path = Path(stage_dir) / "summary.json"
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        rep.paragraph(f"No results: the stage's summary.json could not be read "
                      f"({escape(type(e).__name__)}).")
        return
    shipped = summary.get("shipped") or {}
    rows = summary.get("rows") or []
    rep.paragraph(
        "The generator moves the drawn faces' lips by a coarticulation model (Cohen &amp; "
        "Massaro, 1993): per phone a target and a dominance of each articulatory parameter, "
        "and the rates at which a phone's dominance rises before and decays after its centre. "
        "The hand-typed table was never compared with a real mouth. The fitted model was "
        f"estimated on the real speaker's {summary.get('training_clips', '?')} training "
        "sentences only (their tracked markers brought into the articulatory space through the "
        "generator's own face map, then targets, lip and jaw dominance, the two rates and the "
        f"power by least squares, the hand table as prior; <i>{escape(shipped.get('command'))}"
        f"</i>, file {escape(shipped.get('file'))}, sha256 "
        f"{escape((shipped.get('sha256') or '')[:12])}): θ before the centre "
        f"{_f(shipped.get('theta_anticipation'), 1)}/s, after {_f(shipped.get('theta_carryover'), 1)}/s, "
        f"power {_f(shipped.get('power'))} (the table: 16/s, 25/s, 1). {{label:articulation_table}} "
        f"scores each model on the {summary.get('held_out_clips', '?')} held-out sentences of "
        f"{escape(', '.join(summary.get('speaker', [])))}: the lips each draws from the true "
        "phones, before any mapping is trained, against the tracked lips (speech frames, "
        "z-scored per clip; /p b m/ closed by the face-evaluation rule; chance from circular "
        "shifts). The row <i>articulatory space</i> is the real lips' own projection: the most "
        "any coarticulation model on this face map can reach. Both models force the lips shut "
        "inside every /p b m/, so closure does not tell them apart.")
    body = [[escape(r["model"]), _f(r["r_opening"]), _f(r["chance_r_opening"]),
             _f(r["r_width"]), _f(r["chance_r_width"]), _f(r["closed"]),
             _f(r["chance_closed"]), _f(r.get("false_closed"))] for r in rows]
    rep.table("The hand table against the articulation fitted on the real speaker: held-out "
              "lips drawn from the true phones",
              ["model", "r opening", "chance", "r width", "chance", "/p b m/ closed", "chance",
               "false closures"], body, key="articulation_table",
              note=f"{rows[0]['speech_frames'] if rows else 0} speech frames of "
                   f"{summary.get('held_out_clips', '?')} clips, one speaker: no interval.")
