"""Intervals on real data with the speaker as the unit (DESIGN.md, "Evaluation on real data").

Recordings of one speaker are not independent: they share a voice, an accent, a microphone and
a room. A percentile bootstrap that resamples recordings as if they were independent makes a
set dominated by one speaker look precise when it says little about the next speaker. Here the
resampling is two-stage (a cluster bootstrap; Davison & Hinkley 1997, §3.8, strategy 2): draw
the speakers with replacement, then, within each drawn speaker, draw its recordings with
replacement; the figure is recomputed on the pooled draw. With fewer than :data:`MIN_SPEAKERS`
speakers there is no interval: the spread between two speakers says nothing about a third, and
the result says so (:attr:`Interval.reason`).

A figure is a ratio of sums over recordings (hits / frames, closed / segments): each record
carries its numerator and weight, so a draw pools exactly as the unresampled figure does.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from groundwork.errors import ParameterError

MIN_SPEAKERS = 3
N_BOOT = 2000
SEED = 2002
LEVEL = 0.95


@dataclass(frozen=True)
class Interval:
    """A percentile interval ``(lo, hi)``, or ``None`` with the reason there is none."""

    lo: float | None
    hi: float | None
    speakers: int
    recordings: int
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.lo is not None

    def text(self, digits: int = 2) -> str:
        """``[lo, hi]``, or the reason in brackets."""
        if not self.ok:
            return f"(no interval: {self.reason})"
        return f"[{self.lo:.{digits}f}, {self.hi:.{digits}f}]"


def _check(speakers, hits, weights) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    speakers = np.asarray(speakers, dtype=object)
    hits = np.asarray(hits, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    if not (len(speakers) == len(hits) == len(weights)):
        raise ParameterError(f"speakers, hits and weights must have one entry per recording, got "
                             f"{len(speakers)}, {len(hits)} and {len(weights)}")
    if len(weights) and (not np.all(np.isfinite(weights)) or np.any(weights < 0)):
        raise ParameterError("weights must be finite and non-negative")
    return speakers, hits, weights


def pooled(hits, weights) -> float:
    """sum(hits) / sum(weights) (NaN when the weights sum to 0)."""
    w = float(np.sum(weights))
    return float(np.sum(hits) / w) if w > 0 else float("nan")


def _draws(groups: list[np.ndarray], n_boot: int, rng) -> list[np.ndarray]:
    """``n_boot`` index arrays: speakers drawn with replacement, then recordings within each."""
    out = []
    for _ in range(n_boot):
        picked = rng.integers(0, len(groups), size=len(groups))
        out.append(np.concatenate([g[rng.integers(0, len(g), size=len(g))]
                                   for g in (groups[i] for i in picked)]))
    return out


def _percentiles(boots: np.ndarray, level: float) -> tuple[float, float] | None:
    boots = boots[np.isfinite(boots)]
    if not boots.size:
        return None
    lo, hi = np.quantile(boots, [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi)


def speaker_interval(speakers, hits, weights, *, n_boot: int = N_BOOT, seed: int = SEED,
                     level: float = LEVEL, min_speakers: int = MIN_SPEAKERS) -> Interval:
    """The two-stage bootstrap interval of ``sum(hits) / sum(weights)``.

    Parameters
    ----------
    speakers : sequence of str, (n_recordings,)
        Each recording's speaker id.
    hits, weights : array-like, (n_recordings,)
        Each recording's numerator and denominator (e.g. frames right and frames; for a mean of
        per-recording values, the value and 1).
    n_boot, seed, level :
        Resamples, the generator's seed, and the interval's coverage.
    min_speakers : int
        Fewer distinct speakers give no interval (``Interval.reason`` says why).

    Returns
    -------
    Interval
    """
    speakers, hits, weights = _check(speakers, hits, weights)
    finite = np.isfinite(hits)
    speakers, hits, weights = speakers[finite], hits[finite], weights[finite]
    names = sorted(set(speakers.tolist()))
    n_spk, n_rec = len(names), len(speakers)
    if n_spk < min_speakers:
        return Interval(None, None, n_spk, n_rec,
                        f"{n_spk} speaker{'s' if n_spk != 1 else ''}; an interval needs at "
                        f"least {min_speakers}")
    groups = [np.flatnonzero(speakers == s) for s in names]
    rng = np.random.default_rng(seed)
    boots = np.array([pooled(hits[i], weights[i]) for i in _draws(groups, n_boot, rng)])
    p = _percentiles(boots, level)
    if p is None:
        return Interval(None, None, n_spk, n_rec, "no finite resample")
    return Interval(p[0], p[1], n_spk, n_rec)


def recording_interval(hits, weights, *, n_boot: int = N_BOOT, seed: int = SEED,
                       level: float = LEVEL) -> Interval:
    """The one-stage bootstrap that treats recordings as independent (for comparison only:
    it is too narrow when one speaker dominates)."""
    hits = np.asarray(hits, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    keep = np.isfinite(hits)
    hits, weights = hits[keep], weights[keep]
    if len(hits) < 2:
        return Interval(None, None, 0, len(hits), "fewer than 2 recordings")
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(hits), size=(n_boot, len(hits)))
    with np.errstate(invalid="ignore", divide="ignore"):
        boots = hits[picks].sum(1) / weights[picks].sum(1)
    p = _percentiles(boots, level)
    return (Interval(None, None, 0, len(hits), "no finite resample") if p is None
            else Interval(p[0], p[1], 0, len(hits)))


def paired_speaker_interval(speakers, hits_a, hits_b, weights, **kw) -> Interval:
    """Interval of the difference ``pooled(a) − pooled(b)`` of two systems scored on the same
    recordings (the same draws for both): a comparison of two models on the same speakers."""
    speakers, hits_a, weights = _check(speakers, hits_a, weights)
    hits_b = np.asarray(hits_b, dtype=np.float64)
    if len(hits_b) != len(hits_a):
        raise ParameterError(f"hits_a and hits_b must have one entry per recording, got "
                             f"{len(hits_a)} and {len(hits_b)}")
    finite = np.isfinite(hits_a) & np.isfinite(hits_b)
    speakers, hits_a, hits_b, weights = (speakers[finite], hits_a[finite], hits_b[finite],
                                         weights[finite])
    names = sorted(set(speakers.tolist()))
    min_speakers = kw.get("min_speakers", MIN_SPEAKERS)
    if len(names) < min_speakers:
        return Interval(None, None, len(names), len(speakers),
                        f"{len(names)} speaker{'s' if len(names) != 1 else ''}; an interval "
                        f"needs at least {min_speakers}")
    groups = [np.flatnonzero(speakers == s) for s in names]
    rng = np.random.default_rng(kw.get("seed", SEED))
    boots = np.array([pooled(hits_a[i], weights[i]) - pooled(hits_b[i], weights[i])
                      for i in _draws(groups, kw.get("n_boot", N_BOOT), rng)])
    p = _percentiles(boots, kw.get("level", LEVEL))
    if p is None:
        return Interval(None, None, len(names), len(speakers), "no finite resample")
    return Interval(p[0], p[1], len(names), len(speakers))
