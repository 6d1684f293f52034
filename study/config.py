"""The perception study's settings (paper §VII-C), owned by ``study``; ``talkingface.config``
composes this section (``study``) with the others.
"""
from __future__ import annotations

from dataclasses import dataclass

from face_model.settings import choice


@dataclass(frozen=True)
class StudyConfig:
    """The perception study (paper §VII-C); its seed is derived from the run seed."""

    n_participants: int = 20  # slots of the allocation list (two groups of ten)
    keys: tuple = ("n", "h", "s", "u")  # neutral, happy, sad, not sure
    practice: bool = True  # one practice trial (not in the data) before the blocks
    fixation_s: float = 0.5
    iti_s: float = 0.5
    fullscreen: bool = False
    audio_backend: str = choice("sounddevice", "ptb", "none")  # none: no sound (tests only)
