"""The development rule weighs the development part's two kinds of recording equally (issue 51):
sentences and digits, each the mean of the figures it measures; a run without per-kind rows
scores the pooled development rows; a child missing a kind gets no score; each kind's items and
rows say which kind they are."""
from __future__ import annotations

import math

import pytest

from analysis.dev_rule import (AUDIO_KINDS, DEV_RULE, POOLED, audio_splits, dev_choice,
                               dev_parts, dev_rule_figures)
from analysis.speech_pooling import SPLITS
from analysis.speech_set import FSDD_WORDS, GRID_WORDS, load_speech_set, read_manifest

NAN = float("nan")


def _row(model, split, viseme, bilabial, labiodental, r):
    return {"model": model, "split": split, "input_rate": "native",
            **dict(zip(DEV_RULE, (viseme, bilabial, labiodental, r)))}


@pytest.fixture
def results():
    """Child a leads on digits (many recordings: it leads the pooled rows), child b on
    sentences, where /p b m/ closure is measured; digits measure no closure."""
    return [
        _row("voices-a", POOLED, 0.75, 0.35, 0.65, 0.55),  # mean 0.575
        _row("voices-a", "unseen-dev-digits", 0.80, NAN, 0.70, 0.60),     # mean 0.70
        _row("voices-a", "unseen-dev-sentences", 0.40, 0.30, 0.20, 0.30),  # mean 0.30
        _row("voices-b", POOLED, 0.60, 0.50, 0.50, 0.50),  # mean 0.525
        _row("voices-b", "unseen-dev-digits", 0.60, NAN, 0.50, 0.40),     # mean 0.50
        _row("voices-b", "unseen-dev-sentences", 0.70, 0.80, 0.60, 0.50),  # mean 0.65
        _row("voices-b", "unseen-test", 1, 1, 1, 1),                      # never counts
    ]


def test_each_kind_weighs_half_with_its_own_measured_figures(results):
    assert audio_splits(results) == ("unseen-dev-sentences", "unseen-dev-digits")
    assert dev_rule_figures(results, split="unseen-dev-digits") == (
        "viseme_acc", "labiodental_contact_frac", "r_reference")
    assert dev_rule_figures(results, split="unseen-dev-sentences") == DEV_RULE
    parts = dev_parts(results)
    assert parts["voices-a"]["kinds"] == pytest.approx(
        {"unseen-dev-sentences": 0.30, "unseen-dev-digits": 0.70})
    assert parts["voices-a"]["audio"] == pytest.approx(0.50)
    assert parts["voices-b"]["audio"] == pytest.approx((0.65 + 0.50) / 2)
    best, scores = dev_choice(results)
    assert best == "voices-b" and scores["voices-b"] == pytest.approx(0.575)


def test_without_kinds_the_pooled_development_rows_decide(results):
    pooled = [r for r in results if r["split"] in (POOLED, "unseen-test")]
    assert audio_splits(pooled) == (POOLED,)
    best, scores = dev_choice(pooled)
    assert best == "voices-a" and scores["voices-a"] == pytest.approx(0.575)


def test_a_child_missing_a_kind_gets_no_score(results):
    rows = [r for r in results if not (r["model"] == "voices-b"
                                       and r["split"] == "unseen-dev-sentences")]
    parts = dev_parts(rows)
    assert set(parts) == {"voices-a"}
    assert dev_choice(rows)[0] == "voices-a"


def test_a_figure_missing_in_one_kind_only_leaves_that_child_out(results):
    rows = [dict(r) for r in results]
    next(r for r in rows if r["model"] == "voices-a"
         and r["split"] == "unseen-dev-sentences")["bilabial_closed_frac"] = NAN
    assert set(dev_parts(rows)) == {"voices-b"}


def test_the_kinds_are_the_splits_the_pooling_knows():
    for split in AUDIO_KINDS:
        assert split in SPLITS
    row = {"split": "unseen", "part": "dev", "kind": "sentences"}
    assert SPLITS["unseen-dev-sentences"](row) and not SPLITS["unseen-dev-digits"](row)
    assert SPLITS["unseen-dev"](row)
    assert not SPLITS["unseen-dev-sentences"]({**row, "part": "test"})


def test_digits_are_the_fsdd_words_and_everything_else_sentences():
    ids = [r["id"] for r in read_manifest() if r["part"] == "dev"]
    items = load_speech_set(ids=ids)
    kinds = {(it.speaker, it.kind) for it in items}
    assert kinds == {("fsdd-jackson", "digits"), ("fsdd-lucas", "digits"),
                     ("grid-s26", "sentences")}
    assert all((it.label_source == FSDD_WORDS) == (it.kind == "digits") for it in items)
    assert {it.label_source for it in items if it.kind == "sentences"} == {GRID_WORDS}
    assert not math.isnan(sum(it.duration_s for it in items))
