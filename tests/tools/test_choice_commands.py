"""The commands that re-run the sweeps behind constants chosen on data (issue 37): each recovers a
known optimum on made-up input, ``--check`` fails with one line on a mismatch, the boundary
parameter of hama's spike reading keeps the old behaviour at the midpoint (the default until the
sweep chose otherwise), and the committed hama constants are the development sweep's pick."""
from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from analysis.speech_eval import phone_frames, viseme_index
from analysis.dev_rule import DEV_RULE
from face_model.corpus import PhoneSegment
from face_model.phones import PHONE_INDEX
from groundwork.errors import ParameterError
from mapping import hama_front
from mapping.hama_front import SILENCE, Timing, output_classes

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import choose_alignment_threshold as threshold_tool  # noqa: E402
import choose_hama_timing as hama_tool  # noqa: E402
import choose_voice_model as voice_tool  # noqa: E402

FPS = 30


# -- hama's timing ------------------------------------------------------------------------------

def _token(phone: str) -> int:
    _, classes, _ = hama_front.model()
    return int(np.flatnonzero(classes == PHONE_INDEX[phone])[0])


def _posteriors(spikes: list[tuple[int, int]], n_out: int) -> np.ndarray:
    """Log posteriors (n_out, 191): blank everywhere but at each (frame, token) spike."""
    _, classes, blank = hama_front.model()
    lp = np.full((n_out, len(classes)), np.log(1e-4))
    lp[:, blank] = np.log(0.9)
    for frame, token in spikes:
        lp[frame, token] = np.log(0.95)
    return lp


@pytest.mark.parametrize("lag", [1, 2, 3])
def test_the_hama_sweep_recovers_a_known_spike_lag(lag):
    # 60 phones of 6–16 output frames (20 ms each, seeded), each with its CTC spike `lag`
    # output frames after the segment's middle frame: the sweep's best lag is `lag`
    rng = np.random.default_rng(7)
    phones = ["aa", "m", "iy", "f", "uw"]
    lengths = rng.integers(6, 17, size=60)
    starts = np.r_[0, np.cumsum(lengths)[:-1]]
    names = [phones[i % len(phones)] for i in range(len(lengths))]
    segs = [PhoneSegment(s / 50, (s + n) / 50, p) for s, n, p in zip(starts, lengths, names)]
    lp = _posteriors([(int(s + n // 2 + lag), _token(p))
                      for s, n, p in zip(starts, lengths, names)], int(lengths.sum()) + 8)
    true = viseme_index(phone_frames(segs, np.arange(int(lengths.sum()) * 3 // 5) / FPS))
    rows = hama_tool.sweep_timing([(lp, 0)], [true])
    best = hama_tool.pick(rows)
    assert (best["lag"], best["boundary"]) == (lag, 0.5)
    # every other lag at the midpoint, at any reach, gets fewer frames right (an earlier
    # boundary at the lag before may tie: the stated order puts the midpoint first)
    assert max(r["hits"] for r in rows if r["lag"] != lag and r["boundary"] == 0.5) \
        < best["hits"]
    assert best["hits"] > 0.9 * len(true)


def test_ties_go_to_the_first_row_in_the_stated_order():
    grid = hama_tool.timing_grid()
    assert [(t.lag, t.reach, t.boundary) for t in grid[:4]] == [
        (0, 1, 0.5), (0, 1, 0.35), (0, 1, 0.65), (0, 2, 0.5)]
    rows = [{"lag": 2, "hits": 5}, {"lag": 1, "hits": 7}, {"lag": 0, "hits": 7}]
    assert hama_tool.pick(rows)["lag"] == 1


def _old_output_classes(log_probs, reach):
    """output_classes as it was before the boundary parameter (nearest spike, ties left)."""
    _, classes, blank = hama_front.model()
    best = np.asarray(log_probs).argmax(axis=1)
    before = np.r_[-1, best[:-1]]
    spikes = np.nonzero((best != blank) & (classes[best] >= 0) & (best != before))[0]
    out = np.full(len(best), SILENCE, dtype=np.int64)
    if not len(spikes):
        return out
    frames = np.arange(len(best))
    right = np.clip(np.searchsorted(spikes, frames), 0, len(spikes) - 1)
    left = np.clip(right - 1, 0, len(spikes) - 1)
    nearest = np.where(np.abs(frames - spikes[left]) <= np.abs(spikes[right] - frames),
                       spikes[left], spikes[right])
    near = np.abs(nearest - frames) <= reach
    out[near] = classes[best[nearest[near]]]
    return out


@pytest.mark.parametrize("seed", range(6))
def test_the_midpoint_boundary_gives_the_old_output(seed):
    rng = np.random.default_rng(seed)
    tokens = [_token(p) for p in ("aa", "m", "iy", "f", "uw")]
    n_out = 120
    frames = np.sort(rng.choice(n_out, size=rng.integers(1, 25), replace=False))
    lp = _posteriors([(int(f), int(rng.choice(tokens))) for f in frames], n_out)
    for reach in (1, 3, 6, 50):
        old = _old_output_classes(lp, reach)
        # the midpoint is the rule as it was; the default is the module's chosen BOUNDARY
        np.testing.assert_array_equal(output_classes(lp, reach=reach, boundary=0.5), old)
        np.testing.assert_array_equal(output_classes(lp, reach=reach),
                                      output_classes(lp, reach=reach,
                                                     boundary=hama_front.BOUNDARY))


def test_an_earlier_boundary_hands_frames_to_the_next_spike():
    a, m = _token("aa"), _token("m")
    lp = _posteriors([(0, a), (10, m)], 11)
    mid = output_classes(lp, reach=20, boundary=0.5)
    early = output_classes(lp, reach=20, boundary=0.35)
    assert list(mid).count(PHONE_INDEX["aa"]) == 6  # frames 0–5: f − 0 ≤ 0.5 · 10
    assert list(early).count(PHONE_INDEX["aa"]) == 4  # frames 0–3: f − 0 ≤ 3.5
    with pytest.raises(ParameterError, match=r"boundary must be .* in \(0, 1\), got 1\.0"):
        output_classes(lp, boundary=1.0)


def test_the_hama_check_names_each_constant_that_differs():
    result = {"pick": {"SPIKE_LAG": 3, "REACH": 6}, "constants": {"SPIKE_LAG": 2, "REACH": 6}}
    assert hama_tool.differences(result) == ["SPIKE_LAG 2 → 3"]


def test_the_committed_hama_timing_is_the_development_sweeps_pick(capsys):
    # the real development part (whatever rows have part dev now), each recording decoded once;
    # the stream constants (EDGE, RESAMPLE_QUALITY) need a stream per resampler quality, several
    # times the cost: `python tools/choose_hama_timing.py --check` checks them too
    assert hama_tool.main(["--check", "--no-stream"]) == 0, capsys.readouterr().err
    assert capsys.readouterr().out.strip() == ("mapping/hama_front.py: the constants are the "
                                               "development sweep's pick")


# -- the voices grid's default ------------------------------------------------------------------

def _results(tmp_path: Path, rows: list[tuple]) -> Path:
    run = tmp_path / "run"
    (run / "speech_eval").mkdir(parents=True)
    with open(run / "speech_eval" / "results.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["model", "split", *DEV_RULE])
        w.writerows(rows)
    return run


@pytest.fixture
def run_dir(tmp_path):
    return _results(tmp_path, [
        ("voices-one-voice", "unseen-dev", 0.60, 0.50, 0.40, 0.30),  # mean 0.45
        ("voices-hama", "unseen-dev", 0.80, 0.70, 0.60, 0.50),  # mean 0.65: the best
        ("voices-hama", "unseen-test", 0.10, 0.10, 0.10, 0.10),  # test rows never count
        ("voices-many", "unseen-dev", 0.90, 0.90, "nan", 0.90),  # incomplete: no score
        ("voices-many", "unseen-test", 1, 1, 1, 1),
        ("gated_mlp_utterance", "unseen-dev", 1, 1, 1, 1)])  # not a voices child


def _voices(tmp_path: Path, model: str) -> Path:
    path = tmp_path / "voices.yaml"
    path.write_text(f"model: {model}\nchildren:\n  one-voice: {{}}\n", encoding="utf-8")
    return path


def test_the_voice_chooser_picks_the_best_development_mean(run_dir, capsys):
    result = voice_tool.choose(voice_tool.read_results(run_dir))
    assert result["pick"] == "hama"
    scores = {r["child"]: r["score"] for r in result["rows"]}
    assert scores["hama"] == pytest.approx(0.65) and scores["one-voice"] == pytest.approx(0.45)
    assert scores["many"] is None and "gated_mlp_utterance" not in scores
    assert voice_tool.main([str(run_dir), "--voices", str(_voices(run_dir, "hama"))]) == 0
    assert "pick: hama" in capsys.readouterr().out


def test_the_voice_check_fails_with_one_line_on_a_mismatch(run_dir, capsys):
    voices = _voices(run_dir, "one-voice")
    assert voice_tool.main([str(run_dir), "--voices", str(voices), "--check"]) == 1
    err = capsys.readouterr().err
    assert err.strip() == (f"{voices}: model is 'one-voice' but the development rule picks "
                           f"'hama'")
    assert voice_tool.main([str(run_dir), "--voices", str(_voices(run_dir, "hama")),
                            "--check"]) == 0


def test_a_figure_the_development_part_cannot_measure_is_left_out_for_every_child(tmp_path,
                                                                                 capsys):
    """Digits hold no /p b m/: closure is NaN for every child, so the rule is the mean of the
    other three for all of them alike; a child missing a measured figure still gets no score."""
    run = _results(tmp_path, [
        ("voices-a", "unseen-dev", 0.50, "nan", 0.60, 0.10),  # mean of three 0.40
        ("voices-b", "unseen-dev", 0.40, "nan", 0.20, 0.30),  # 0.30
        ("voices-c", "unseen-dev", 0.90, "nan", "nan", 0.90)])  # incomplete: no score
    result = voice_tool.choose(voice_tool.read_results(run))
    assert result["figures"] == {"unseen-dev": ["viseme_acc", "labiodental_contact_frac",
                                                "r_reference"]}
    scores = {r["child"]: r["score"] for r in result["rows"]}
    assert result["pick"] == "a" and scores["a"] == pytest.approx(0.4)
    assert scores["b"] == pytest.approx(0.3) and scores["c"] is None
    assert voice_tool.main([str(run), "--voices", str(_voices(run, "a"))]) == 0
    assert "bilabial_closed_frac: not measured on the development part" in capsys.readouterr().out


def test_the_voice_chooser_names_a_missing_results_file(tmp_path, capsys):
    assert voice_tool.main([str(tmp_path), "--voices", str(_voices(tmp_path, "x"))]) == 2
    assert "speech_eval/results.csv: not found" in capsys.readouterr().err


# -- the transcript check's threshold ---------------------------------------------------------

def test_the_threshold_chooser_recovers_the_known_optimum():
    nan = float("nan")
    # own: refused below −threshold or when unaligned (nan); wrong: accepted at or above it
    own = [6.0, 4.0, 2.0, -1.2, -2.8, nan]
    wrong = [-12.0, -9.0, -5.3, -4.6, nan, nan]
    # errors: own refused 3 (t < 1.2), 2 (t < 2.8), 1; wrong accepted 0 (t < 4.6), 1, 2 (t ≥ 5.3)
    # the least total error, 1/6, holds for 2.8 ≤ t < 4.6: the smallest candidate there is 3.0
    pick, rows = threshold_tool.choose_threshold(own, wrong)
    assert pick == 3.0
    by = {r["threshold"]: r for r in rows}
    assert by[3.0]["total_error"] == pytest.approx(1 / 6)
    assert (by[4.5]["own_refused"], by[4.5]["wrong_accepted"]) == (1, 0)
    assert (by[5.0]["own_refused"], by[5.0]["wrong_accepted"]) == (1, 1)
    assert (by[1.0]["own_refused"], by[1.0]["wrong_accepted"]) == (3, 0)
    assert min(r["total_error"] for r in rows) == pytest.approx(1 / 6)
    with pytest.raises(ParameterError, match="need own and wrong transcripts"):
        threshold_tool.choose_threshold([], wrong)


def test_the_threshold_check_fails_with_one_line_on_a_mismatch():
    line = threshold_tool.check_line({"constant": 4.0, "pick": 3.5})
    assert line == ("face_model/forced_align.py: MAX_SCORE_GAP is 4 but the development sweep "
                    "picks 3.5")
    assert threshold_tool.check_line({"constant": 4.0, "pick": 4.0}) is None


def test_the_threshold_halves_and_wrong_transcripts_follow_the_sorted_ids(tmp_path):
    grid = tmp_path / "grid"
    (grid / "video").mkdir(parents=True)
    (grid / "align").mkdir()
    ids = [f"c{i:02d}" for i in range(20)]
    for i, c in enumerate(ids):
        (grid / "video" / f"{c}.mpg").write_bytes(b"")
        (grid / "align" / f"{c}.align").write_text(
            f"0 1000 sil\n1000 2000 w{i}\n2000 3000 x\n3000 4000 y\n4000 5000 z\n",
            encoding="utf-8")
    jobs = threshold_tool.jobs(grid)
    assert [j["part"] for j in jobs] == ["dev"] * 10 + ["check"] * 10
    first = jobs[0]["transcripts"]
    assert first == {"own": "w0 x y z", "other": "w7 x y z", "first3": "w0 x y"}
    assert jobs[5]["transcripts"]["other"] == "w2 x y z"  # 7 places further, wrapping in its half
    assert jobs[10]["transcripts"]["other"] == "w17 x y z"
    assert [j["id"] for j in threshold_tool.jobs(grid, every=5)] == ["c00", "c05", "c10", "c15"]


def test_the_voice_chooser_weighs_sentences_and_digits_equally(tmp_path, capsys):
    """Child a leads the pooled rows (digits are most of them), b the mean of the two kinds."""
    run = _results(tmp_path, [
        ("voices-a", "unseen-dev", 0.75, 0.35, 0.65, 0.55),
        ("voices-a", "unseen-dev-digits", 0.80, "nan", 0.70, 0.60),     # 0.70
        ("voices-a", "unseen-dev-sentences", 0.40, 0.30, 0.20, 0.30),  # 0.30
        ("voices-b", "unseen-dev", 0.60, 0.50, 0.50, 0.50),
        ("voices-b", "unseen-dev-digits", 0.60, "nan", 0.50, 0.40),     # 0.50
        ("voices-b", "unseen-dev-sentences", 0.70, 0.80, 0.60, 0.50)])  # 0.65
    result = voice_tool.choose(voice_tool.read_results(run))
    assert result["kinds"] == ["unseen-dev-sentences", "unseen-dev-digits"]
    assert result["pick"] == "b"
    rows = {r["child"]: r for r in result["rows"]}
    assert rows["b"]["audio"] == pytest.approx(0.575) and rows["a"]["audio"] == pytest.approx(0.5)
    assert rows["b"]["sentences:bilabial_closed_frac"] == 0.8
    assert math.isnan(rows["b"]["digits:bilabial_closed_frac"])
    assert voice_tool.main([str(run), "--voices", str(_voices(run, "b"))]) == 0
    out = capsys.readouterr().out
    assert "mean of the kinds, equally weighed" in out
    assert ("digits (unseen-dev-digits): mean of viseme_acc, labiodental_contact_frac, "
            "r_reference; bilabial_closed_frac: not measured") in out
