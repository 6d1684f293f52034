"""Models and peers scored on real clips (talkingface.stages.face_scoring): the prediction has
exactly the clip's frames at every input rate, the clip's phones and no-face frames reach
the scores, and clips of another face scored as a training speaker are refused (issue 42)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from face_model.corpus import load_corpus
from face_model.face_match import MAX_FACE_MISFIT
from groundwork.errors import ParameterError
from mapping.animator import FaceAnimator
from talkingface.stages.face_scoring import (clips_from_corpus, peer_opening, score_model,
                                             score_peer, speech_span)
from talkingface.stages.real_speaker import BUILTIN
from tests.mapping.small_mapping import train_small

IDS = ("bbaf3s", "bbaf5a")
REAL = BUILTIN.parent


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


def test_the_transcript_peer_without_word_times_is_closed_outside_the_speech_span():
    clip = dataclasses.replace(clips_from_corpus(BUILTIN, IDS[:1])[0], words=None)
    a, b = speech_span(clip)
    o = peer_opening("openfacefx-text", clip)
    assert len(o) == clip.n_frames and np.all(o[:a] == 0) and np.all(o[b:] == 0)
    assert o[a:b].max() > 0
    s = score_peer("loudness", [clip], input_rate=8000)
    assert s.tracks[0].n_frames == clip.n_frames
    s = score_peer("openfacefx-text", [clip])
    assert s.pooled["word_times"] == {clip.clip: "speech span"}
    assert s.pooled["word_time_clips"] == 0


@pytest.mark.parametrize("corpus", [BUILTIN, REAL / "grid-s26", REAL / "grid-s31"],
                         ids=["grid-s1", "grid-s26", "grid-s31"])
def test_the_transcript_peer_with_word_times_moves_the_mouth_inside_the_words(corpus):
    """A corpus with words/ gives each clip its words; the peer is closed (0) at every frame
    outside every word, open inside some, and each word's motion stays in its own interval:
    without one of the words, the mouth is closed in that word's interval and unchanged
    elsewhere."""
    clips = clips_from_corpus(corpus)[:3]
    for c in clips:
        assert c.words and " ".join(w for _, _, w in c.words) == c.text
        o = peer_opening("openfacefx-text", c)
        t = np.arange(c.n_frames) / c.fps
        inside = np.logical_or.reduce([(t >= s) & (t < e) for s, e, _ in c.words])
        assert np.all(o[~inside] == 0) and o[inside].max() > 0.2
        for rate in (16000, 8000):  # the input rate changes nothing: the peer reads the words
            np.testing.assert_array_equal(peer_opening("openfacefx-text", c, rate), o)
        for i, (s0, e0, _) in enumerate(c.words):
            fewer = dataclasses.replace(c, words=c.words[:i] + c.words[i + 1:])
            o_fewer = peer_opening("openfacefx-text", fewer)
            word = (t >= s0) & (t < e0)
            assert np.all(o_fewer[word] == 0)
            np.testing.assert_array_equal(o_fewer[~word], o[~word])
    s = score_peer("openfacefx-text", clips)
    assert s.pooled["word_times"] == {c.clip: "words" for c in clips}
    assert s.pooled["word_time_clips"] == len(clips)
    assert "word_times" not in score_peer("loudness", clips[:1]).pooled


def test_the_summary_says_which_timing_the_transcript_peer_got():
    from talkingface.stages.real_speaker import WORD_TIMES

    assert "keeps no word times" not in WORD_TIMES
    assert "each word segmented on its own interval" in WORD_TIMES
    assert "speech span" in WORD_TIMES and "word_times" in WORD_TIMES


def test_clips_of_another_face_scored_as_a_training_speaker_are_refused(small_corpus,
                                                                         small_corpus_dir):
    trained = train_small(small_corpus, method="linear", epochs=5)
    animator = FaceAnimator(trained.mapping, trained.units)
    synthetic = small_corpus.utterances[0].speaker
    allowed = rf"at most {MAX_FACE_MISFIT:.1f} % allowed"
    # real GRID s1 clips named as the model's synthetic speaker (the case)
    grid = [dataclasses.replace(c, speaker=synthetic) for c in clips_from_corpus(BUILTIN, IDS)]
    with pytest.raises(ParameterError, match=rf"^clips bbaf3s \(and 1 more\) scored as speaker "
                       rf"'{synthetic}' show another face: their neutral face misfits the "
                       rf"speaker's by \d+\.\d % of the face's size .*{allowed}"):
        score_model(animator, grid, training_corpus=small_corpus)
    # the opposite: a synthetic clip named as the real speaker of the training corpus
    first = small_corpus.utterances[0].utt_id
    synth = [dataclasses.replace(c, speaker="grid-s1")
             for c in clips_from_corpus(small_corpus_dir, [first])]
    with pytest.raises(ParameterError, match=rf"^clip {first} scored as speaker 'grid-s1' shows "
                       rf"another face: .*{allowed}"):
        score_model(animator, synth, training_corpus=load_corpus(BUILTIN))
    # each under its own name: scored, with LVE on the training speaker's
    own = score_model(animator, clips_from_corpus(small_corpus_dir, [first]),
                      training_corpus=small_corpus)
    assert own.pooled["lve_clips"] == 1
    # a speaker the model was not trained on has no neutral to compare: scored without LVE
    unseen = score_model(animator, grid, training_corpus=load_corpus(BUILTIN))
    assert unseen.pooled["lve_clips"] == 0


def test_the_default_real_speaker_is_the_built_in_corpus_of_196_sentences(tmp_path):
    """``real_speaker.corpus: builtin`` (the default) names the shipped GRID s1 folder, which the
    one corpus reader takes whole (the suite's full replication reads a quarter of it, copied
    by tests/talkingface/full_run.py, whose manifest is every 4th row of this one)."""
    from talkingface.config import Config
    from talkingface.stages.given_corpus import check_folder
    from talkingface.stages.real_speaker import real_corpus
    from tests.talkingface.full_run import real_speaker_part

    assert Config().real_speaker.corpus == "builtin" and real_corpus(Config()) == BUILTIN
    whole = check_folder(BUILTIN, "real_speaker.corpus")
    assert whole["n_utterances"] == 196
    part = real_speaker_part(tmp_path / "part")
    assert check_folder(part, "real_speaker.corpus")["n_utterances"] == 49
    assert [u.utt_id for u in load_corpus(part).utterances] == \
        [u.utt_id for u in load_corpus(BUILTIN).utterances][::4]
