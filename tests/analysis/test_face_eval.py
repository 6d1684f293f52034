"""Scoring predicted lips against a real face (analysis.face_eval), on tracks whose answer is
known by construction."""
from __future__ import annotations

import csv
import json
import re

import numpy as np
import pytest
from PIL import Image

from analysis.face_eval import (CSV_COLUMNS, ClipTrack, closure_events, closure_threshold,
                                opening_strip_figure, score_clips, write_scores_csv)
from analysis.speech_eval import correlation
from face_model.layout import default_layout
from groundwork.atomic import partial_path
from groundwork.errors import ParameterError

FPS = 30.0
HOLD = 3  # frames of each constructed closure


def speech_like(rng, n_events: int = 10, gap=(12, 24)):
    """Openings (px) of a talking mouth: open stretches (a smooth bump, 3 px at its edges up
    to 7–13 px) separated by ``n_events`` closures of :data:`HOLD` frames at 0.5–0.7 px; the
    closures' first frames."""
    parts, starts, k = [], [], 0
    for i in range(n_events + 1):
        g = int(rng.integers(gap[0], gap[1] + 1))
        bump = 3 + rng.uniform(4, 10) * np.sin(np.pi * np.arange(1, g + 1) / (g + 1))
        parts.append(bump)
        k += g
        if i < n_events:
            parts.append(0.5 + 0.2 * rng.random(HOLD))
            starts.append(k)
            k += HOLD
    return np.concatenate(parts), starts


def two_speakers(rng, clips_each: int = 2):
    """Real openings of clips ``a0, a1, …`` (speaker A, scale 1) and ``b0, …`` (speaker B,
    another mouth: twice the size and 4 px of offset)."""
    out = {}
    for spk, (scale, offset) in {"A": (1.0, 0.0), "B": (2.0, 4.0)}.items():
        for i in range(clips_each):
            out[f"{spk.lower()}{i}"] = (spk, scale * speech_like(rng)[0] + offset)
    return out


def test_an_affine_image_of_the_real_opening_scores_r_1_and_agrees_on_every_closure():
    rng = np.random.default_rng(1)
    real = two_speakers(rng)
    affine = {"A": (0.3, 40.0), "B": (2.5, -3.0)}  # each speaker's model draws its own scale
    tracks = [ClipTrack(c, s, x, affine[s][0] * x + affine[s][1], FPS)
              for c, (s, x) in real.items()]
    scores = score_clips(tracks)
    p = scores.pooled
    assert p["r_pooled"] == pytest.approx(1.0)
    assert [c.r for c in scores.clips] == pytest.approx([1.0] * 4)
    assert p["r_clip_mean"] == pytest.approx(1.0) and p["r_clip_median"] == pytest.approx(1.0)
    assert p["closure_events"] == 4 * 10  # every constructed closure, nothing else
    assert p["closures_agreed"] == 40 and p["closure_agreed_frac"] == 1.0
    assert p["predicted_closure_events"] == 40 and p["false_closures"] == 0
    # without the per-speaker normalisation the speakers' scales would decide pooled r
    naive = correlation(np.concatenate([t.real for t in tracks]),
                        np.concatenate([t.predicted for t in tracks]))
    assert naive < 0.9


@pytest.mark.parametrize("scramble", ["reversed", "shuffled"])
def test_a_reversed_or_shuffled_prediction_has_a_low_r(scramble):
    rng = np.random.default_rng(2)
    real = speech_like(rng, n_events=150)[0]
    pred = real[::-1].copy() if scramble == "reversed" else rng.permutation(real)
    scores = score_clips([ClipTrack("c", "A", real, 2 * pred + 1, FPS)])
    assert abs(scores.clips[0].r) < 0.2
    assert abs(scores.pooled["r_pooled"]) < 0.2


def test_a_prediction_with_one_closure_removed_loses_exactly_that_event():
    rng = np.random.default_rng(3)
    real, starts = speech_like(rng)
    pred = real.copy()
    gone = 4
    pred[starts[gone]:starts[gone] + HOLD] = 6.0  # the mouth stays open there
    scores = score_clips([ClipTrack("c", "A", real, 0.5 * pred + 2, FPS)])
    clip, track = scores.clips[0], scores.tracks[0]
    assert clip.closure_events == 10 and clip.closures_agreed == 9
    assert track.events == [(s, s + HOLD) for s in starts]
    assert track.agreed == [i != gone for i in range(10)]
    assert clip.false_closures == 0 and clip.predicted_closure_events == 9


def test_a_closure_the_real_lips_do_not_make_is_a_false_closure():
    rng = np.random.default_rng(4)
    real, starts = speech_like(rng, gap=(18, 24))
    pred = real.copy()
    k = starts[2] + HOLD + 8  # the middle of an open stretch, > 2 frames from any closure
    pred[k:k + 2] = 0.6
    clip = score_clips([ClipTrack("c", "A", real, pred, FPS)]).clips[0]
    assert (clip.closure_events, clip.closures_agreed) == (10, 10)
    assert (clip.predicted_closure_events, clip.false_closures) == (11, 1)


def test_an_event_needs_two_frames_and_agreement_allows_two_frames_of_offset():
    real = np.full(80, 8.0)
    for k in (10, 40, 50, 60, 70):
        real[k:k + 3] = 0.5  # events of 3 frames
    real[25] = 0.5  # a single low frame: no event
    assert closure_events(real, closure_threshold(real), 2) == [
        (k, k + 3) for k in (10, 40, 50, 60, 70)]
    for frame, agrees in [(13, True), (14, True), (15, False), (9, True), (8, True), (7, False)]:
        pred = real.copy()
        pred[10:13] = 8.0
        pred[25] = 8.0
        pred[frame] = 0.5  # one closed frame, after or before the first event
        track = score_clips([ClipTrack("c", "A", real, pred, FPS)]).tracks[0]
        assert track.agreed == [agrees] + [True] * 4, frame
        assert track.false == [False] * 4


def test_the_closed_level_is_p10_plus_a_tenth_of_the_p10_p90_range_and_rank_based():
    x = np.arange(101, dtype=float)  # P10 = 10, P90 = 90
    assert closure_threshold(x) == pytest.approx(10 + 0.1 * 80)
    assert np.isnan(closure_threshold(np.full(5, 3.0)))  # a still mouth has no closures
    rng = np.random.default_rng(5)
    y = speech_like(rng)[0]
    assert (closure_events(y, closure_threshold(y), 2)
            == closure_events(7 * y - 3, closure_threshold(7 * y - 3), 2))


def test_per_speaker_normalisation_makes_r_and_closures_invariant_to_a_speakers_scale():
    rng = np.random.default_rng(6)
    real = two_speakers(rng)
    noisy = {c: (s, x + rng.normal(0, 1.5, len(x))) for c, (s, x) in real.items()}

    def score(real_map, pred_map):
        return score_clips([ClipTrack(c, s, x, pred_map[c][1], FPS)
                            for c, (s, x) in real_map.items()])

    base = score(real, noisy)
    # speaker A's real face filmed larger and lower; speaker B's prediction drawn smaller
    moved = {c: (s, 3 * x + 50 if s == "A" else x) for c, (s, x) in real.items()}
    small = {c: (s, 0.2 * x - 7 if s == "B" else x) for c, (s, x) in noisy.items()}
    other = score(moved, small)
    assert other.pooled["r_pooled"] == pytest.approx(base.pooled["r_pooled"], abs=1e-12)
    assert [c.r for c in other.clips] == pytest.approx([c.r for c in base.clips], abs=1e-12)
    for key in ("closure_events", "closures_agreed", "false_closures"):
        assert other.pooled[key] == base.pooled[key]
    raw = [correlation(np.concatenate([m[c][1] for c in real]),
                       np.concatenate([p[c][1] for c in real]))
           for m, p in ((real, noisy), (moved, small))]
    assert raw[0] != pytest.approx(raw[1], abs=1e-3)  # unnormalised pooling is not invariant


def _z(x):
    x = np.asarray(x, float)
    return (x - x.mean()) / x.std()


@pytest.mark.parametrize("speakers", [("S", "S"), ("S", "T")])
def test_pooling_equals_the_hand_computation_on_two_small_clips(speakers):
    ra, pa = [1.0, 3, 2, 5, 4], [2.0, 2, 3, 6, 3]
    rb, pb = [10.0, 14, 12, 11], [0.5, 0.9, 0.7, 0.8, 0.6]  # one frame longer: trimmed
    scores = score_clips([ClipTrack("a", speakers[0], ra, pa, FPS),
                          ClipTrack("b", speakers[1], rb, pb, FPS)])
    pb = pb[:4]
    if speakers[0] == speakers[1]:  # one speaker: one mean and deviation over both clips
        zr, zp = _z(ra + rb), _z(pa + pb)
    else:
        zr, zp = np.concatenate([_z(ra), _z(rb)]), np.concatenate([_z(pa), _z(pb)])
    r_a, r_b = np.corrcoef(ra, pa)[0, 1], np.corrcoef(rb, pb)[0, 1]
    p = scores.pooled
    assert p["frames"] == 9 and [c.n_frames for c in scores.clips] == [5, 4]
    assert p["r_pooled"] == pytest.approx(np.corrcoef(zr, zp)[0, 1])
    assert [c.r for c in scores.clips] == pytest.approx([r_a, r_b])
    assert p["r_clip_mean"] == pytest.approx((r_a + r_b) / 2)
    assert p["r_clip_median"] == pytest.approx((r_a + r_b) / 2)
    assert np.concatenate([t.real for t in scores.tracks]) == pytest.approx(zr)
    assert p["speakers"] == len(set(speakers))


def test_openings_more_than_one_frame_apart_are_refused_naming_the_clip():
    with pytest.raises(ParameterError, match=re.escape(
            "clip 'spk1_007': real opening has 10 frames and predicted 12; they may differ by "
            "at most 1")):
        ClipTrack("spk1_007", "spk1", np.arange(10.0), np.arange(12.0), FPS)
    assert ClipTrack("c", "s", np.arange(10.0), np.arange(11.0)).n_frames == 10


@pytest.mark.parametrize("make, message", [
    (lambda: ClipTrack("c", "s", [1.0, np.nan, 2.0], [1.0, 2.0, 3.0]),
     "clip 'c': real opening has 1 non-finite frames; all must be finite"),
    (lambda: ClipTrack("c", "s", [1.0, 2.0], [1.0, 2.0], fps=0),
     "clip 'c': fps must be positive, got 0"),
    (lambda: ClipTrack("c", "s", [1.0, 2.0], [1.0, 2.0], real_markers=np.zeros((2, 79, 2))),
     "clip 'c': give both real and predicted markers, or neither"),
    (lambda: ClipTrack("c", "s", [1.0, 2.0], [1.0, 2.0], 30, np.zeros((2, 79, 2)),
                       np.zeros((3, 79, 2))),
     "clip 'c': predicted markers must have shape (2, 79, 2) to match its opening, got "
     "(3, 79, 2)"),
    (lambda: score_clips([]), "no clips to score; give at least one ClipTrack"),
    (lambda: score_clips([ClipTrack("c", "s", [1.0, 2.0], [1.0, 2.0])] * 2),
     "clip 'c' is given twice; clip ids must be unique"),
])
def test_bad_input_is_refused_with_one_line_naming_it(make, message):
    with pytest.raises(ParameterError, match=re.escape(message)):
        make()


def test_lve_is_the_mean_over_frames_of_the_worst_lip_marker_error():
    neutral = default_layout().neutral.astype(float)
    real = np.repeat(neutral[None], 4, axis=0)
    real[:, 71:76, 1] += np.array([0, 4, 8, 2])[:, None]  # the mouth opens and closes
    pred = real.copy()
    pred[0, 46] += (3, 4)  # 5 px: the worst lip marker of frame 0
    pred[0, 50] += (1, 0)
    pred[1, 72] += (0, -2)  # 2 px
    pred[2, 10] += (100, 0)  # a forehead marker: not counted; frame 2 is 0
    pred[3, 60] += (0, 1)  # 1 px
    one = ClipTrack.from_markers("a", "S", real, pred, FPS)
    other = ClipTrack.from_markers("b", "S", real[:2], real[:2] + (0, 3), FPS)  # 3 px each
    unseen = ClipTrack.from_markers("c", "T", real, pred, FPS, lve=False)
    scores = score_clips([one, other, unseen])
    assert scores.clips[0].lve_px == pytest.approx((5 + 2 + 0 + 1) / 4)
    assert scores.clips[1].lve_px == pytest.approx(3.0)
    assert np.isnan(scores.clips[2].lve_px)
    assert scores.pooled["lve_px"] == pytest.approx((5 + 2 + 0 + 1 + 3 + 3) / 6)
    assert scores.pooled["lve_clips"] == 2


def test_the_table_and_the_dict_hold_every_clip_and_the_pooled_figures(tmp_path):
    rng = np.random.default_rng(7)
    tracks = [ClipTrack(c, s, x, x + rng.normal(0, 1, len(x)), FPS)
              for c, (s, x) in two_speakers(rng).items()]
    scores = score_clips(tracks)
    path = write_scores_csv(scores, tmp_path / "face_scores.csv")
    assert not partial_path(path).exists()
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0]) == CSV_COLUMNS
    assert [r["clip"] for r in rows] == ["a0", "a1", "b0", "b1"]
    assert [float(r["r"]) for r in rows] == [c.r for c in scores.clips]
    assert all(r["lve_px"] == "nan" for r in rows)
    d = json.loads(json.dumps(scores.to_dict(), allow_nan=False))  # strict JSON: NaN as null
    assert d["pooled"]["lve_px"] is None and d["pooled"]["clips"] == 4
    assert d["rule"]["closed_percentile"] == 10.0
    assert [s["speaker"] for s in d["speakers"]] == ["A", "B"]
    assert d["clips"][0]["closure_agreed_frac"] == scores.clips[0].closure_agreed_frac


def test_the_strip_figure_is_written_for_a_scored_or_a_lone_track(tmp_path):
    rng = np.random.default_rng(8)
    real, starts = speech_like(rng)
    pred = real.copy()
    pred[starts[1]:starts[1] + HOLD] = 6.0
    pred[starts[5] + HOLD + 8:starts[5] + HOLD + 10] = 0.6
    scores = score_clips([ClipTrack("c", "A", real, pred, FPS)])
    for arg, name in ((scores.tracks[0], "scored.png"), (ClipTrack("c", "A", real, pred),
                                                         "lone.png")):
        path = opening_strip_figure(arg, tmp_path / name, "clip c: real vs predicted")
        with Image.open(path) as im:
            assert im.width > 500 and im.height > 200
