"""Frame-level scores of a lip track on labelled real speech (DESIGN.md, "Evaluation on real
data": lip scores measure speech), shared by the models, the recognisers and the peers.

Frames. Frame k sits at k / fps seconds (the corpus convention); its true phone is the labelled
segment holding that instant (:func:`phone_frames`). A recording of n samples at sr Hz has
``ceil(n·fps/sr)`` frames (:func:`label_frames`); a prediction may differ from that by the one
frame its own rounding explains (:data:`FRAME_SLACK`), and is cut or edge-padded to it
(:func:`fit_frames`); more is an error.

Speech-frame correlation (:func:`speech_r_terms`). On the frames whose phone is not ``sil``,
each clip's prediction and reference are centred and scaled (z-scores over that clip's speech
frames); the pooled r is the mean product over every speech frame of every clip, i.e.
``sum(terms) / sum(frames)`` — the frame-weighted mean of per-clip r, each clip counting its
own shape and not its level. A clip constant over its speech frames contributes 0 (per clip:
NaN). Silence frames are reported apart (:func:`silence_opening`).

Chance baseline (:func:`chance_scores`). The same prediction circularly shifted by each of
:data:`CHANCE_SHIFTS` of its length (a third back, a half, a third on) and scored the same way:
what a track with the prediction's own statistics but no alignment to this speech earns. It
reuses the prediction; nothing is re-run.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from face_model.phones import BILABIALS, PHONE_INDEX, PHONES, VISEMES, viseme
from groundwork.errors import ParameterError

VOWELS = frozenset("iy ih ey eh ae aa ah ax ay aw ao ow oy uw uh er".split())
LABIODENTALS = frozenset({"f", "v"})
SIL = PHONE_INDEX["sil"]
CHANCE_SHIFTS = (-1 / 3, 1 / 2, 1 / 3)  # fractions of a clip's length
FRAME_SLACK = 1  # frames a prediction may differ from ceil(n·fps/sr) by (its own rounding)
_VISEME_OF_PHONE = np.array([VISEMES.index(viseme(p)) for p in PHONES])
CLOSED_VISEME = VISEMES.index("m")


def phone_frames(segments, times: np.ndarray) -> np.ndarray:
    """Phone index (into ``PHONES``) of the segment holding each time; times past the last
    segment take the last one."""
    ends = np.array([s.end_s for s in segments])
    idx = np.minimum(np.searchsorted(ends, np.asarray(times), side="right"), len(segments) - 1)
    return np.array([PHONE_INDEX[segments[i].phone] for i in idx], dtype=int)


def viseme_index(phone_idx: np.ndarray) -> np.ndarray:
    """Viseme (index into ``VISEMES``) of each phone index."""
    return _VISEME_OF_PHONE[np.asarray(phone_idx, dtype=int)]


def group_viseme(name: str) -> int:
    """Viseme index of a gate class name: a phone, or a group of the 8-class gate
    (``other`` and ``sil`` are neutral)."""
    if name in PHONE_INDEX:
        return int(_VISEME_OF_PHONE[PHONE_INDEX[name]])
    return VISEMES.index(name if name in VISEMES else "neutral")


def frame_accuracy(true: np.ndarray, pred: np.ndarray) -> float:
    """Fraction of frames where ``pred`` equals ``true`` (NaN for no frames)."""
    true, pred = np.asarray(true), np.asarray(pred)
    return float(np.mean(true == pred)) if len(true) else float("nan")


def label_frames(n_samples: int, sr: int, fps: float) -> int:
    """Frames of a recording of ``n_samples`` at ``sr`` Hz: ``ceil(n·fps/sr)``."""
    return int(np.ceil(n_samples * fps / sr))


def fit_frames(track: np.ndarray, n: int, *, what: str) -> np.ndarray:
    """``track`` (m, ...) cut or edge-padded to ``n`` frames when ``|m − n| ≤``
    :data:`FRAME_SLACK`; a larger mismatch is a :class:`ParameterError` naming ``what``."""
    track = np.asarray(track)
    m = len(track)
    if abs(m - n) > FRAME_SLACK:
        raise ParameterError(f"{what}: {m} frames predicted for labels of {n} frames; allowed: "
                             f"within {FRAME_SLACK} (the rounding of ceil(n·fps/sr))")
    if m >= n:
        return track[:n]
    return np.concatenate([track, np.repeat(track[-1:], n - m, axis=0)]) if m else track


@dataclass(frozen=True)
class Contact:
    """Per-segment result of :func:`segment_contact`: whether the lips met and the opening at
    the segment's centre (px), one entry per segment of the chosen phones."""

    met: np.ndarray
    centre_opening: np.ndarray

    @property
    def n(self) -> int:
        return len(self.met)

    @property
    def fraction(self) -> float:
        return float(self.met.mean()) if self.n else float("nan")


def _segment_frames(s, times: np.ndarray, fps: float) -> np.ndarray:
    """Frames whose span [t − 1/2fps, t + 1/2fps) overlaps segment ``s`` (the frame nearest its
    centre for a shorter segment)."""
    half = 0.5 / fps
    k = np.flatnonzero((times + half > s.start_s) & (times - half < s.end_s))
    if len(k) == 0:
        k = np.array([int(np.clip(round(0.5 * (s.start_s + s.end_s) * fps), 0,
                                  len(times) - 1))])
    return k


def segment_contact(opening: np.ndarray, fps: float, segments, phones, threshold: float
                    ) -> Contact:
    """For each segment whose phone is in ``phones``: do the lips meet (``opening`` ≤
    ``threshold`` in a frame whose span [t − 1/2fps, t + 1/2fps) overlaps the segment, or in the
    frame nearest the centre of a shorter segment), and the opening at its centre (linear
    interpolation). ``opening`` (n_frames,) pixels, frame k at k / fps s."""
    opening = np.asarray(opening, dtype=np.float64)
    times = np.arange(len(opening)) / fps
    met, centre = [], []
    for s in segments:
        if s.phone not in phones:
            continue
        met.append(bool(np.min(opening[_segment_frames(s, times, fps)]) <= threshold))
        centre.append(float(np.interp(0.5 * (s.start_s + s.end_s), times, opening)))
    return Contact(np.array(met, dtype=bool), np.array(centre))


def viseme_contact(visemes: np.ndarray, fps: float, segments, phones) -> np.ndarray:
    """For a track of visemes (indices into ``VISEMES``): per segment of ``phones``, whether
    the closed viseme ``m`` is shown in a frame overlapping it (the closure of a tool that
    gives visemes, not pixels)."""
    visemes = np.asarray(visemes)
    times = np.arange(len(visemes)) / fps
    return np.array([bool(np.any(visemes[_segment_frames(s, times, fps)] == CLOSED_VISEME))
                     for s in segments if s.phone in phones], dtype=bool)


def vowel_median(opening: np.ndarray, phone_idx: np.ndarray) -> float:
    """Median opening over the frames labelled with a vowel (NaN if there are none)."""
    sel = np.isin(np.asarray(phone_idx), [PHONE_INDEX[p] for p in VOWELS])
    return float(np.median(np.asarray(opening)[sel])) if sel.any() else float("nan")


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson's r of two equal-length tracks (NaN when either is constant)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if len(a) != len(b):
        raise ParameterError(f"tracks of {len(a)} and {len(b)} frames cannot be correlated")
    if len(a) < 2 or np.std(a) == 0 or np.std(b) == 0:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1])


def _z(x: np.ndarray) -> np.ndarray:
    sd = np.std(x)
    return (x - np.mean(x)) / sd if len(x) and sd > 0 else np.zeros_like(x)


def speech_r_terms(pred: np.ndarray, ref: np.ndarray, true_phone: np.ndarray
                   ) -> tuple[float, int]:
    """``(sum of z-score products, speech frames)`` of one clip (see the module docstring):
    the pooled r over clips is ``sum(terms) / sum(frames)``."""
    pred, ref = np.asarray(pred, np.float64), np.asarray(ref, np.float64)
    if not (len(pred) == len(ref) == len(true_phone)):
        raise ParameterError(f"tracks of {len(pred)}, {len(ref)} and {len(true_phone)} frames "
                             "cannot be scored together")
    sel = np.asarray(true_phone) != SIL
    return float(np.sum(_z(pred[sel]) * _z(ref[sel]))), int(sel.sum())


def silence_opening(opening: np.ndarray, true_phone: np.ndarray) -> np.ndarray:
    """The openings of the frames labelled ``sil`` (reported apart from speech)."""
    return np.asarray(opening, np.float64)[np.asarray(true_phone) == SIL]


def shifts(n: int) -> list[int]:
    """The circular shifts (frames) of :data:`CHANCE_SHIFTS` for a clip of ``n`` frames
    (non-zero; one frame at least)."""
    return [int(np.sign(f)) * max(1, int(round(abs(f) * n))) for f in CHANCE_SHIFTS]


@dataclass(frozen=True)
class ChanceTerms:
    """One clip's chance-baseline numerators, summed over the shifts of :func:`shifts` (their
    denominators are the clip's frames, segments and speech frames times the number of
    shifts)."""

    viseme_hits: float
    closed: float
    r_terms: float
    n_shifts: int


def chance_scores(true_phone: np.ndarray, fps: float, segments, *, visemes=None, opening=None,
                  reference=None, threshold: float | None = None) -> ChanceTerms:
    """The chance baseline of one clip's prediction (``visemes`` (n,) indices into
    ``VISEMES`` and/or ``opening`` (n,) with its ``reference`` and closed ``threshold``):
    every score recomputed on the prediction circularly shifted by each of :func:`shifts`.
    Closure counts on the opening when given, else on the visemes (:func:`viseme_contact`)."""

    n = len(true_phone)
    vis_true = viseme_index(true_phone)
    hits = closed = terms = 0.0
    ks = shifts(n)
    for k in ks:
        if visemes is not None:
            hits += float(np.sum(np.roll(visemes, k) == vis_true))
        if opening is not None:
            o = np.roll(opening, k)
            closed += float(segment_contact(o, fps, segments, BILABIALS, threshold).met.sum())
            if reference is not None:
                terms += speech_r_terms(o, reference, true_phone)[0]
        elif visemes is not None:
            closed += float(viseme_contact(np.roll(visemes, k), fps, segments,
                                           BILABIALS).sum())
    return ChanceTerms(hits, closed, terms, len(ks))
