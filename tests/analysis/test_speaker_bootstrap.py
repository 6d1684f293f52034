"""The speaker-level bootstrap: wider than the recording-level one when one speaker dominates,
no interval under three speakers, the paired difference of identical systems centred on 0."""
import numpy as np
import pytest

from analysis.speaker_bootstrap import (Interval, paired_speaker_interval, pooled,
                                        recording_interval, speaker_interval)
from groundwork.errors import ParameterError


def _one_speaker_heavy(seed=0):
    """40 recordings of speaker A (accuracy ~0.9) and 2 each of four others (~0.5–0.7)."""
    rng = np.random.default_rng(seed)
    speakers, hits, weights = [], [], []
    for spk, n, p in [("a", 40, 0.9), ("b", 2, 0.5), ("c", 2, 0.6), ("d", 2, 0.7),
                      ("e", 2, 0.55)]:
        for _ in range(n):
            w = 90
            speakers.append(spk)
            hits.append(rng.binomial(w, p))
            weights.append(w)
    return speakers, np.array(hits, float), np.array(weights, float)


def test_speaker_level_is_wider_than_recording_level_on_a_one_speaker_heavy_set():
    speakers, hits, weights = _one_speaker_heavy()
    spk = speaker_interval(speakers, hits, weights)
    rec = recording_interval(hits, weights)
    assert spk.ok and rec.ok
    assert spk.speakers == 5 and spk.recordings == 48
    assert (spk.hi - spk.lo) > 3 * (rec.hi - rec.lo)
    point = pooled(hits, weights)
    assert spk.lo <= point <= spk.hi


def test_fewer_than_three_speakers_give_no_interval_and_say_why():
    iv = speaker_interval(["a"] * 10 + ["b"] * 3, np.ones(13), np.ones(13) * 2)
    assert not iv.ok and iv.lo is None and iv.hi is None
    assert iv.speakers == 2 and iv.recordings == 13
    assert "2 speakers" in iv.reason and "at least 3" in iv.text()


def test_same_seed_same_interval_and_constant_data_collapse():
    speakers, hits, weights = _one_speaker_heavy()
    assert speaker_interval(speakers, hits, weights, seed=7) == \
        speaker_interval(speakers, hits, weights, seed=7)
    iv = speaker_interval(list("abcd"), [3, 3, 3, 3], [4, 4, 4, 4])
    assert iv.lo == pytest.approx(0.75) and iv.hi == pytest.approx(0.75)


def test_paired_difference_of_a_system_with_itself_is_zero():
    speakers, hits, weights = _one_speaker_heavy()
    iv = paired_speaker_interval(speakers, hits, hits, weights)
    assert iv.lo == 0 and iv.hi == 0
    shifted = paired_speaker_interval(speakers, hits, hits - 9, weights)  # 0.1 per 90 frames
    assert shifted.lo == pytest.approx(0.1) and shifted.hi == pytest.approx(0.1)


def test_mismatched_lengths_are_refused():
    with pytest.raises(ParameterError, match="one entry per recording, got 2, 3 and 3"):
        speaker_interval(["a", "b"], [1, 2, 3], [1, 1, 1])
    assert isinstance(speaker_interval(list("abc"), [1, 1, 1], [2, 2, 2]), Interval)
