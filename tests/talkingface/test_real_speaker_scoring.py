"""Models and peers scored on real clips (talkingface.stages.face_scoring): the prediction has
exactly the clip's frames at every input rate, and the clip's phones and no-face frames reach
the scores."""
from __future__ import annotations

import math

import numpy as np

from face_model.corpus import load_corpus
from mapping.animator import FaceAnimator
from talkingface.stages.face_scoring import (clips_from_corpus, peer_opening, score_model,
                                             score_peer, speech_span)
from talkingface.stages.real_speaker import BUILTIN
from tests.mapping.small_mapping import train_small

IDS = ("bbaf3s", "bbaf5a")


def test_a_model_is_scored_on_real_clips_at_every_rate(small_corpus):
    trained = train_small(small_corpus, method="linear", epochs=5)
    animator = FaceAnimator(trained.mapping, trained.units)
    clips = clips_from_corpus(BUILTIN, IDS)
    assert all(c.phones and c.valid is not None and c.fps == 30.0 for c in clips)
    for rate in (None, 16000, 8000):
        s = score_model(animator, clips, input_rate=rate)
        assert [t.n_frames for t in s.tracks] == [c.n_frames for c in clips]
        p = s.pooled
        assert p["speech_known"] and p["speech_frames"] > 0 and p["silence_frames"] > 0
        assert p["bilabial_segments"] > 0 and math.isfinite(p["chance_r_speech"])
        assert p["lve_clips"] == 0  # never trained on this speaker
    own = score_model(animator, clips, training_corpus=load_corpus(BUILTIN))
    assert own.pooled["lve_clips"] == len(clips)


def test_the_transcript_peer_is_closed_outside_the_speech_span():
    clip = clips_from_corpus(BUILTIN, IDS[:1])[0]
    a, b = speech_span(clip)
    o = peer_opening("openfacefx-text", clip)
    assert len(o) == clip.n_frames and np.all(o[:a] == 0) and np.all(o[b:] == 0)
    assert o[a:b].max() > 0
    s = score_peer("loudness", [clip], input_rate=8000)
    assert s.tracks[0].n_frames == clip.n_frames
