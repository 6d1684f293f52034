"""Coarticulation (Cohen & Massaro, 1993): dominance-weighted targets, forced bilabial closure."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from data_synth.articulation import Articulation, coarticulate
from face_model.corpus import PhoneSegment
from face_model.phones import ARTIC_PARAMS, BILABIALS, PHONE_INDEX, PHONES, target_matrix
from groundwork.errors import ParameterError

CLOSURE = ARTIC_PARAMS.index("closure")
PROTRUSION = ARTIC_PARAMS.index("protrusion")
EPS = np.finfo(float).eps


def _segments(spec):
    """[("sil", 0.1), ("b", 0.08), ...] → contiguous PhoneSegments starting at 0."""
    out, t = [], 0.0
    for phone, dur in spec:
        out.append(PhoneSegment(t, t + dur, phone))
        t += dur
    return out


SENTENCE = _segments([("sil", 0.2), ("ax", 0.06), ("b", 0.07), ("aa", 0.15), ("m", 0.08),
                      ("iy", 0.12), ("s", 0.09), ("p", 0.06), ("uw", 0.14), ("sil", 0.25)])


def test_bilabial_closure_is_one_inside_every_p_b_m_segment():
    t = np.arange(0.0, SENTENCE[-1].end_s, 0.001)
    traj = coarticulate(SENTENCE, t)
    assert traj.shape == (len(t), len(ARTIC_PARAMS))
    inside_any = np.zeros(len(t), bool)
    for seg in SENTENCE:
        if seg.phone in BILABIALS:
            inside = (t >= seg.start_s) & (t < seg.end_s)
            assert inside.sum() > 50
            assert np.all(traj[inside, CLOSURE] == 1.0)
            inside_any |= inside
    # Elsewhere the closure is a dominance-weighted mean below 1 that still anticipates the lips
    # closing: it rises before each bilabial begins.
    assert np.all(traj[~inside_any, CLOSURE] < 1.0)
    b = SENTENCE[2]
    before = traj[(t > b.start_s - 0.03) & (t < b.start_s), CLOSURE]
    assert np.all(np.diff(before) > 0) and before[-1] > 0.3


def test_long_silence_relaxes_to_the_rest_target():
    segs = _segments([("aa", 0.2), ("sil", 3.0), ("uw", 0.2)])
    assert np.array_equal(target_matrix()[PHONE_INDEX["sil"]], np.zeros(len(ARTIC_PARAMS)))
    t = np.linspace(1.2, 2.2, 101)  # at least a second from both vowels
    np.testing.assert_allclose(coarticulate(segs, t), 0.0, rtol=0, atol=1e-7)
    # The relaxation is gradual: after the vowel the jaw closes monotonically towards rest, and
    # the lips round monotonically ahead of the next (rounded) vowel.
    jaw = ARTIC_PARAMS.index("jaw")
    after = coarticulate(segs, np.linspace(0.2, 1.2, 101))[:, jaw]
    assert after[0] > 0.1 and np.all(np.diff(after) < 0)
    ahead = coarticulate(segs, np.linspace(2.2, 3.2, 101, endpoint=False))[:, PROTRUSION]
    assert ahead[-1] > 0.1 and np.all(np.diff(ahead) > 0)


@pytest.mark.parametrize("phone", PHONES)
def test_single_phone_returns_its_target(phone):
    t = np.linspace(-0.3, 0.6, 181)  # inside and up to 0.3 s around the segment
    traj = coarticulate([PhoneSegment(0.0, 0.3, phone)], t)
    target = target_matrix()[PHONE_INDEX[phone]]
    # Exact up to the rounding of (alpha·D·T) / (alpha·D): at most a couple of ulps.
    np.testing.assert_allclose(traj, np.broadcast_to(target, traj.shape), rtol=0, atol=4 * EPS)


@pytest.mark.parametrize("phone", ["hh", "aa"])
def test_single_phone_returns_its_target_far_from_the_segment(phone):
    """F = Σ D T / Σ D equals T for one segment at any time; the dominance only decays.

    Library bug: the denominator is floored at 1e-12, which is larger than the dominance of a
    phone about a second from its centre (alpha · exp(-25 · 1.1) ≈ 1e-12), so the trajectory
    collapses towards 0 there instead of staying at the target.
    """
    t = np.linspace(-3.0, 3.3, 64)
    traj = coarticulate([PhoneSegment(0.0, 0.3, phone)], t)
    target = target_matrix()[PHONE_INDEX[phone]]
    np.testing.assert_allclose(traj, np.broadcast_to(target, traj.shape), rtol=0, atol=1e-9)


def test_anticipation_reaches_further_than_carry_over():
    """θ_anticipation (16/s) < θ_carry-over (25/s): rounding shows earlier than it lingers."""
    segs = _segments([("sil", 1.0), ("uw", 0.2), ("sil", 1.0)])
    centre = 1.1
    for delta in (0.15, 0.2, 0.3):
        before, after = coarticulate(segs, np.array([centre - delta, centre + delta]))
        assert before[PROTRUSION] > after[PROTRUSION] > 0
    before, after = coarticulate(segs, np.array([centre - 0.2, centre + 0.2]),
                                 Articulation.table(theta_anticipation=25.0,
                                                    theta_carryover=25.0))
    np.testing.assert_allclose(before, after, rtol=1e-12)


@given(spec=st.lists(st.tuples(st.sampled_from(PHONES), st.floats(0.02, 0.3)), min_size=1,
                     max_size=12),
       theta=st.tuples(st.floats(5.0, 80.0), st.floats(5.0, 80.0)))
def test_trajectory_is_a_mix_of_the_segments_targets(spec, theta):
    segs = _segments(spec)
    t = np.linspace(0.0, segs[-1].end_s, 97, endpoint=False)
    traj = coarticulate(segs, t, Articulation.table(theta[0], theta[1]))
    targets = target_matrix()[[PHONE_INDEX[p] for p, _ in spec]]
    assert np.all(np.isfinite(traj))
    assert np.all(traj >= targets.min(0) - 1e-12)
    assert np.all(traj <= targets.max(0) + 1e-12)  # forced closure only where a target is 1


@pytest.mark.parametrize("kwargs,shown", [
    ({"theta_anticipation": 0.0}, "0.0, 25.0, 1.0"),
    ({"theta_anticipation": -3.0}, "-3.0, 25.0, 1.0"),
    ({"theta_carryover": 0.0}, "16.0, 0.0, 1.0"),
    ({"theta_carryover": -1.0}, "16.0, -1.0, 1.0"),
    ({"power": 0.0}, "16.0, 25.0, 0.0"),
    ({"power": -2.0}, "16.0, 25.0, -2.0"),
])
def test_non_positive_rates_are_refused(kwargs, shown):
    with pytest.raises(ParameterError, match=f"articulation table: dominance rates and power "
                                             f"must be positive, got {shown}"):
        coarticulate(SENTENCE, np.array([0.1]), Articulation.table(**kwargs))


def test_no_segments_is_refused():
    with pytest.raises(ParameterError, match="coarticulate: no phone segments"):
        coarticulate([], np.array([0.0]))
