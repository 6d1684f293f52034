"""The front ends on real speech (issue 29): the look-ahead curve read from one decoding equals a
stream per look-ahead, and the recognisers' rows split the test part by where its labels came
from.

The tests that score the recognisers read them through one content-keyed cache for the module
(``heard``): each recording is heard once at each rate, however many tests score it
(tests/mapping/test_hearing.py proves the rows read through the cache are the rows heard one by
one)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from analysis.speech_recogniser import (LABELS, LOOKAHEAD_FRAMES, RECOGNISERS, PhoneRecogniser,
                                        lookahead_figure, recogniser_scores)
from analysis.speech_set import load_speech_set
from groundwork.cache import ArrayCache
from groundwork.errors import ParameterError
from mapping import hama_front
from mapping.recogniser import hearing_cache, recogniser_name


@pytest.fixture(scope="module")
def two():
    # one recording with independent (HTS) labels, one labelled by pocketsphinx's alignment
    # (put in a development part here, to see both parts)
    slt, cards = load_speech_set(ids=["slt_a0009", "ps_cards_001"])
    return [slt, dataclasses.replace(cards, part="dev")]


@pytest.fixture(scope="module")
def heard(tmp_path_factory):
    """The module's cache of what the recognisers heard (``with hearing_cache(heard):``)."""
    return ArrayCache(tmp_path_factory.mktemp("heard"))


def test_hama_curve_from_one_decoding_equals_a_stream_per_look_ahead(two):
    """On a whole recording (1.1 s: 33 frames, 11 decodes, the first ones filled with silence,
    the last frames of every look-ahead decided at the end of the audio), the curve read from
    one stream's decodes is, for every look-ahead, what a stream with that look-ahead
    decides."""
    it = two[1]
    curve = hama_front.labels_at_delays(it.audio, it.sr, 30, LOOKAHEAD_FRAMES)
    for d in LOOKAHEAD_FRAMES:
        stream = hama_front.HamaStream(it.sr, 30, d, 0)
        stream.push(it.audio)
        stream.flush()
        assert np.array_equal(curve[d], stream.labels), d


def test_pocketsphinx_curve_from_one_decoding_equals_a_decoding_per_look_ahead(two):
    it = two[1]
    rec = PhoneRecogniser()
    many = rec.streaming_delays(it.audio, it.sr, [k / 30 for k in LOOKAHEAD_FRAMES])
    for k, labels in zip(LOOKAHEAD_FRAMES, many):
        assert np.array_equal(labels, rec.streaming(it.audio, it.sr, k / 30)), k


def test_the_recognisers_rows_split_the_test_part_by_label_source(two, heard, tmp_path):
    with hearing_cache(heard):
        files, summary, curve = recogniser_scores(two)
    assert {r["model"] for r in files} == {recogniser_name(r) for r in RECOGNISERS}
    by = {(r["model"], r["split"]): r for r in summary}
    for name in map(recogniser_name, RECOGNISERS):
        # slt_a0009 is a test recording with HTS labels, ps_cards_001 (aligned) put in a
        # development part by the fixture
        assert by[(name, "unseen-test-independent")]["files"] == 1
        assert by[(name, "unseen-test-aligned")]["files"] == 0
        assert by[(name, "unseen-dev")]["files"] == 1
        indep = next(r for r in files if r["model"] == name and r["id"] == "slt_a0009")
        assert indep["labels"] == LABELS[0] and indep["speaker"] == "arctic-slt"
        row = by[(name, "unseen-test-independent")]
        assert row["viseme_acc"] == indep["viseme_acc"]
        # one speaker: no interval, and the row says why
        assert row["speakers"] == 1 and row["speaker_ids"] == "arctic-slt"
        assert row["viseme_acc_lo"] is None and "1 speaker" in row["interval_note"]
        # its chance baseline: the same labels shifted, far below the recogniser
        assert row["chance_viseme_acc"] < row["viseme_acc"]
        # the 100-ms column is the curve's 3-frame point
        point = next(r for r in curve if r["model"] == name and r["lookahead_frames"] == 3
                     and r["split"] == "unseen-test-independent")
        assert point["viseme_acc"] == indep["viseme_acc_stream_100ms"]
        assert len([r for r in curve if r["model"] == name and r["split"] == "all"]) == \
            len(LOOKAHEAD_FRAMES)
        # both hear the sentence: well above chance on its independent labels
        assert indep["viseme_acc"] > row["chance_viseme_acc"] + 0.1
    png = lookahead_figure(curve, tmp_path / "lookahead.png")
    assert png.stat().st_size > 10_000


def test_a_seen_speaker_is_never_in_an_unseen_row(two, heard):
    with hearing_cache(heard):
        files, summary, _ = recogniser_scores(two[:1], frozenset({"arctic-slt"}),
                                              recognisers=("hama",))
    by = {r["split"]: r for r in summary}
    assert by["seen"]["files"] == 1 and by["unseen"]["files"] == 0
    assert by["unseen-test"]["files"] == 0 and files[0]["split"] == "seen"


def test_an_8_khz_input_is_scored_as_given(two, heard):
    with hearing_cache(heard):
        files, _, _ = recogniser_scores(two[:1], recognisers=("hama",),
                                        rates=("native", 8000))
    native, low = files
    assert (native["input_rate"], low["input_rate"]) == ("native", "8000")
    assert native["frames"] == low["frames"] and low["rate_note"] == ""


def test_a_look_ahead_off_the_curve_is_refused(two):
    with pytest.raises(ParameterError, match=r"delay_s 0\.05 is not one of the look-aheads"):
        recogniser_scores(two[:1], delay_s=0.05)
