"""The development rule weighs real lips (issue 50): half of the score is the audio figures on
the development recordings, half the lip figures on the development faces (lip r on speech
frames, /p b m/ closed); a candidate without lip figures gets no score once some have them; a
run without real faces scores the audio alone; the latency bound still excludes."""
from __future__ import annotations

import pytest

from analysis.dev_rule import (AUDIO_WEIGHT, DEV_RULE, LIP_RULE, LIP_WEIGHT, deciding_half,
                               dev_choice, dev_parts)


def _audio(model, v):
    return {"model": model, "split": "unseen-dev", **{k: str(v) for k in DEV_RULE}}


def _lips(model, r, closed, part="dev", speaker="all", rate="native"):
    return {"model": model, "part": part, "speaker": speaker, "rate": rate,
            "r_speech": str(r), "closure_rate": str(closed)}


AUDIO = [_audio("voices-loud", 0.70), _audio("voices-lips", 0.60)]
# lips: r 0.6 and 0.9 closed (mean 0.75) against r 0.2, 0.3 closed (0.25)
FACES = [_lips("voices-lips", 0.6, 0.9), _lips("voices-loud", 0.2, 0.3),
         # rows the rule must not read: the test part, one speaker, another rate, a peer
         _lips("voices-loud", 1.0, 1.0, part="test"), _lips("voices-loud", 1.0, 1.0, speaker="s"),
         _lips("voices-loud", 1.0, 1.0, rate="8000"), _lips("loudness", 1.0, 1.0)]


def test_the_weights_are_half_and_half_and_fixed():
    assert (AUDIO_WEIGHT, LIP_WEIGHT) == (0.5, 0.5) and LIP_RULE == ("r_speech", "closure_rate")


def test_lips_decide_a_known_pair():
    best, scores = dev_choice(AUDIO, real_faces=FACES)
    assert scores == pytest.approx({"voices-loud": 0.5 * 0.70 + 0.5 * 0.25,
                                    "voices-lips": 0.5 * 0.60 + 0.5 * 0.75})
    assert best == "voices-lips"
    text = deciding_half(dev_parts(AUDIO, real_faces=FACES), best, scores)
    assert text.startswith("the lips: against the runner-up voices-loud, lips 0.750 vs 0.250")


def test_without_real_faces_the_audio_alone_decides():
    best, scores = dev_choice(AUDIO)
    assert best == "voices-loud" and scores == pytest.approx({"voices-loud": 0.7,
                                                              "voices-lips": 0.6})


def test_a_candidate_without_lip_figures_gets_no_score():
    best, scores = dev_choice(AUDIO + [_audio("voices-blind", 0.99)], real_faces=FACES)
    assert "voices-blind" not in scores and best == "voices-lips"


def test_the_latency_bound_still_excludes_the_best_lips():
    best, _ = dev_choice(AUDIO, real_faces=FACES,
                         latency={"voices-lips": 180.0, "voices-loud": 120.0}, bound_ms=133.3)
    assert best == "voices-loud"
