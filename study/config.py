"""The perception study's settings (paper §VII-C), owned by ``study``; ``talkingface.config``
composes this section (``study``) with the others. Every value is checked when the config is
made (:mod:`groundwork.settings`).
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from groundwork.settings import check_fields, choice, distinct_keys, integer, number, require

CONSENT = ("You are invited to take part in a study of how people perceive emotion in speech "
           "and faces. You will see and hear short sentences and say which emotion you "
           "perceived; it takes about ten minutes. Taking part is voluntary: you may stop at any "
           "time by closing the page. Your answers are stored under a random identifier, "
           "without your name, and used for research only. By continuing you confirm that you "
           "are 18 or older and agree to take part.")
# a completion code: what recruitment sites accept (Prolific: letters and digits)
_CODE = re.compile(r"[A-Za-z0-9]{0,32}")


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
    # the web study (`talkingface study web` / `serve`): the consent text its first page shows,
    # and what a participant who completed is given: a code to paste into the recruitment site
    # and, when set, the address the page then opens ({code} is replaced by the code), e.g.
    # https://app.prolific.com/submissions/complete?cc={code}
    consent: str = CONSENT
    completion_code: str = ""
    completion_url: str = ""

    def __post_init__(self):
        check_fields(self)
        require(self, "consent", isinstance(self.consent, str) and bool(self.consent.strip()),
                "the consent text the web study's first page shows (not empty)")
        require(self, "completion_code", isinstance(self.completion_code, str)
                and bool(_CODE.fullmatch(self.completion_code)),
                "0-32 letters or digits (blank: no code)")
        url = self.completion_url
        require(self, "completion_url", isinstance(url, str) and (
            url == "" or (url.startswith("https://") and " " not in url)),
                "blank, or an https:// address ({code} is replaced by completion_code)")
