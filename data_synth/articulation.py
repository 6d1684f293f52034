"""Coarticulated articulatory trajectories from timed phones (Cohen & Massaro, 1993).

Each phone segment s has a target ``T_sp`` and a dominance magnitude ``alpha_sp`` per articulatory
parameter p (``face_model.phones``). Its dominance at time t is

    D_sp(t) = alpha_sp · exp(−θ · |τ|^c),   θ = θ_anticipation before the centre, θ_carry-over after,

with τ the distance (s) to the segment centre, and the trajectory is the dominance-weighted mean
``F_p(t) = Σ_s D_sp(t) T_sp / Σ_s D_sp(t)``. Silences hold full dominance over their whole extent
(τ counts from the segment's edge), so the face rests during pauses. Bilabial closure is forced
inside every /p b m/ segment so that it is never averaged away.
"""
from __future__ import annotations

import numpy as np

from face_model.phones import (
    ARTIC_PARAMS,
    BILABIALS,
    PHONE_INDEX,
    check_phone,
    dominance_matrix,
    target_matrix,
)
from groundwork.errors import ParameterError

_CLOSURE = ARTIC_PARAMS.index("closure")


def coarticulate(segments, times: np.ndarray, *, theta_anticipation: float = 16.0,
                 theta_carryover: float = 25.0, power: float = 1.0) -> np.ndarray:
    """Articulatory parameters at the given times.

    Parameters
    ----------
    segments : sequence of PhoneSegment
        Contiguous, time-ordered phone segments (44-class labels).
    times : ndarray, shape (n_frames,)
        Sample times in seconds (frame k at k / fps).
    theta_anticipation, theta_carryover : float
        Dominance decay rates in 1/s before and after a segment's centre.
    power : float
        The exponent c of |τ|.

    Returns
    -------
    ndarray, shape (n_frames, 7), in ``ARTIC_PARAMS`` order.
    """
    if theta_anticipation <= 0 or theta_carryover <= 0 or power <= 0:
        raise ParameterError(f"dominance rates and power must be positive, got "
                             f"{theta_anticipation}, {theta_carryover}, {power}")
    if len(segments) == 0:
        raise ParameterError("coarticulate: no phone segments")
    idx = np.array([PHONE_INDEX[check_phone(s.phone, source="coarticulate")] for s in segments])
    start = np.array([s.start_s for s in segments])
    end = np.array([s.end_s for s in segments])
    centre = 0.5 * (start + end)
    is_sil = np.array([s.phone == "sil" for s in segments])

    t = np.asarray(times, dtype=np.float64)[None, :]  # (1, n)
    signed = t - centre[:, None]  # (n_seg, n): negative before the centre
    dist = np.abs(signed)
    # Silences: distance from the nearest edge (0 inside).
    edge = np.maximum(start[:, None] - t, t - end[:, None]).clip(min=0.0)
    dist = np.where(is_sil[:, None], edge, dist)
    theta = np.where(signed < 0, theta_anticipation, theta_carryover)
    # log D = log alpha − θ|τ|^c; normalising by the per-time maximum before exp keeps the
    # weighted mean exact however far a time lies from every segment centre.
    log_decay = -theta * dist**power  # (n_seg, n)
    alpha = dominance_matrix()[idx]  # (n_seg, 7), all > 0
    target = target_matrix()[idx]  # (n_seg, 7)
    log_dom = np.log(alpha)[:, None, :] + log_decay[:, :, None]  # (n_seg, n, 7)
    dom = np.exp(log_dom - log_dom.max(axis=0, keepdims=True))
    traj = (dom * target[:, None, :]).sum(0) / dom.sum(0)

    bilabial = np.array([s.phone in BILABIALS for s in segments])
    if bilabial.any():
        inside = (t >= start[bilabial, None]) & (t < end[bilabial, None])
        traj[inside.any(0), _CLOSURE] = 1.0
    return traj
