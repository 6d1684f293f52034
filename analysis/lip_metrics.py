"""Lip and face metrics beside the paper's R, ν and MSE (issue 13, part 3).

R over all 158 coordinates, each divided by its maximum, weighs a forehead coordinate that
barely moves as much as a lip corner. These measure where viewers look:

* **LVE** (lip vertex error; VOCA, Cudeiro et al. 2019; FaceFormer, Fan et al. 2022): per frame
  the largest Euclidean error over the 30 lip markers (46–75), in pixels, averaged over frames.
* **FDD** (upper-face dynamics deviation; CodeTalker, Xing et al. 2023): per utterance and
  forehead marker (0–21), the standard deviation over time of the length of its displacement
  (its *dynamics*); FDD is the true dynamics minus the estimated, averaged over the markers and
  then over utterances, in pixels. Positive: the estimate moves the brows less than the truth.
* **Per-region R**: Eq. 6 on the normalised coordinates of one region (lips, cheeks, forehead).
* **Closure on /p b m/**: the fraction of bilabial segments (runs of frames labelled p, b or m)
  in which the estimated inner lips meet in some frame of the segment: the mouth opening
  (:func:`face_model.layout.mouth_opening`) of the displacement alone is at most 0, i.e. the
  lips are no further apart than in the neutral face, the generator's closed mouth
  (:mod:`analysis.speech_eval` uses the same rule on real speech). The opening is linear in the
  markers, so the neutral face cancels. A segment belongs to the part (training or test) of its
  middle frame.

Displacements are (n_frames, 158) pixels, x/y interleaved per marker (``units.inverse_transform``).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from analysis.metrics import pearson_r
from face_model.layout import N_MARKERS, REGIONS, mouth_opening
from face_model.phones import BILABIALS, PHONE_INDEX
from groundwork.errors import ParameterError

LIP_REGIONS = ("lips", "cheeks", "forehead")
LIP_METRIC_NAMES = ("LVE", "FDD", "R_lips", "R_cheeks", "R_forehead", "closure",
                    "closure_true", "bilabial_segments")
_BILABIAL_INDEX = np.array(sorted(PHONE_INDEX[p] for p in BILABIALS))


def _markers(d) -> np.ndarray:
    d = np.asarray(d, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != 2 * N_MARKERS:
        raise ParameterError(f"displacements must be (n_frames, {2 * N_MARKERS}), got {d.shape}")
    return d.reshape(len(d), N_MARKERS, 2)


def lip_vertex_error(d, d_est) -> float:
    """LVE (px): mean over frames of the largest lip-marker position error."""
    t, e = _markers(d), _markers(d_est)
    if t.shape != e.shape or len(t) == 0:
        raise ParameterError(f"truth {t.shape} and estimate {e.shape} must have one shape with "
                             "frames")
    lips = list(REGIONS["lips"])
    return float(np.linalg.norm(t[:, lips] - e[:, lips], axis=2).max(axis=1).mean())


def dynamics(d, markers=REGIONS["forehead"]) -> np.ndarray:
    """Per marker of ``markers``: the standard deviation over frames of the length of its
    displacement (px), shape (len(markers),)."""
    return np.linalg.norm(_markers(d)[:, list(markers)], axis=2).std(axis=0)


def dynamics_deviation(truths: list, estimates: list, markers=REGIONS["forehead"]) -> float:
    """FDD (px): true minus estimated :func:`dynamics`, averaged over ``markers`` and then over
    the utterances (``truths`` and ``estimates``: one displacement array each)."""
    if len(truths) != len(estimates) or not truths:
        raise ParameterError(f"need as many estimates as truths (at least one), got "
                             f"{len(truths)} and {len(estimates)}")
    return float(np.mean([np.mean(dynamics(t, markers) - dynamics(e, markers))
                          for t, e in zip(truths, estimates)]))


def region_r(d, d_est, scale, region: str) -> float:
    """Eq. 6 on the coordinates of one region of the layout, after dividing by ``scale``
    (NaN when the truth or the estimate does not move there)."""
    if region not in REGIONS:
        raise ParameterError(f"unknown region {region!r}; allowed: {', '.join(REGIONS)}")
    cols = np.array([2 * m + k for m in REGIONS[region] for k in (0, 1)])
    s = np.asarray(scale, dtype=np.float64)[cols]
    t, e = np.asarray(d)[:, cols] / s, np.asarray(d_est)[:, cols] / s
    if np.ptp(t, axis=0).max() == 0 or np.ptp(e, axis=0).max() == 0:
        return float("nan")
    return pearson_r(t, e)


def bilabial_segments(phones: np.ndarray) -> list[tuple[int, int]]:
    """``[(first, stop)]`` frame ranges of the runs of bilabial labels in per-frame phone
    indices."""
    is_b = np.isin(np.asarray(phones), _BILABIAL_INDEX)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], is_b.astype(int), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def closure(d, phones, use=None) -> tuple[int, int]:
    """``(closed, segments)`` over the bilabial segments of ``phones`` (per frame) whose middle
    frame is in ``use`` (all when None): closed when the mouth opening of the displacement
    ``d`` is at most 0 in a frame of the segment."""
    opening = mouth_opening(_markers(d))
    segs = bilabial_segments(phones)
    if use is not None:
        segs = [(a, b) for a, b in segs if use[(a + b - 1) // 2]]
    return sum(bool(np.any(opening[a:b] <= 0)) for a, b in segs), len(segs)


@dataclass(frozen=True)
class LipMetrics:
    """The lip and face figures of one set (see the module docstring); ``closure_true`` is the
    same rule on the ground truth (the generator's own closure, near 1)."""

    LVE: float
    FDD: float
    R_lips: float
    R_cheeks: float
    R_forehead: float
    closure: float
    closure_true: float
    bilabial_segments: int

    def as_dict(self) -> dict:
        return asdict(self)


def lip_metrics(truths: list, estimates: list, phones: list, uses: list, scale) -> LipMetrics:
    """The figures of one set: per utterance its true and estimated displacements (all frames),
    its phone index per frame and the boolean mask of the set's frames in it."""
    t_all = [np.asarray(t)[u] for t, u in zip(truths, uses) if np.any(u)]
    e_all = [np.asarray(e)[u] for e, u in zip(estimates, uses) if np.any(u)]
    if not t_all:
        raise ParameterError("no frames in the set")
    t, e = np.concatenate(t_all), np.concatenate(e_all)
    closed = [closure(es, ph, u) for es, ph, u in zip(estimates, phones, uses)]
    closed_true = [closure(tr, ph, u) for tr, ph, u in zip(truths, phones, uses)]
    n = sum(k for _, k in closed)
    frac = (lambda c: sum(a for a, _ in c) / n) if n else (lambda c: float("nan"))
    return LipMetrics(LVE=lip_vertex_error(t, e), FDD=dynamics_deviation(t_all, e_all),
                      **{f"R_{r}": region_r(t, e, scale, r) for r in LIP_REGIONS},
                      closure=frac(closed), closure_true=frac(closed_true), bilabial_segments=n)
