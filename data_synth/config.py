"""The synthetic corpus's settings (paper §IV-A, §VII-A), owned by ``data_synth``.

``talkingface.config`` composes this section (``synth``) with the other packages' sections.
Every value is checked when the config is made (:mod:`groundwork.settings`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from numbers import Real

from data_synth.articulation import TABLE, articulation_path, read_articulation, shipped_names
from data_synth.backends import voice_problem
from face_model.corpus import EXPRESSIONS
from groundwork.errors import ParameterError
from groundwork.settings import (SettingError, check_fields, choice, integer, number, require,
                                 span, subset)


@dataclass(frozen=True)
class VoicesRule:
    """A list of distinct strings (each an ``"engine:voice"``, checked by ``__post_init__``)."""

    def accepts(self, v) -> bool:
        return (isinstance(v, (tuple, list)) and all(isinstance(x, str) for x in v)
                and len(set(v)) == len(v))

    @property
    def allowed(self) -> str:
        return "a list of distinct 'engine:voice' strings, e.g. [espeak:en-us+f3, flite:awb]"


def check_voices(voices, key: str = "voices") -> None:
    """Refuse the first voice of ``voices`` that no engine here has (a :class:`SettingError`
    naming ``key``, the voice and the problem)."""
    for spec in voices:
        problem = voice_problem(spec)
        if problem is not None:
            raise SettingError(key, spec, problem)


def check_articulation(value) -> None:
    """Refuse a ``synth.articulation`` that is not ``table``, a shipped name or a readable
    articulation model file (a :class:`SettingError` naming the key, the value and the
    problem)."""
    if not isinstance(value, str) or not value:
        raise SettingError("articulation", value, f"{TABLE}, a shipped name "
                           f"({', '.join(shipped_names())}) or the path of a model file")
    if value == TABLE:
        return
    try:
        read_articulation(articulation_path(value))
    except ParameterError as exc:
        raise SettingError("articulation", value, f"{TABLE}, a shipped name "
                           f"({', '.join(shipped_names())}) or the path of a model file "
                           f"({exc})") from None


@dataclass(frozen=True)
class _Weights:
    """A list (possibly empty) of finite numbers >= 0."""

    def accepts(self, v) -> bool:
        return isinstance(v, (tuple, list)) and all(
            isinstance(x, Real) and not isinstance(x, bool) and math.isfinite(x) and x >= 0
            for x in v)

    @property
    def allowed(self) -> str:
        return "a list of finite numbers >= 0"


@dataclass(frozen=True)
class SynthConfig:
    """The synthetic audio-visual corpus (paper §IV-A, §VII-A). Units: seconds, pixels, wpm.
    Sizes in pixels are bounded by what a face of ~200 px can show, so that no setting can
    make markers that are not finite numbers."""

    n_sentences: int = integer(100, ge=0)  # 0: every sentence of the source
    expressions: tuple = subset(EXPRESSIONS, EXPRESSIONS)
    speakers: int = integer(1, ge=1)
    text_file: str = ""  # empty: the built-in sentences
    backend: str = choice("espeak", "flite", "espeak-ng")  # espeak-ng: another name of espeak
    workers: int = integer(0, ge=0)  # 0: all cores
    # Voices drawn per utterance, "engine:voice" (data_synth.backends). Empty: `backend`,
    # `voice` and the per-speaker espeak variants (the paper's single-speaker design); else
    # those three are not used, and rate and pitch reach each engine through its own controls.
    voices: tuple = field(default=(), metadata={"rule": VoicesRule()})
    voice_weights: tuple = field(default=(), metadata={"rule": _Weights()})  # empty: equal
    # speech (pitch and its range on espeak's 0–100 scale)
    voice: str = "en-us+m3"
    rate_wpm: int = integer(165, gt=0)
    pitch: int = integer(45, ge=0, le=100)
    pitch_range: int = integer(50, ge=0, le=100)
    lead_silence_s: float = number(0.20, ge=0, le=10)
    trail_silence_s: float = number(0.20, ge=0, le=10)
    audio_noise_dbfs: float = number(-66.0, le=0)  # a recording-room noise floor
    # expression prosody (added to the speaker's voice)
    smile_pitch_delta: int = integer(6, ge=-100, le=100)
    smile_rate_delta: int = integer(5)
    sad_pitch_delta: int = integer(-8, ge=-100, le=100)
    sad_rate_delta: int = integer(-15)
    # coarticulation (Cohen & Massaro 1993)
    theta_anticipation: float = number(16.0, gt=0, le=1000)  # 1/s
    theta_carryover: float = number(25.0, gt=0, le=1000)  # 1/s
    dominance_power: float = number(1.0, gt=0, le=20)
    # the coarticulation model (data_synth.articulation): `table` (face_model.phones' hand table
    # with the three rates above) or a fitted model file: a shipped name (grid-s1: fitted on the
    # real speaker's training sentences, tools/fit_articulation.py) or a path; a file's own
    # rates replace the three above
    articulation: str = "table"
    # articulation → marker displacement gains, pixels at parameter value 1
    jaw_px: float = number(10.0, ge=0, le=100)
    aperture_px: float = number(6.0, ge=0, le=100)
    spread_px: float = number(7.0, ge=0, le=100)
    protrusion_px: float = number(8.0, ge=0, le=100)
    upper_raise_px: float = number(4.0, ge=0, le=100)
    lower_tuck_px: float = number(6.0, ge=0, le=100)
    brow_px: float = number(2.5, ge=0, le=100)
    # expressions: envelope (each utterance draws from these ranges) and interaction with speech
    expression_onset_s: tuple = span((0.25, 0.5), gt=0)
    expression_offset_s: tuple = span((0.3, 0.6), gt=0)
    expression_intensity: tuple = span((0.7, 1.0), ge=0)
    smile_rounding_damping: float = number(0.6, ge=0, le=1)  # fraction of the lip rounding
    smile_widening: float = number(0.3, ge=0, le=5)
    sad_jaw_reduction: float = number(0.35, ge=0, le=1)  # fraction of the jaw opening
    # speaker variation (standard deviations)
    speaker_scale_sd: float = number(0.04, ge=0, le=0.5)
    speaker_shape_sd_px: float = number(1.5, ge=0, le=50)
    speaker_gain_sd: float = number(0.10, ge=0, le=1)
    speaker_rate_sd: float = number(12.0, ge=0, le=100)
    speaker_pitch_sd: float = number(8.0, ge=0, le=50)
    # nuisances
    head_rotation_deg: float = number(2.0, ge=0, le=45)
    head_scale: float = number(0.02, ge=0, le=0.5)
    head_translation_px: float = number(6.0, ge=0, le=200)
    marker_noise_px: float = number(0.15, ge=0, le=50)  # sub-pixel marker localisation

    def __post_init__(self):
        check_fields(self)
        check_voices(self.voices)
        check_articulation(self.articulation)
        w = self.voice_weights
        require(self, "voice_weights", not w or (len(w) == len(self.voices) and sum(w) > 0),
                f"empty (equal weights), or one number >= 0 per voice of voices "
                f"({len(self.voices)}) with a sum > 0", ("voices",))
        object.__setattr__(self, "voice_weights", tuple(float(x) for x in w))
        for delta in ("smile_rate_delta", "sad_rate_delta"):  # the expression's rate stays > 0
            require(self, delta, self.rate_wpm + getattr(self, delta) > 0,
                    f"an integer > -rate_wpm ({-self.rate_wpm})", ("rate_wpm",))
