"""The real-speaker section: its numbers come from the stage's summary.json, the target
verdicts are computed, and a missing file or value is a sentence, not an error."""
import json
import re

import numpy as np
import pytest
from pypdf import PdfReader

from analysis.real_face_report import (frame_strip_figure, mu_figure, real_speaker_section,
                                       strip_frames)
from analysis.real_face_tables import target_checks
from analysis.config import TargetsConfig
from analysis.report import Report
from face_model.layout import default_layout, mouth_opening

N = 90


def _row(split, part, R, method="gated_mlp", **lips):
    row = {"method": method, "split": split, "expression": "neutral", "part": part,
           "R": R, "nu_d": "0.201", "nu_d_est": "0.187", "MSE": "0.0031",
           "paper_R": "0.968" if part == "test" else "0.980", "paper_nu_d": "0.196",
           "paper_nu_d_est": "0.184", "paper_MSE": "0.0029", "LVE": "", "FDD": "",
           "R_lips": "", "R_cheeks": "", "R_forehead": "", "closure": "", "closure_true": "",
           "bilabial_segments": ""}
    row.update(lips)
    return row


def _scores(r, median, hit, segments, false, lve=None, silence=0.2, chance=0.01):
    return {"rule": {"half_window_s": 0.1, "close_fraction": 0.2}, "clips": [],
            "pooled": {"clips": 3, "speakers": 1, "frames": 270, "speech_frames": 150,
                       "silence_frames": 120, "excluded_frames": 0, "speech_known": True,
                       "r_speech": r, "chance_r_speech": chance, "r_silence": silence,
                       "chance_r_silence": -0.02, "r_clip_mean": median,
                       "r_clip_median": median, "bilabial_segments": segments,
                       "closures_hit": hit, "closure_rate": hit / segments,
                       "chance_closure_rate": 0.3, "real_closed_rate": 1.0,
                       "real_false_closure_rate": 0.05, "control_segments": 100,
                       "false_closures": false, "false_closure_rate": false / 100,
                       "chance_false_closure_rate": 0.4, "lve_px": lve,
                       "lve_clips": 3 if lve else 0,
                       "interval_r_speech": "(no interval: 1 speaker; an interval needs at "
                                            "least 3)"}}


def _summary(speaker_r=0.912, synthetic_r=0.654) -> dict:
    tables = {
        "real": [_row(s, p, R) for s, p, R in (("random_frames", "train", "0.871"),
                                               ("random_frames", "test", "0.862"),
                                               ("utterance", "train", "0.858"))]
        + [_row("utterance", "test", "0.843", LVE="4.56", R_lips="0.777", closure="0.71",
                bilabial_segments="21")],
        "synthetic": [_row("utterance", "test", 0.951, LVE=3.21, R_lips=0.944, closure=0.88,
                           bilabial_segments=40),
                      _row("utterance", "test", 0.5, method="linear")]}
    return {
        "corpus": {"source": "GRID corpus, speaker s1", "speaker": "grid-s1", "utterances": 79,
                   "frames": 5925, "refused": 2, "licence": "CC BY 4.0"},
        "units": {"n_utterance": 7, "variance_explained": 0.9123, "synthetic": 0.9811,
                  "paper": 0.9756},
        "tables": tables,
        "test_utterances": ["bbaf2n", "bbaf3s", "bbal6n"],
        "input_rate": 22050,
        "face_scores": {"speaker_model": _scores(speaker_r, 0.901, 17, 20, 2, lve=3.77),
                        "synthetic_model": _scores(synthetic_r, 0.612, 13, 20, 5),
                        "loudness": _scores(0.701, 0.287, 6, 20, 9),
                        "openfacefx-text": _scores(0.211, 0.2, 16, 20, 3),
                        "openfacefx-energy": _scores(0.305, 0.3, 12, 20, 12),
                        "pylipsync": _scores(0.266, 0.25, 19, 20, 90)},
        "rates": {"22050": {"speaker_model": {"r_speech": speaker_r},
                            "synthetic_model": {"r_speech": synthetic_r}},
                  "16000": {"speaker_model": {"r_speech": 0.905},
                            "synthetic_model": {"r_speech": 0.601}},
                  "8000": {"speaker_model": {"r_speech": 0.812},
                           "synthetic_model": {"r_speech": 0.433}}},
        "peers": {"versions": {"openfacefx": "0.24.0", "pylipsync": "0.2.1"},
                  "openfacefx_text_words": "transcript over the speech span"},
        "models": {"speaker_model": "real/mapping/gated_mlp_utterance.tfmap",
                   "synthetic_model": "/x/runs/r1/voices-many-cmvn/mapping/gated_mlp_utterance.tfmap"},
        "note": "The corpus holds neutral speech only: no expression MUs or cascades.",
    }


def _markers(opening: np.ndarray, gain: float = 1.0) -> np.ndarray:
    m = np.repeat(default_layout().neutral[None], len(opening), axis=0).copy()
    m[:, 71:76, 1] += gain * opening[:, None]
    m[:, 56:64, 1] += gain * opening[:, None]
    return m


@pytest.fixture
def stage(tmp_path):
    d = tmp_path / "real_speaker"
    d.mkdir()
    (d / "summary.json").write_text(json.dumps(_summary()))
    t = np.arange(N) / 30
    opening = np.clip(6 * np.sin(2 * np.pi * 1.3 * t), 0, None)
    real, spk, syn = _markers(opening), _markers(np.roll(opening, 2), 0.8), _markers(
        np.roll(opening, 5), 1.5)
    z = {k: (o - o.mean()) / o.std() for k, o in
         (("real", mouth_opening(real)), ("speaker", mouth_opening(spk)),
          ("synthetic", mouth_opening(syn)))}
    np.savez(d / "strip.npz", clip="bbaf2n", real=real, speaker=spk, synthetic=syn,
             neutral=default_layout().neutral, real_opening=z["real"],
             speaker_opening=z["speaker"], synthetic_opening=z["synthetic"])
    comps = np.linalg.qr(np.random.default_rng(0).standard_normal((158, 7)))[0].T
    np.savez(d / "units.npz", components=comps, scale=np.linspace(8, 2, 7),
             neutral=default_layout().neutral)
    return d


def _build(stage_dir, tmp_path) -> str:
    rep = Report("T")
    real_speaker_section(rep, stage_dir, tmp_path / "figs")
    pdf = rep.build(tmp_path / "r.pdf")
    return " ".join(" ".join(p.extract_text() for p in PdfReader(pdf).pages).split())


def _row_text(text: str, start: str, end: str) -> str:
    return text[text.index(start):text.index(end, text.index(start))]


def test_the_section_prints_the_summarys_numbers(stage, tmp_path):
    text = _build(stage, tmp_path)
    for s in ("A real speaker (GRID s1)", "grid-s1", "79 utterances", "5925 frames",
              "2 clips were refused", "CC BY 4.0", "Cooke", "Zenodo 3625687",
              "91.23 %", "98.11 %", "97.56 %", "neutral speech only",
              "0.871", "0.862", "0.858", "0.843", "0.951", "0.968", "0.980",  # Tables I-II
              "4.56", "3.21", "0.777", "0.944", "0.71 of 21", "0.88 of 40",  # lips
              "0.912 (0.010)", "0.654 (0.010)", "0.701 (0.010)", "0.901", "0.612",
              "17/20 85 % (30 %)", "13/20 65 % (30 %)", "2 % (40 %)", "3.77",
              "voices-many-cmvn/mapping/gated_mlp_utterance.tfmap", "on 3 held-out sentences",
              "1 speaker; an interval needs at least 3", "audio at 22050 Hz",
              "input 22050 Hz", "22050 Hz", "16000 Hz", "8000 Hz", "0.905", "0.433",
              "openfacefx 0.24.0", "pylipsync 0.2.1", "transcript over the speech span",
              "PP", "silence", "face_speaker_r 0.85"):
        assert s in text, s
    assert "0.500" not in text  # another method's row is not in the gated MLP's table
    assert len(list((tmp_path / "figs").glob("*.png"))) == 2


def test_the_default_below_a_peer_is_said_plainly(stage, tmp_path):
    text = _build(stage, tmp_path)
    assert ("its speech-frame r (0.654) is below the loudness envelope's (0.701) by 0.047"
            in text)
    assert "share of /p b m/ closed (65 %) is below the openfacefx, transcript's (80 %)" in text
    assert "false-closure rate (5 %) is above that of the openfacefx, transcript (3 %)" in text
    assert "below the pylipsync" not in text.split("speech-frame r (0.654)")[1][:40]


def test_every_table_and_figure_is_cited(stage, tmp_path):
    rep = Report("T")
    real_speaker_section(rep, stage, tmp_path / "figs")
    rep.build(tmp_path / "r.pdf")
    assert rep.uncited() == []


def test_targets_met_and_not_met_are_computed(stage, tmp_path):
    text = _build(stage, tmp_path)
    speaker = _row_text(text, "speaker-trained model", "synthetic-trained default")
    synthetic = _row_text(text, "synthetic-trained default", "loudness envelope (peer)")
    assert re.search(r"r ≥ 0\.85: met", speaker) and "not met" not in speaker
    assert "r ≥ 0.70: not met" in synthetic and "closures ≥ 80 %: not met" in synthetic
    s = _summary(speaker_r=0.80, synthetic_r=0.75)
    (stage / "summary.json").write_text(json.dumps(s))
    text = _build(stage, tmp_path)
    speaker = _row_text(text, "speaker-trained model", "synthetic-trained default")
    synthetic = _row_text(text, "synthetic-trained default", "loudness envelope (peer)")
    assert "r ≥ 0.85: not met" in speaker
    assert "r ≥ 0.70: met" in synthetic


def test_target_checks_compare_with_the_targets():
    s = _summary(speaker_r=0.85, synthetic_r=None)
    checks = {(c["model"], c["what"]): c["verdict"] for c in target_checks(s)}
    assert checks == {("speaker_model", "r"): "met", ("synthetic_model", "r"): "not measured",
                      ("synthetic_model", "closures"): "not met",
                      ("speaker_model", "rate"): "met",  # 0.85 at 22.05 kHz, 0.905 at 16
                      ("synthetic_model", "rate"): "not measured"}
    s = _summary()
    rate = {c["model"]: c for c in target_checks(s, TargetsConfig(rate_tolerance=0.01))
            if c["what"] == "rate"}
    assert rate["speaker_model"]["value"] == pytest.approx(0.912 - 0.905)
    assert rate["speaker_model"]["verdict"] == "met"
    assert rate["synthetic_model"]["verdict"] == "not met"  # 0.654 - 0.601 > 0.01


def test_missing_files_and_values_are_said_in_a_sentence(stage, tmp_path):
    (stage / "strip.npz").unlink()
    s = _summary()
    s["units"]["synthetic"] = None
    s["face_scores"]["synthetic_model"] = None
    (stage / "summary.json").write_text(json.dumps(s))
    text = _build(stage, tmp_path)
    assert "No frame strip: the stage left no strip.npz." in text
    assert "absent from the summary for this run's synthetic corpus" in text
    synthetic = _row_text(text, "synthetic-trained default", "loudness envelope (peer)")
    assert "not measured" in synthetic
    assert not (tmp_path / "figs" / "real_strip.png").exists()


def test_a_stage_without_summary_says_so(tmp_path):
    (tmp_path / "empty").mkdir()
    text = _build(tmp_path / "empty", tmp_path)
    assert "A real speaker (GRID s1)" in text and "summary.json could not be read" in text


def test_the_figures_are_drawn(stage, tmp_path):
    assert mu_figure(stage / "units.npz", tmp_path / "mu.png").stat().st_size > 0
    assert frame_strip_figure(stage / "strip.npz", tmp_path / "s.png").stat().st_size > 0
    assert strip_frames(80) == [5, 15, 25, 35, 45, 55, 65, 75]
    assert strip_frames(3) == [0, 1, 2]
