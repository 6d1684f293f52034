"""The synthetic corpus's settings (paper §IV-A, §VII-A), owned by ``data_synth``.

``talkingface.config`` composes this section (``synth``) with the other packages' sections.
"""
from __future__ import annotations

from dataclasses import dataclass

from face_model.corpus import EXPRESSIONS


@dataclass(frozen=True)
class SynthConfig:
    """The synthetic audio-visual corpus (paper §IV-A, §VII-A). Units: seconds, pixels, wpm."""

    n_sentences: int = 100
    expressions: tuple = EXPRESSIONS
    speakers: int = 1
    text_file: str = ""  # empty: the built-in sentences
    backend: str = "espeak"
    workers: int = 0  # 0: all cores
    # speech
    voice: str = "en-us+m3"
    rate_wpm: int = 165
    pitch: int = 45
    pitch_range: int = 50
    lead_silence_s: float = 0.20
    trail_silence_s: float = 0.20
    audio_noise_dbfs: float = -66.0  # a recording-room noise floor
    # expression prosody (added to the speaker's voice)
    smile_pitch_delta: int = 6
    smile_rate_delta: int = 5
    sad_pitch_delta: int = -8
    sad_rate_delta: int = -15
    # coarticulation (Cohen & Massaro 1993)
    theta_anticipation: float = 16.0  # 1/s
    theta_carryover: float = 25.0  # 1/s
    dominance_power: float = 1.0
    # articulation → marker displacement gains, pixels at parameter value 1
    jaw_px: float = 10.0
    aperture_px: float = 6.0
    spread_px: float = 7.0
    protrusion_px: float = 8.0
    upper_raise_px: float = 4.0
    lower_tuck_px: float = 6.0
    brow_px: float = 2.5
    # expressions: envelope and interaction with speech
    expression_onset_s: tuple = (0.25, 0.5)
    expression_offset_s: tuple = (0.3, 0.6)
    expression_intensity: tuple = (0.7, 1.0)
    smile_rounding_damping: float = 0.6
    smile_widening: float = 0.3
    sad_jaw_reduction: float = 0.35
    # speaker variation (standard deviations)
    speaker_scale_sd: float = 0.04
    speaker_shape_sd_px: float = 1.5
    speaker_gain_sd: float = 0.10
    speaker_rate_sd: float = 12.0
    speaker_pitch_sd: float = 8.0
    # nuisances
    head_rotation_deg: float = 2.0
    head_scale: float = 0.02
    head_translation_px: float = 6.0
    marker_noise_px: float = 0.15  # sub-pixel marker localisation
