"""The settings owned by ``analysis``: the project's targets (section ``targets`` of the run
config) and the part of the real-speech set the evaluation scores (section ``speech_set``).

One table of targets, stated once before a run and quoted from here by every table that
compares a figure with its target (the real-speech section, the real-speaker section, the
first page). They are the bars the project set itself for real data; a figure short of its
target is reported as short, never tuned toward it. ``talkingface.config`` composes these
sections; ``configs/paper.yaml`` mirrors them.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

from face_model.corpus import FPS
from groundwork.settings import check_fields, fraction, integer, number
from mapping.config import MappingConfig

# The paper's look-ahead window (its context, 3 frames after the current one at 30 fps: 100 ms)
# plus one frame (33.3 ms): the bound on the live latency of a default model, in ms. Computed
# from the paper's values (MappingConfig's default context_forward, the corpus's FPS), not typed.
PAPER_STREAM_LATENCY_MS = 1000.0 * (MappingConfig().context_forward + 1) / FPS


@dataclass(frozen=True)
class TargetsConfig:
    """Targets on real data (unseen speakers unless a name says otherwise)."""

    # speech set, the default model streaming at the look-ahead below: viseme frame accuracy
    viseme_accuracy: float = fraction(0.80)
    lookahead_ms: float = number(100.0, ge=0, le=1000)
    # /p b m/ segments the phones say must close: fraction the predicted lips close
    bilabial_closed: float = fraction(0.80)
    # the centre opening of a /p b m/ segment at most this times the median vowel opening
    bilabial_centre_rel_vowel: float = number(0.4, ge=0, le=10)
    # speech set: r of the predicted opening with the generator's reference articulation
    speech_r_reference: float = fraction(0.70)
    # real face (held-out sentences), speech frames: lip r of the model trained on the speaker
    face_speaker_r: float = fraction(0.85)
    # real face: lip r of the synthetic-trained default (it has never seen the speaker)
    face_synthetic_r: float = fraction(0.70)
    # real face: fraction of the /p b m/ closures the synthetic-trained default closes
    face_closures: float = fraction(0.80)
    # a score at 16 kHz input within this of the same score at 22.05 kHz
    rate_tolerance: float = number(0.02, ge=0, le=1)
    # streaming front end: per-frame compute, 99th percentile (bench/bench_streaming.py)
    frame_cost_p99_ms: float = number(3.0, gt=0, le=1000)
    # the development rule: a model whose measured latency in `talkingface stream` (a recording
    # paced in real time; talkingface.stages.latency), 99th percentile, exceeds this cannot be
    # the default, whatever its accuracy; default: the paper's window plus one frame
    stream_latency_p99_ms: float = number(PAPER_STREAM_LATENCY_MS, gt=0, le=10000)

    def __post_init__(self):
        check_fields(self)

    def rows(self) -> list[tuple[str, float, str]]:
        """``(key, value, what it bounds)`` for the report's table of targets, in field order."""
        return [(f.name, getattr(self, f.name), TARGET_TEXT[f.name]) for f in fields(self)]


@dataclass(frozen=True)
class SpeechSetConfig:
    """Which recordings of the real-speech set (``analysis/real_speech/``) the ``speech_eval``
    stage and ``talkingface evaluate-speech`` score
    (:func:`analysis.speech_set.subset_rows`)."""

    # 0: every recording; N >= 1: the first N recordings of each speaker in each part (dev,
    # test), in manifest order (a speaker with fewer gives all it has): a quick look, e.g. a
    # small replication, not the set's figures
    per_speaker: int = integer(0, ge=0)

    def __post_init__(self):
        check_fields(self)


TARGET_TEXT = {
    "viseme_accuracy": "viseme frame accuracy on unseen speakers, streaming, at least",
    "lookahead_ms": "look-ahead of the streaming figures, ms",
    "bilabial_closed": "/p b m/ segments closed by the predicted lips, at least",
    "bilabial_centre_rel_vowel": "/p b m/ centre opening / median vowel opening, at most",
    "speech_r_reference": "r with the reference articulation of the real phones, at least",
    "face_speaker_r": "real face, speech frames: lip r of the speaker-trained model, at least",
    "face_synthetic_r": "real face, speech frames: lip r of the synthetic-trained default, "
                        "at least",
    "face_closures": "real face: /p b m/ closures the synthetic-trained default closes, "
                     "at least",
    "rate_tolerance": "a score at 16 kHz input within this of its score at 22.05 kHz",
    "frame_cost_p99_ms": "streaming front end: per-frame compute p99, ms, at most",
    "stream_latency_p99_ms": "live latency of the default model (`talkingface stream`, paced "
                             "in real time), p99, ms, at most: the paper's window plus one "
                             "frame",
}
