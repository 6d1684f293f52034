"""Lip scores that measure speech (DESIGN.md, "Evaluation on real data"): a copy of the truth
scores 1, a constant scores nothing beyond its chance level, a shifted copy scores as the shift,
silence earns nothing on the speech-frame r; the pooled rows state their speakers and
recordings, the per-speaker table sums to them, and the shared-draw intervals are the speaker
bootstrap's own."""
from __future__ import annotations

import numpy as np
import pytest

from analysis.speaker_bootstrap import paired_speaker_interval, speaker_interval
from analysis.speech_pooling import (compare, interval, paired_interval, per_speaker,
                                     pool_rows, summarise)
from analysis.speech_scores import (BILABIALS, CHANCE_SHIFTS, SIL, chance_scores,
                                    phone_frames, segment_contact, shifts, speech_r_terms,
                                    viseme_contact, viseme_index)
from face_model.corpus import PhoneSegment
from face_model.phones import VISEMES

FPS = 30
KEY = "viseme_acc_stream_100ms"


def _segs(spec):
    out, t = [], 0.0
    for p, d in spec:
        out.append(PhoneSegment(t, t + d, p))
        t += d
    return out


@pytest.fixture
def clip():
    """Three seconds of labelled speech: silence, then vowels and /p b m/, then silence."""
    spec = [("sil", 0.4)] + sum([[("aa", 0.2), (p, 0.1), ("iy", 0.15), ("s", 0.1)]
                                 for p in "pbmpbm"], []) + [("sil", 0.3)]
    segs = _segs(spec)
    n = int(np.ceil(segs[-1].end_s * FPS))
    true = phone_frames(segs, np.arange(n) / FPS)
    # a truth-like opening: closed in silence and on /p b m/, open on vowels
    opening = np.where(np.isin(viseme_index(true), [VISEMES.index("neutral"),
                                                    VISEMES.index("m")]), 0.0, 8.0)
    opening = opening * np.linspace(1, 2, n)  # a shape within the open frames
    return segs, true, opening


def _r(pred, ref, true):
    terms, n = speech_r_terms(pred, ref, true)
    return terms / n


def test_a_copy_of_the_truth_scores_one(clip):
    segs, true, opening = clip
    vis = viseme_index(true)
    assert np.mean(vis == viseme_index(true)) == 1
    assert _r(opening, opening, true) == pytest.approx(1.0)
    assert segment_contact(opening, FPS, segs, BILABIALS, 0.5).fraction == 1.0
    assert viseme_contact(vis, FPS, segs, BILABIALS).all()


def test_a_constant_scores_r_zero_and_closure_only_at_its_chance_level(clip):
    segs, true, opening = clip
    n = len(true)
    for level in (0.0, 8.0):  # always closed, always open
        const = np.full(n, level)
        assert _r(const, opening, true) == 0.0
        met = segment_contact(const, FPS, segs, BILABIALS, 0.5)
        chance = chance_scores(true, FPS, segs, opening=const, reference=opening,
                               threshold=0.5)
        assert met.met.sum() == chance.closed / chance.n_shifts  # no better than shifted
        assert chance.r_terms == 0.0


def test_a_shifted_copy_scores_as_its_shift(clip):
    segs, true, opening = clip
    vis = viseme_index(true)
    chance = chance_scores(true, FPS, segs, visemes=vis, opening=opening, reference=opening,
                           threshold=0.5)
    ks = shifts(len(true))
    assert len(ks) == len(CHANCE_SHIFTS) and all(k != 0 for k in ks)
    hits = [np.sum(np.roll(vis, k) == vis) for k in ks]
    assert chance.viseme_hits == pytest.approx(sum(hits))
    terms = [speech_r_terms(np.roll(opening, k), opening, true)[0] for k in ks]
    assert chance.r_terms == pytest.approx(sum(terms))
    # and a shifted copy is far below the copy itself
    assert max(hits) < len(vis) and max(terms) / speech_r_terms(opening, opening, true)[1] < 0.5


def test_silence_only_agreement_earns_nothing_on_the_speech_frame_r(clip):
    segs, true, opening = clip
    # right in silence (closed) and wildly varying there, constant over speech
    pred = np.where(true == SIL, opening, 3.0)
    assert _r(pred, opening, true) == 0.0
    # while r over every frame would credit the silence
    assert np.corrcoef(pred, opening)[0, 1] > 0.3


def _row(model, rid, speaker, hits, frames, *, split="unseen", part="test", rate="native"):
    return {"model": model, "id": rid, "speaker": speaker, "split": split, "part": part,
            "labels": "independent", "input_rate": rate, "seconds": frames / FPS,
            "frames": frames, "viseme_hits": hits, "viseme_stream_hits": hits,
            "chance_viseme_hits": frames / 7, "bilabial_segments": 2,
            "bilabial_closed": hits % 3, "chance_closed": 0.5, "r_terms": hits / 2,
            "speech_frames": frames - 5, "chance_r_terms": 0.0, "phone_hits": hits}


@pytest.fixture
def rows():
    rng = np.random.default_rng(0)
    out = []
    for model in ("a", "b"):
        for i, spk in enumerate(["s1"] * 5 + ["s2"] * 2 + ["s3", "s4"]):
            frames = int(rng.integers(40, 90))
            out.append(_row(model, f"r{i}", spk, int(rng.integers(10, frames)), frames))
    out.append(_row("a", "x", "s9", 10, 50, split="seen"))
    return out


def test_pooled_rows_state_their_speakers_and_recordings(rows):
    mine = [r for r in rows if r["model"] == "a"]
    row = pool_rows(mine, "unseen-test", KEY, intervals=True)
    assert row["files"] == 9 and row["speakers"] == 4 and row["speaker_ids"] == "s1;s2;s3;s4"
    assert row["viseme_acc"] == pytest.approx(sum(r["viseme_hits"] for r in mine[:9])
                                              / sum(r["frames"] for r in mine[:9]))
    assert row["viseme_acc_lo"] < row["viseme_acc"] < row["viseme_acc_hi"]
    seen = pool_rows(mine, "seen", KEY, intervals=True)
    assert seen["files"] == 1 and seen["viseme_acc_lo"] is None
    assert seen["interval_note"] == "1 speaker; an interval needs at least 3"


def test_the_per_speaker_table_sums_to_the_pooled_counts(rows):
    table = [r for r in per_speaker(rows, KEY) if r["model"] == "a"]
    pooled_row = next(r for r in summarise(rows, KEY) if r["model"] == "a"
                      and r["split"] == "test")
    assert sum(r["files"] for r in table) == pooled_row["files"] == 10
    assert sum(r["frames"] for r in table) == sum(r["frames"] for r in rows if r["model"] == "a")
    weighted = sum(r["viseme_acc"] * r["frames"] for r in table) / sum(r["frames"]
                                                                         for r in table)
    assert weighted == pytest.approx(pooled_row["viseme_acc"])


def test_shared_draw_intervals_are_the_speaker_bootstraps_own(rng):
    spk = ["a"] * 4 + ["b"] * 2 + ["c", "d", "d"]
    h, h2, w = rng.random(9) * 10, rng.random(9) * 10, rng.integers(10, 20, 9).astype(float)
    for mine, theirs in ((interval(spk, h, w), speaker_interval(spk, h, w)),
                         (paired_interval(spk, h, h2, w), paired_speaker_interval(spk, h, h2, w))):
        # the same draws: equal up to the order of the floating-point sums
        assert (mine.lo, mine.hi) == pytest.approx((theirs.lo, theirs.hi), rel=1e-12)
        assert (mine.speakers, mine.recordings) == (theirs.speakers, theirs.recordings) == (4, 9)
    assert interval(spk[:6], h[:6], w[:6]) == speaker_interval(spk[:6], h[:6], w[:6])


def test_a_comparison_pairs_the_same_recordings(rows):
    row = compare(rows, "a", "b", "viseme_acc", KEY)
    assert row["files"] == 9 and row["speakers"] == 4
    assert row["difference"] == pytest.approx(row["a"] - row["b"])
    assert row["lo"] <= row["difference"] <= row["hi"]
    same = compare(rows, "a", "a", "viseme_acc", KEY)
    assert same["difference"] == 0 and same["lo"] == same["hi"] == 0
