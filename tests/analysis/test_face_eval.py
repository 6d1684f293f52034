"""Scoring predicted lips against a real face (analysis.face_eval), on tracks whose answer is
known by construction."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from analysis.face_eval import (CSV_COLUMNS, ClipTrack, closure_segments, score_clips,
                                speech_mask, write_scores_csv)
from analysis.speech_eval import correlation
from groundwork.errors import ParameterError

FPS = 30.0
WORDS = (("b", "ih", "n"), ("b", "l", "uw"), ("ae", "t"), ("p", "l", "ey", "s"),
         ("s", "ow", "n"), ("m", "aa", "r"), ("g", "r", "iy", "n"), ("w", "ih", "th"))


def sentence(rng, n_words: int = 8):
    """Phone segments of a sentence (silence, words of 60–120 ms phones, silence) and a real
    opening (px) that closes on /p b m/, rests at 0.3 px in silence and opens 3–10 px
    otherwise."""
    t, phones = 0.0, []
    lead = float(rng.uniform(0.4, 0.7))
    phones.append((0.0, lead, "sil"))
    t = lead
    for i in range(n_words):
        for ph in WORDS[(i + int(rng.integers(len(WORDS)))) % len(WORDS)]:
            d = float(rng.uniform(0.06, 0.12))
            phones.append((t, t + d, ph))
            t += d
    phones.append((t, t + 0.6, "sil"))
    n = int(np.ceil((t + 0.6) * FPS))
    time = np.arange(n) / FPS
    real = np.full(n, 0.3)
    for s, e, ph in phones:
        m = (time >= s) & (time < e)
        real[m] = 0.3 if ph == "sil" else 0.0 if ph in "pbm" else rng.uniform(3, 10)
    real = np.convolve(real, [0.25, 0.5, 0.25], mode="same")  # the lips move smoothly
    return phones, real + 0.05 * rng.random(n)


def clip(rng, name="c0", speaker="s1", pred=None, **kw):
    phones, real = sentence(rng)
    return ClipTrack(name, speaker, real, real.copy() if pred is None else pred(real), FPS,
                     phones, **kw)


def test_a_copy_of_the_truth_scores_1_and_closes_every_bilabial_segment():
    rng = np.random.default_rng(1)
    tracks = [clip(rng, f"c{i}") for i in range(3)]
    p = score_clips(tracks).pooled
    assert p["r_speech"] == pytest.approx(1.0) and p["r_silence"] == pytest.approx(1.0)
    assert p["bilabial_segments"] > 0 and p["control_segments"] > 0
    assert p["real_closed"] == p["closures_hit"] == p["bilabial_segments"]
    assert p["closure_rate"] == 1.0 and p["real_closed_rate"] == 1.0
    assert p["chance_r_speech"] < 0.5 and p["chance_closure_rate"] < 1.0
    assert p["interval_r_speech"] == "(no interval: 1 speaker; an interval needs at least 3)"


def test_a_constant_prediction_scores_r_0_and_closes_only_as_chance_does():
    rng = np.random.default_rng(2)
    tracks = [clip(rng, f"c{i}", pred=lambda r: np.full(len(r), 4.0)) for i in range(3)]
    s = score_clips(tracks)
    assert s.pooled["r_speech"] == 0.0 and s.pooled["chance_r_speech"] == 0.0
    assert all(np.isnan(c.r_speech) for c in s.clips)
    assert s.pooled["closures_hit"] == 0 and s.pooled["closure_rate"] == \
        s.pooled["chance_closure_rate"] == 0.0


def test_a_copy_shifted_by_k_frames_scores_the_truths_lag_k_autocorrelation():
    rng = np.random.default_rng(3)
    _, real = sentence(rng)
    n, k = len(real), 2
    everything = [(0.0, n / FPS, "aa")]  # every frame is speech
    s = score_clips([ClipTrack("c", "s", real, np.roll(real, k), FPS, everything)])
    z = (real - real.mean()) / real.std()
    assert s.pooled["r_speech"] == pytest.approx(np.mean(z * np.roll(z, k)), abs=1e-12)


def test_agreement_on_silence_only_earns_nothing_on_the_speech_frame_r():
    rng = np.random.default_rng(4)
    phones, real = sentence(rng)
    sp = speech_mask(phones, len(real), FPS)
    noise = rng.normal(size=len(real))
    pred = np.where(sp, noise, real)
    s = score_clips([ClipTrack("c", "s", real, pred, FPS, phones)])
    assert s.pooled["r_silence"] == pytest.approx(1.0)
    assert s.pooled["r_speech"] == pytest.approx(correlation(real[sp], noise[sp]), abs=1e-12)
    assert abs(s.pooled["r_speech"]) < 0.3


def test_frames_without_a_detected_face_are_excluded_from_every_score():
    rng = np.random.default_rng(5)
    phones, real = sentence(rng)
    pred = np.roll(real, 1) + 0.3 * rng.random(len(real))
    valid = np.ones(len(real), bool)
    valid[20:26] = valid[40:43] = False
    a = score_clips([ClipTrack("c", "s", real, pred, FPS, phones, valid)])
    real2, pred2 = real.copy(), pred.copy()
    real2[~valid], pred2[~valid] = 50.0, -7.0  # whatever the interpolation made
    b = score_clips([ClipTrack("c", "s", real2, pred2, FPS, phones, valid)])
    skip = {"chance_r_speech", "chance_r_silence", "chance_closure_rate",
            "chance_false_closure_rate"}  # a shift moves other frames onto valid ones
    for key, v in a.pooled.items():
        if key not in skip:
            assert b.pooled[key] == v or (v != v and b.pooled[key] != b.pooled[key]), key
    assert a.pooled["excluded_frames"] == 9


def test_a_length_mismatch_is_an_error_naming_the_clip_and_both_lengths():
    with pytest.raises(ParameterError, match=r"clip 'bbaf3s': real opening has 90 frames and "
                                             r"predicted 89; they must be equal"):
        ClipTrack("bbaf3s", "s", np.ones(90), np.ones(89), FPS)


def test_bilabial_runs_merge_and_silence_is_no_control():
    phones = [(0, .5, "sil"), (.5, .6, "m"), (.6, .7, "p"), (.7, .8, "aa"), (.8, .9, "b"),
              (.9, 1.0, "sil")]
    bil, ctl = closure_segments(phones)
    assert bil == pytest.approx([0.6, 0.85]) and ctl == pytest.approx([0.75])


def test_speakers_pool_by_clip_and_three_give_an_interval(tmp_path):
    rng = np.random.default_rng(6)
    tracks = [clip(rng, f"{s}{i}", s, pred=lambda r: 3 * np.roll(r, 1) + 5)
              for s in "abc" for i in range(3)]
    s = score_clips(tracks)
    assert s.pooled["speakers"] == 3 and s.pooled["interval_r_speech"].startswith("[")
    out = write_scores_csv(s, tmp_path / "per_clip.csv")
    with open(out, newline="") as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0]) == CSV_COLUMNS and len(rows) == 9
    json.dumps(s.to_dict())  # JSON-ready
