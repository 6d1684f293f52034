"""Progress of the recognisers (issue 42): a long recording heard with ``progress`` prints one
cost line and a bar on stderr, and hears exactly the phones it hears without; a pass of the
recognisers over several recordings counts them to n/n."""
import dataclasses
import re

import numpy as np
import pytest
import soxr

from analysis.speech_recogniser import recogniser_scores
from analysis.speech_set import load_speech_set
from mapping import recogniser
from mapping.recogniser import (COST_SAMPLE_S, cost_line, phone_stream, progress_bars,
                                recognise_windows)
from tests.terminal_text import screen_lines

SR = 22050  # a rate both streams resample from, as the mapping's audio is
COST = re.compile(r"(pocketsphinx|hama): (\d+\.\d) s of audio, ~(\d+\.\d\d) s of work per s "
                  r"of audio \(about \d+ (s|min) on this machine, measured on the first "
                  r"(\d+\.\d) s\)")


@pytest.fixture(scope="module")
def speech():
    """Two real recordings of the speech set (slt_a0009, ps_cards_001) at 22,050 Hz, one after
    the other: a recording longer than the cost sample and not a whole number of steps."""
    items = load_speech_set(ids=["slt_a0009", "ps_cards_001"])
    y = np.concatenate([soxr.resample(it.audio.astype(np.float32), it.sr, SR) for it in items])
    assert len(y) / SR > COST_SAMPLE_S + 1.5
    return y.astype(np.float32)


@pytest.fixture
def fresh(monkeypatch):
    """An empty cache of heard windows, so every call hears its audio."""
    monkeypatch.setattr(recogniser, "_HEARD", {})


@pytest.mark.parametrize("which", ["pocketsphinx", "hama"])
def test_a_recording_heard_with_progress_gives_the_same_windows(speech, which, fresh, capsys):
    quiet = recognise_windows(speech, SR, delay_frames=3, back=2, recogniser=which,
                              progress=False)
    assert capsys.readouterr().err == ""
    recogniser._HEARD.clear()
    shown = recognise_windows(speech, SR, delay_frames=3, back=2, recogniser=which,
                              progress=True)
    np.testing.assert_array_equal(shown, quiet)
    # and the same as one stream fed the whole audio at once
    s = phone_stream(which, SR, 30, 3, 2)
    s.push_windows(speech)
    s.flush_windows()
    np.testing.assert_array_equal(shown, s.windows)
    err = capsys.readouterr().err
    (line,) = [ln for ln in screen_lines(err) if COST.fullmatch(ln)]
    m = COST.fullmatch(line)
    assert m[1] == which and float(m[2]) == round(len(speech) / SR, 1)
    assert float(m[3]) > 0 and float(m[5]) == COST_SAMPLE_S
    total = f"{len(speech) / SR:.1f}"
    assert f"{which}: 100%" in err and f"{total}/{total}" in err  # the bar reached the end


def test_progress_bars_turns_the_bar_on_for_a_block_only(speech, fresh, capsys):
    y = speech[: int(1.5 * SR)]  # shorter than the cost sample: measured on all of it
    with progress_bars():
        recognise_windows(y, SR, recogniser="pocketsphinx")
        recognise_windows(y, SR, recogniser="pocketsphinx")  # heard already: no work, no bar
    err = capsys.readouterr().err
    assert len([ln for ln in screen_lines(err) if COST.fullmatch(ln)]) == 1
    assert "measured on the first 1.5 s" in err
    recogniser._HEARD.clear()
    recognise_windows(y, SR, recogniser="pocketsphinx")
    with progress_bars(False):
        recognise_windows(y[:SR], SR, recogniser="pocketsphinx")
    assert capsys.readouterr().err == ""


def test_the_cost_line_extrapolates_the_measured_rate():
    assert cost_line("hama", 600.0, 0.55, 2.0) == (
        "hama: 600.0 s of audio, ~0.55 s of work per s of audio (about 6 min on this machine, "
        "measured on the first 2.0 s)")
    assert "(about 30 s on" in cost_line("pocketsphinx", 60.0, 0.5, 2.0)


def test_a_pass_of_the_recognisers_over_recordings_counts_them(capsys):
    items = load_speech_set(ids=["slt_a0009", "ps_cards_001"])
    items = [*items, dataclasses.replace(items[0], id="slt_a0009_again")]
    shown = recogniser_scores(items, recognisers=("pocketsphinx",), progress=True)
    err = capsys.readouterr().err
    assert "recognisers: 100%" in err and "3/3" in err
    quiet = recogniser_scores(items, recognisers=("pocketsphinx",), progress=False)
    assert capsys.readouterr().err == ""
    assert repr(shown) == repr(quiet)  # the rows, pooled rows and curve (NaN where no score)
