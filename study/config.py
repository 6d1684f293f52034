"""The perception study's settings (paper §VII-C), owned by ``study``; ``talkingface.config``
composes this section (``study``) with the others. Every value is checked when the config is
made (:mod:`groundwork.settings`).
"""
from __future__ import annotations

from dataclasses import dataclass

from groundwork.settings import check_fields, choice, distinct_keys, integer, number


@dataclass(frozen=True)
class StudyConfig:
    """The perception study (paper §VII-C); its seed is derived from the run seed."""

    # slots of the allocation list (two groups of ten; at least one in each group)
    n_participants: int = integer(20, ge=2)
    keys: tuple = distinct_keys(("n", "h", "s", "u"))  # neutral, happy, sad, not sure
    practice: bool = True  # one practice trial (not in the data) before the blocks
    fixation_s: float = number(0.5, ge=0, le=10)
    iti_s: float = number(0.5, ge=0, le=10)
    fullscreen: bool = False
    audio_backend: str = choice("sounddevice", "ptb", "none")  # none: no sound (tests only)

    def __post_init__(self):
        check_fields(self)
