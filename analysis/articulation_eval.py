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

from dataclasses import dataclass

import numpy as np

from analysis.face_eval import ClipTrack, score_clips
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
