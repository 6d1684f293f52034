"""The perception study's design (paper §VII-C), as pure functions.

Each participant makes 27 judgments, in four blocks, always in this order (the paper's: the
unimodal experiment first — "the subjects are first asked to recognize the expressions … without
audio", "then asked to listen to the audio" — then the two bimodal experiments):

====================  ======  =====================================================  =========
block                 period  stimuli                                                 trials
====================  ======  =====================================================  =========
visual                0       silent animations: 2 faces × 3 expressions              6
audio                 0       the three sentences, read calmly, no face               3
bimodal               1       the first face of the sequence: 3 sentences × 3 expr.   9
bimodal               2       the other face: 3 sentences × 3 expressions             9
====================  ======  =====================================================  =========

The sequence is ``SR`` (synthetic face first in the bimodal experiments) or ``RS``; groups of
ten each in the paper. The visual-only animations are those of the neutral sentence ("It is
normal.") played without sound, so a face's visual-only and bimodal stimuli are the same
animation. Trial order is shuffled within each block from a per-participant seed
(:func:`participant_seed`: the study seed and the participant id, so a resumed session repeats
its order exactly).

Sequences come from a pre-generated allocation list (:func:`allocation_sequences`): permuted
blocks of four slots (two SR, two RS in a seeded random order), so any multiple of four
participants is exactly balanced and the list can be printed and audited before the study.
"""
from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass

import numpy as np

from face_model.corpus import EXPRESSIONS  # the corpus's expressions, also the study's
from groundwork.errors import ParameterError
from groundwork.identifiers import check_identifier

SENTENCES = {"normal": "It is normal.", "good": "It is good.", "bad": "It is bad."}
AUDIO = tuple(SENTENCES)  # audio track 1, 2, 3 of the paper
FACES = ("synthetic", "real")
RESPONSES = ("neutral", "happy", "sad", "not_sure")
EMOTION_OF = {"neutral": "neutral", "smile": "happy", "sad": "sad"}  # a face's expression
AUDIO_EMOTION = {"normal": "neutral", "good": "happy", "bad": "sad"}  # a sentence's content
SEQUENCES = ("SR", "RS")
BLOCKS = ("visual", "audio", "bimodal")
N_TRIALS = 27
VISUAL_AUDIO = "normal"  # the sentence whose animation the visual-only block shows, silent
ALLOCATION_BLOCK = 4
_ID = r"[A-Za-z0-9]{1,32}"
_STIMULUS_ID = r"[a-z]+(?:-[a-z]+){1,2}"  # face-expression-audio, audio-<audio>


def check_participant_id(pid) -> str:
    """A participant id is 1–32 letters or digits (BIDS/psych-DS ``sub-<id>``), nothing else:
    no path characters, no spaces, and it should not be a name or any other personal data."""
    return check_identifier("participant id", pid, _ID, "use 1-32 letters or digits (e.g. P01); "
                            "no path characters, spaces or punctuation, and no personal data "
                            "such as names")


def check_stimulus_id(sid) -> str:
    """A stimulus id is two or three lowercase words joined by ``-`` (:func:`stimulus_id`:
    ``synthetic-smile-good``, ``audio-good``); it names the stimulus's files and data rows."""
    return check_identifier("stimulus id", sid, _STIMULUS_ID, "two or three lowercase words "
                            "joined by '-', e.g. synthetic-smile-good or audio-good")


def group_of(sequence: str) -> str:
    """The paper's two groups by their bimodal order."""
    check_sequence(sequence)
    return "synthetic_first" if sequence == "SR" else "real_first"


def check_sequence(sequence) -> str:
    if sequence not in SEQUENCES:
        raise ParameterError(f"sequence {sequence!r}; allowed: {', '.join(SEQUENCES)}")
    return sequence


def stimulus_id(face: str, expression: str, audio: str) -> str:
    """``synthetic-smile-good``; ``audio-good`` for the audio-only tracks."""
    if face == "none":
        return f"audio-{audio}"
    return f"{face}-{expression}-{audio}"


@dataclass(frozen=True)
class Trial:
    """One judgment: ``face`` synthetic|real|none, ``expression`` neutral|smile|sad|none,
    ``audio`` normal|good|bad|none (what is heard; a visual-only trial shows the
    ``normal`` animation silently), ``stimulus_id`` the manifest entry it plays."""

    block: str
    period: int
    trial_index: int
    face: str
    expression: str
    audio: str
    stimulus_id: str

    def as_dict(self) -> dict:
        return asdict(self)


def participant_seed(study_seed: int, participant_id: str) -> int:
    """A 63-bit seed from the study seed and the id (stable across machines and versions)."""
    check_participant_id(participant_id)
    h = hashlib.sha256(f"{int(study_seed)}:{participant_id}".encode()).digest()
    return int.from_bytes(h[:8], "big") >> 1


def session_trials(participant_id: str, sequence: str, study_seed: int) -> list[Trial]:
    """The participant's 27 trials in presentation order (see the module text)."""
    check_sequence(sequence)
    rng = np.random.default_rng(participant_seed(study_seed, participant_id))
    first, second = ("synthetic", "real") if sequence == "SR" else ("real", "synthetic")
    blocks = [
        ("visual", 0, [(f, e, "none", stimulus_id(f, e, VISUAL_AUDIO))
                       for f in FACES for e in EXPRESSIONS]),
        ("audio", 0, [("none", "none", a, stimulus_id("none", "none", a)) for a in AUDIO]),
        ("bimodal", 1, [(first, e, a, stimulus_id(first, e, a)) for a in AUDIO
                        for e in EXPRESSIONS]),
        ("bimodal", 2, [(second, e, a, stimulus_id(second, e, a)) for a in AUDIO
                        for e in EXPRESSIONS]),
    ]
    trials = []
    for block, period, items in blocks:
        for j in rng.permutation(len(items)):
            face, expr, audio, sid = items[j]
            trials.append(Trial(block, period, len(trials), face, expr, audio, sid))
    return trials


def allocation_sequences(n: int, seed: int) -> list[str]:
    """``n`` sequences (SR/RS) in permuted blocks of four: exactly balanced when ``n`` is a
    multiple of four, off by at most two otherwise."""
    if not isinstance(n, (int, np.integer)) or n < 1:
        raise ParameterError(f"the allocation needs a positive number of slots, got {n!r}")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5E0]))
    out: list[str] = []
    while len(out) < n:
        block = np.array(["SR", "SR", "RS", "RS"])
        out.extend(block[rng.permutation(ALLOCATION_BLOCK)].tolist())
    return out[:n]


def required_stimuli() -> list[str]:
    """Every stimulus id a session can play (18 videos and 3 audio-only tracks)."""
    ids = [stimulus_id(f, e, a) for f in FACES for e in EXPRESSIONS for a in AUDIO]
    return ids + [stimulus_id("none", "none", a) for a in AUDIO]
