"""The study design as pure functions: 27 trials in the paper's block order, per-participant
shuffles that a resumed session repeats, a balanced and reproducible allocation list, and
participant ids that cannot name a path."""
from collections import Counter

import pytest
from hypothesis import given, strategies as st

from groundwork.errors import ParameterError
from study.design import (
    N_TRIALS,
    allocation_sequences,
    check_participant_id,
    participant_seed,
    required_stimuli,
    session_trials,
)


@pytest.mark.parametrize("sequence, first, second", [("SR", "synthetic", "real"),
                                                     ("RS", "real", "synthetic")])
def test_27_trials_in_the_papers_block_order(sequence, first, second):
    trials = session_trials("P01", sequence, 2002)
    assert len(trials) == N_TRIALS == 27
    assert [t.trial_index for t in trials] == list(range(27))
    blocks = [(t.block, t.period) for t in trials]
    assert blocks == [("visual", 0)] * 6 + [("audio", 0)] * 3 + [("bimodal", 1)] * 9 + \
        [("bimodal", 2)] * 9
    assert {t.face for t in trials[9:18]} == {first} and {t.face for t in trials[18:]} == {second}
    # each block holds its full factorial design once
    visual = Counter((t.face, t.expression) for t in trials[:6])
    assert len(visual) == 6 and all(t.audio == "none" for t in trials[:6])
    assert all(t.stimulus_id.endswith("-normal") for t in trials[:6])  # silent 'normal' video
    assert sorted(t.audio for t in trials[6:9]) == ["bad", "good", "normal"]
    assert all(t.face == "none" and t.expression == "none" for t in trials[6:9])
    for part in (trials[9:18], trials[18:]):
        assert len({(t.expression, t.audio) for t in part}) == 9
    assert {t.stimulus_id for t in trials} <= set(required_stimuli())


def test_the_order_is_the_participants_own_and_repeats_exactly():
    a = session_trials("P01", "SR", 2002)
    assert session_trials("P01", "SR", 2002) == a
    others = [session_trials(p, "SR", 2002) for p in ("P02", "P03", "P04")]
    assert any(o != a for o in others)
    assert session_trials("P01", "SR", 7) != a  # another study seed, another order
    assert participant_seed(2002, "P01") == participant_seed(2002, "P01") < 2**63


def test_twenty_slots_are_ten_and_ten_reproducibly():
    seqs = allocation_sequences(20, 2002)
    assert Counter(seqs) == {"SR": 10, "RS": 10}
    assert allocation_sequences(20, 2002) == seqs
    assert allocation_sequences(20, 2003) != seqs
    for k in range(0, 20, 4):  # permuted blocks: balanced at every fourth participant
        assert Counter(seqs[k:k + 4]) == {"SR": 2, "RS": 2}


@given(n=st.integers(1, 60), seed=st.integers(0, 2**32))
def test_any_list_is_balanced_within_two(n, seed):
    c = Counter(allocation_sequences(n, seed))
    assert abs(c["SR"] - c["RS"]) <= 2 and sum(c.values()) == n


@pytest.mark.parametrize("pid", ["../x", "", "P 01", "a/b", "P01.csv", "x" * 33, "Jöns", None,
                                 "P01\n"])
def test_bad_participant_ids_are_refused(pid):
    with pytest.raises(ParameterError, match="use 1-32 letters or digits"):
        check_participant_id(pid)


def test_bad_sequences_and_sizes_are_refused():
    with pytest.raises(ParameterError, match="sequence 'SS'; allowed: SR, RS"):
        session_trials("P01", "SS", 1)
    with pytest.raises(ParameterError, match="positive number of slots, got 0"):
        allocation_sequences(0, 1)
