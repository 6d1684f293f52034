"""The parametric 2D face: speakers, articulation → marker displacement, expressions.

Displacement fields are smooth functions of each marker's neutral position (lips most; cheeks
follow the jaw and the lip corners; the brows move a little with prosody). Expressions are
displacement fields with a time envelope that also *change the articulation*: a smile widens the
lips and damps rounding, sadness lowers the corners and reduces jaw excursion. The expression
residual is therefore not a constant offset, which is what the paper's Expression MUs and the
expression cascade have to learn.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from face_model.layout import (
    FACE_CENTRE,
    LOWER_INNER,
    LOWER_OUTER,
    MOUTH_CENTRE_Y,
    MOUTH_HALF_WIDTH,
    UPPER_INNER,
    UPPER_OUTER,
    default_layout,
)
from face_model.phones import ARTIC_PARAMS

_P = {name: i for i, name in enumerate(ARTIC_PARAMS)}


@dataclass(frozen=True)
class Speaker:
    """A synthetic speaker: face shape, articulation gains and voice.

    ``neutral`` (79, 2) is this speaker's neutral face in pixels; ``gains`` (7,) scale the
    articulatory displacement fields; ``expression_gain`` scales smile/sad fields.
    """

    index: int
    neutral: np.ndarray
    gains: np.ndarray
    expression_gain: float
    voice: str
    rate_wpm: int
    pitch: int


_VARIANTS = ("m3", "f2", "m1", "f4", "m5", "f1", "m7", "f3", "m2", "f5", "m4", "m6")


def make_speaker(index: int, cfg, seed: int) -> Speaker:
    """Speaker ``index``: index 0 uses the configured voice exactly; every face shape is drawn
    from ``seed`` (so the same seed gives the same speakers)."""
    rng = np.random.default_rng([seed, 7919, index])
    lay = default_layout()
    centre = np.asarray(FACE_CENTRE)
    rel = lay.neutral - centre
    scale = 1.0 + cfg.speaker_scale_sd * rng.standard_normal()
    aspect = 1.0 + 0.5 * cfg.speaker_scale_sd * rng.standard_normal()
    mouth = 1.0 + 1.5 * cfg.speaker_scale_sd * rng.standard_normal()
    shaped = rel * np.array([scale, scale * aspect])
    lips = lay.region == "lips"
    shaped[lips, 0] *= mouth
    # Smooth per-speaker shape offsets: a few random low-order polynomial fields.
    x, y = rel[:, 0] / 100.0, rel[:, 1] / 100.0
    basis = np.stack([x, y, x * y, x**2, y**2], axis=1)
    coef = rng.standard_normal((5, 2)) * cfg.speaker_shape_sd_px
    shaped += basis @ coef
    shaped[lay.region == "glasses"] = rel[lay.region == "glasses"] * scale
    if index == 0:
        voice, rate, pitch = cfg.voice, cfg.rate_wpm, cfg.pitch
    else:
        lang = cfg.voice.split("+")[0]
        voice = f"{lang}+{_VARIANTS[index % len(_VARIANTS)]}"
        rate = int(round(cfg.rate_wpm + cfg.speaker_rate_sd * rng.standard_normal()))
        pitch = int(np.clip(round(cfg.pitch + cfg.speaker_pitch_sd * rng.standard_normal()), 5, 95))
    gains = np.clip(1.0 + cfg.speaker_gain_sd * rng.standard_normal(len(ARTIC_PARAMS)), 0.5, 1.5)
    eg = float(np.clip(1.0 + cfg.speaker_gain_sd * rng.standard_normal(), 0.5, 1.5))
    return Speaker(index, shaped + centre, gains, eg, voice, rate, pitch)


def displacement_fields(neutral: np.ndarray, cfg) -> dict[str, np.ndarray]:
    """Displacement fields (79, 2) in pixels for unit parameter values, from neutral positions
    (``jaw_lips jaw_face aperture spread protrusion upper_raise lower_tuck press brow``)."""
    lay = default_layout()
    rel = neutral - np.asarray(FACE_CENTRE)
    x, y = rel[:, 0], rel[:, 1]
    n = len(rel)
    lips = lay.region == "lips"
    cheeks = lay.region == "cheeks"
    fore = lay.region == "forehead"
    u = np.clip(x / MOUTH_HALF_WIDTH, -1.0, 1.0)
    prof = np.sqrt(np.clip(1.0 - u**2, 0.0, 1.0))
    upper = np.zeros(n, bool)
    upper[list(UPPER_OUTER) + list(UPPER_INNER)] = True
    lower = np.zeros(n, bool)
    lower[list(LOWER_OUTER) + list(LOWER_INNER)] = True
    inner = np.zeros(n, bool)
    inner[list(UPPER_INNER) + list(LOWER_INNER)] = True
    corner = lips & ~upper & ~lower
    dy_mouth = y - MOUTH_CENTRE_Y
    near_mouth = np.exp(-((np.abs(x) - 45.0) ** 2 + dy_mouth**2) / (2 * 35.0**2))

    f = {k: np.zeros((n, 2)) for k in ("jaw_lips", "jaw_face", "aperture", "spread", "protrusion",
                                         "upper_raise", "lower_tuck", "press", "brow")}
    # Jaw: the lower lip rides on the jaw; the corners half; chin and lower cheeks follow.
    f["jaw_lips"][lower, 1] = 0.6 + 0.4 * prof[lower]
    f["jaw_lips"][corner, 1] = 0.45
    f["jaw_lips"][upper, 1] = 0.08
    w_cheek = np.clip((y - 10.0) / 85.0, 0.0, 1.0) ** 1.3
    f["jaw_face"][cheeks, 1] = 0.85 * w_cheek[cheeks]
    f["jaw_face"][cheeks, 0] = -0.06 * np.sign(x[cheeks]) * w_cheek[cheeks]
    # Aperture: lips part, inner contour more than outer.
    f["aperture"][upper & inner, 1] = -0.45 * prof[upper & inner]
    f["aperture"][lower & inner, 1] = 0.55 * prof[lower & inner]
    f["aperture"][upper & ~inner, 1] = -0.3 * prof[upper & ~inner]
    f["aperture"][lower & ~inner, 1] = 0.4 * prof[lower & ~inner]
    # Spread: the mouth widens about its centre and thins; cheeks near the corners follow.
    f["spread"][lips, 0] = u[lips]
    f["spread"][upper & ~inner, 1] = 0.15 * prof[upper & ~inner]
    f["spread"][lower & ~inner, 1] = -0.15 * prof[lower & ~inner]
    f["spread"][cheeks, 0] = 0.3 * np.sign(x[cheeks]) * near_mouth[cheeks]
    # Protrusion / rounding: the mouth narrows and becomes rounder.
    f["protrusion"][lips, 0] = -0.8 * u[lips]
    f["protrusion"][upper & ~inner, 1] = -0.25 * prof[upper & ~inner]
    f["protrusion"][lower & ~inner, 1] = 0.15 * prof[lower & ~inner]
    f["protrusion"][cheeks, 0] = -0.15 * np.sign(x[cheeks]) * near_mouth[cheeks]
    f["upper_raise"][upper, 1] = -(0.5 + 0.5 * prof[upper])
    f["lower_tuck"][lower, 1] = -(0.5 + 0.5 * prof[lower])
    f["lower_tuck"][lower & inner, 1] *= 1.1
    # Bilabial press: upper and lower lips meet and compress.
    f["press"][upper, 1] = 1.0 * prof[upper]
    f["press"][lower, 1] = -1.0 * prof[lower]
    # Brows: the brow row most, the forehead less.
    f["brow"][fore, 1] = -np.where(y[fore] > -80, 1.0, np.where(y[fore] > -110, 0.6, 0.35))
    gains = {"jaw_lips": cfg.jaw_px, "jaw_face": cfg.jaw_px, "aperture": cfg.aperture_px,
             "spread": cfg.spread_px, "protrusion": cfg.protrusion_px,
             "upper_raise": cfg.upper_raise_px, "lower_tuck": cfg.lower_tuck_px, "press": 1.2,
             "brow": cfg.brow_px}
    return {k: v * gains[k] for k, v in f.items()}


def expression_fields(neutral: np.ndarray) -> dict[str, np.ndarray]:
    """Smile and sad displacement fields (79, 2), pixels at full intensity."""
    lay = default_layout()
    rel = neutral - np.asarray(FACE_CENTRE)
    x, y = rel[:, 0], rel[:, 1]
    lips = lay.region == "lips"
    cheeks = lay.region == "cheeks"
    brows = np.zeros(len(rel), bool)
    brows[:8] = True
    u = np.clip(x / MOUTH_HALF_WIDTH, -1.0, 1.0)
    dy_mouth = y - MOUTH_CENTRE_Y
    smile = np.zeros_like(rel)
    smile[lips, 0] = 7.0 * u[lips]
    smile[lips, 1] = -6.0 * np.abs(u[lips]) ** 1.5 - 1.0
    raise_ = np.exp(-((np.abs(x) - 60.0) ** 2 + (y - 35.0) ** 2) / (2 * 32.0**2))
    smile[cheeks, 1] = -5.0 * raise_[cheeks]
    smile[cheeks, 0] = 2.0 * np.sign(x[cheeks]) * raise_[cheeks]
    smile[brows, 1] = 0.5
    sad = np.zeros_like(rel)
    sad[lips, 1] = 5.0 * np.abs(u[lips]) ** 2
    sad[lips, 0] = -1.5 * u[lips]
    centre_lower = lips & (dy_mouth > 3) & (np.abs(u) < 0.6)
    sad[centre_lower, 1] -= 1.5  # the chin pushes the lower lip up (a pout)
    inner_brow = brows & (np.abs(x) < 45)
    sad[inner_brow, 1] = -4.0 * (1.0 - np.abs(x[inner_brow]) / 45.0) - 0.5
    sad[inner_brow, 0] = -1.5 * np.sign(x[inner_brow])
    sad[brows & ~inner_brow, 1] = 1.5
    sad[cheeks, 1] = 1.0 * np.clip(dy_mouth[cheeks] / 40.0, 0, 1)
    return {"smile": smile, "sad": sad}


def expression_envelope(n_frames: int, fps: int, *, onset_s: float, offset_s: float,
                        intensity: float, delay_s: float = 0.0) -> np.ndarray:
    """Raised-cosine onset, hold, and offset to 30 % of the peak at the last frame."""
    t = np.arange(n_frames) / fps
    dur = n_frames / fps
    rise = np.clip((t - delay_s) / onset_s, 0.0, 1.0)
    fall = np.clip((dur - t) / offset_s, 0.0, 1.0)
    ramp = lambda v: 0.5 - 0.5 * np.cos(np.pi * v)  # noqa: E731
    return intensity * ramp(rise) * (0.3 + 0.7 * ramp(fall))


def articulate(speaker: Speaker, artic: np.ndarray, brow: np.ndarray, *, expression: str,
               envelope: np.ndarray, cfg) -> np.ndarray:
    """Marker positions (n_frames, 79, 2) in the speaker's face frame (no head motion, no noise).

    ``artic`` (n_frames, 7) are the coarticulated parameters, ``brow`` (n_frames,) the prosodic
    brow raise in [0, 1], ``envelope`` (n_frames,) the expression intensity (zeros if neutral).
    """
    a = artic * speaker.gains[None, :]
    e = envelope * speaker.expression_gain if expression != "neutral" else np.zeros(len(a))
    col = lambda name: a[:, _P[name]].copy()  # noqa: E731
    jaw, ap, spread, prot = col("jaw"), col("aperture"), col("spread"), col("protrusion")
    if expression == "smile":
        prot_raw = prot.copy()
        prot *= 1.0 - cfg.smile_rounding_damping * e
        spread = spread + cfg.smile_widening * e * (1.0 - np.clip(prot_raw, 0, 1))
        ap *= 1.0 + 0.25 * e
    elif expression == "sad":
        jaw *= 1.0 - cfg.sad_jaw_reduction * e
        ap *= 1.0 - 0.2 * e
        spread *= 1.0 - 0.3 * e
    closure = np.clip(a[:, _P["closure"]], 0.0, 1.0)
    tuck = np.clip(col("lower_tuck"), 0.0, 1.5)
    opening = (1.0 - closure) * (1.0 - 0.7 * np.clip(tuck, 0, 1))
    f = displacement_fields(speaker.neutral, cfg)
    d = (jaw[:, None, None] * (opening[:, None, None] * f["jaw_lips"] + f["jaw_face"])
         + (ap * opening)[:, None, None] * f["aperture"]
         + spread[:, None, None] * f["spread"]
         + prot[:, None, None] * f["protrusion"]
         + col("upper_raise")[:, None, None] * f["upper_raise"]
         + tuck[:, None, None] * f["lower_tuck"]
         + closure[:, None, None] * f["press"]
         + brow[:, None, None] * f["brow"])
    if expression != "neutral":
        d = d + e[:, None, None] * expression_fields(speaker.neutral)[expression]
    scale = np.linalg.norm(speaker.neutral[76] - speaker.neutral[78]) / 172.0
    return speaker.neutral[None] + d * scale
