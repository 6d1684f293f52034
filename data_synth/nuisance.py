"""Nuisances of a real recording: smooth head motion and marker measurement noise.

Head motion is a smooth 2D similarity transform (rotation, isotropic scale, translation — the
global motion of the paper's Eq. 5) applied to every marker, glasses included, so the glasses stay
rigid with the head and alignment by them can undo it. Each component is a sum of three slow
sinusoids with random frequencies (0.1–0.7 Hz) and phases, scaled to the configured magnitude.
"""
from __future__ import annotations

import numpy as np

from face_model.layout import FACE_CENTRE


def _smooth_signal(rng: np.random.Generator, n_frames: int, fps: int, amplitude: float) -> np.ndarray:
    t = np.arange(n_frames) / fps
    freq = rng.uniform(0.1, 0.7, 3)
    phase = rng.uniform(0, 2 * np.pi, 3)
    weight = rng.uniform(0.3, 1.0, 3)
    s = (weight[:, None] * np.sin(2 * np.pi * freq[:, None] * t + phase[:, None])).sum(0)
    return amplitude * s / weight.sum()


def head_motion(rng: np.random.Generator, n_frames: int, fps: int, *, rotation_deg: float,
                scale: float, translation_px: float) -> np.ndarray:
    """Per-frame similarity parameters, shape (n_frames, 4): angle (rad), scale, tx, ty (px)."""
    angle = np.deg2rad(_smooth_signal(rng, n_frames, fps, rotation_deg))
    s = 1.0 + _smooth_signal(rng, n_frames, fps, scale)
    tx = _smooth_signal(rng, n_frames, fps, translation_px)
    ty = _smooth_signal(rng, n_frames, fps, translation_px * 0.6)
    return np.stack([angle, s, tx, ty], axis=1)


def apply_head_motion(points: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """Apply per-frame similarity ``motion`` (n_frames, 4) about the face centre to ``points``
    (n_frames, n_markers, 2)."""
    c = np.asarray(FACE_CENTRE)
    ang, s, tx, ty = motion.T
    cos, sin = np.cos(ang) * s, np.sin(ang) * s
    rot = np.stack([np.stack([cos, -sin], -1), np.stack([sin, cos], -1)], -2)  # (n, 2, 2)
    out = np.einsum("nij,nmj->nmi", rot, points - c) + c
    return out + np.stack([tx, ty], -1)[:, None, :]


def add_marker_noise(rng: np.random.Generator, points: np.ndarray, sd_px: float) -> np.ndarray:
    """I.i.d. Gaussian measurement noise of ``sd_px`` pixels on every coordinate."""
    return points + sd_px * rng.standard_normal(points.shape)


def brow_track(audio: np.ndarray, n_frames: int, hop: int) -> np.ndarray:
    """Prosodic brow raise in [0, 1] per frame: the smoothed frame energy of the speech, so the
    brows lift a little on loud (accented) stretches. ``audio`` is float, ``hop`` samples/frame."""
    pad = np.zeros(n_frames * hop)
    k = min(len(audio), len(pad))
    pad[:k] = audio[:k]
    rms = np.sqrt((pad.reshape(n_frames, hop) ** 2).mean(1))
    kernel = np.hanning(9)
    kernel /= kernel.sum()
    smooth = np.convolve(rms, kernel, mode="same")
    peak = smooth.max()
    return smooth / peak if peak > 0 else smooth
