"""The corpus generator: reproducibility, the default corpus's size and content, lip motion, and
phone timing against the audio.

The default-size corpus (100 sentences × 3 expressions) is built once per test run by the
``default_corpus_dir`` fixture; everything else uses 4-sentence corpora.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from data_synth.generate import plan_corpus, synthesize_corpus
from face_model.alignment import corpus_deformations, speaker_neutrals, unflatten
from face_model.corpus import load_corpus
from face_model.layout import LAYOUT_VERSION, REGIONS
from face_model.phones import PHONE_INDEX, PHONES
from groundwork.errors import ParameterError
from talkingface.config import Config

SEED = Config().seed
SIL = PHONE_INDEX["sil"]


def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes()
            for p in sorted(root.rglob("*")) if p.is_file()}


def _differing(a: dict, b: dict) -> list[str]:
    assert sorted(a) == sorted(b)
    return [k for k in a if a[k] != b[k]]


# -- reproducibility -----------------------------------------------------------------------------
def test_same_seed_gives_byte_identical_files(small_corpus_dir, synth_config, tmp_path):
    again = synthesize_corpus(tmp_path / "again", synth_config(), SEED, progress=False)
    first, second = _files(small_corpus_dir), _files(again)
    kinds = {k.split("/")[0] for k in first}
    assert kinds == {"manifest.csv", "corpus.json", "audio", "markers", "phones"}
    assert len(first) == 2 + 3 * 12
    assert _differing(first, second) == []


@pytest.fixture(scope="module")
def one_worker_corpus_dir(tmp_path_factory):
    """The small corpus (conftest's ``small_corpus_dir``: the same settings and seed) made by one
    worker process instead of two; read-only, for the two tests below."""
    from tests.conftest import small_synth_config

    return synthesize_corpus(tmp_path_factory.mktemp("w1") / "corpus",
                             small_synth_config(workers=1), SEED, progress=False)


def test_data_files_identical_for_one_or_two_workers(small_corpus_dir, one_worker_corpus_dir):
    one = _files(one_worker_corpus_dir)
    two = _files(small_corpus_dir)
    assert [k for k in _differing(one, two) if k != "corpus.json"] == []


def test_corpus_json_identical_for_one_or_two_workers(small_corpus_dir, one_worker_corpus_dir):
    """The number of worker processes must not change the corpus, its description included.

    Library bug: corpus.json records every SynthConfig field, ``workers`` among them.
    """
    out = one_worker_corpus_dir
    assert (out / "corpus.json").read_bytes() == (small_corpus_dir / "corpus.json").read_bytes()


def test_another_seed_changes_markers_and_audio(small_corpus_dir, synth_config, tmp_path):
    other = _files(synthesize_corpus(tmp_path / "other", synth_config(), SEED + 1,
                                     progress=False))
    base = _files(small_corpus_dir)
    changed = set(_differing(base, other))
    for kind in ("audio", "markers"):
        names = {k for k in base if k.startswith(kind + "/")}
        assert len(names) == 12 and names <= changed
    # Speaker 0 speaks with the configured voice whatever the seed, so the timing is the same.
    assert not any(k.startswith("phones/") for k in changed)
    assert json.loads(other["corpus.json"])["seed"] == SEED + 1


def test_corpus_description(small_corpus, small_corpus_dir):
    info = json.loads((small_corpus_dir / "corpus.json").read_text())
    assert info["seed"] == SEED and info["layout_version"] == LAYOUT_VERSION
    assert info["n_utterances"] == len(small_corpus) == 12
    assert info["n_frames"] == small_corpus.n_frames
    assert info["settings"]["n_sentences"] == 4 and info["settings"]["expressions"] == [
        "neutral", "smile", "sad"]
    assert len(info["sentences"]) == 4 and info["speakers"][0]["voice"] == "en-us+m3"
    assert {u.text for u in small_corpus.utterances} == set(info["sentences"])


def test_overwrite_regenerates_the_same_corpus(small_corpus_dir, synth_config, tmp_path):
    out = tmp_path / "c"
    synthesize_corpus(out, synth_config(n_sentences=2), SEED + 5, progress=False)
    refused = re.escape(f"corpus folder {out} already exists and is not empty; choose another "
                        "folder or pass --overwrite")
    with pytest.raises(ParameterError, match=refused):
        synthesize_corpus(out, synth_config(), SEED, progress=False)
    synthesize_corpus(out, synth_config(), SEED, overwrite=True, progress=False)
    assert _differing(_files(out), _files(small_corpus_dir)) == []


def test_overwrite_refuses_a_folder_that_is_not_a_corpus(synth_config, tmp_path):
    (tmp_path / "notes.txt").write_text("keep me")
    refused = re.escape(f"{tmp_path} is not empty and holds no manifest.csv")
    with pytest.raises(ParameterError, match=refused):
        synthesize_corpus(tmp_path, synth_config(), SEED, overwrite=True, progress=False)
    assert (tmp_path / "notes.txt").read_text() == "keep me"


@pytest.mark.parametrize("changes,message", [
    ({"expressions": ("neutral", "angry")}, r"expressions is \['neutral', 'angry'\]; allowed: a "
                                            r"non-empty list of distinct values from neutral, "
                                            r"smile, sad"),
    ({"expressions": ()}, r"expressions is \[\]"),
    ({"speakers": 0}, "speakers is 0; allowed: an integer >= 1"),
    ({"n_sentences": 1000}, "synth.n_sentences=1000, but the built-in set has only 360 sentences"),
    ({"marker_noise_px": -0.1}, r"marker_noise_px is -0.1; allowed: a finite number in \[0, 50\]"),
])
def test_bad_settings_are_refused_before_any_work(synth_config, tmp_path, changes, message):
    with pytest.raises(ParameterError, match=message):
        synthesize_corpus(tmp_path / "c", synth_config(**changes), SEED, progress=False)
    assert not (tmp_path / "c").exists()


def test_plan_orders_speakers_expressions_sentences(synth_config):
    speakers, plans = plan_corpus(synth_config(speakers=2, n_sentences=3), SEED)
    assert [p.utt_id for p in plans[:4]] == ["s00_neutral_000", "s00_neutral_001",
                                             "s00_neutral_002", "s00_smile_000"]
    assert len(plans) == 2 * 3 * 3 and plans[-1].utt_id == "s01_sad_002"
    assert speakers[0].voice == "en-us+m3" and speakers[1].voice != speakers[0].voice
    base = plans[0].request
    smile, sad = plans[3].request, plans[6].request
    assert (smile.pitch - base.pitch, smile.rate_wpm - base.rate_wpm) == (6, 5)
    assert (sad.pitch - base.pitch, sad.rate_wpm - base.rate_wpm) == (-8, -15)


def test_each_speaker_has_its_own_face(synth_config, tmp_path):
    out = synthesize_corpus(tmp_path / "c", synth_config(speakers=2, n_sentences=2,
                                                         expressions=("neutral",)),
                            SEED, progress=False)
    corpus = load_corpus(out)
    assert [u.speaker for u in corpus.utterances] == ["s00", "s00", "s01", "s01"]
    neutrals = speaker_neutrals(corpus)
    gap = np.abs(neutrals["s00"] - neutrals["s01"])
    assert gap[:76].max() > 1.0  # pixels: different face shapes
    assert gap[76:].max() < 0.5  # ... but both aligned onto the same glasses (up to noise)


# -- the default corpus ---------------------------------------------------------------------------
def test_default_corpus_size_and_phone_classes(default_corpus, default_corpus_dir):
    assert len(default_corpus) == 300
    assert {e: len(default_corpus.by_expression(e)) for e in ("neutral", "smile", "sad")} == {
        "neutral": 100, "smile": 100, "sad": 100}
    assert 15_000 <= default_corpus.n_frames <= 25_000
    seen = set()
    for f in (default_corpus_dir / "phones").glob("*.csv"):
        seen |= {line.rsplit(",", 1)[1] for line in f.read_text().splitlines()[1:]}
    assert seen == set(PHONES)


def _rms_speeds(corpus) -> dict[str, float]:
    """RMS frame-to-frame displacement (pixels per frame) of the aligned markers of a region,
    over frame pairs that are both speech, or both silence."""
    defs = corpus_deformations(corpus)
    sums = {}
    for u in corpus.utterances:
        v2 = (np.diff(unflatten(defs[u.utt_id]), axis=0) ** 2).sum(2)  # (n_frames-1, 79)
        ph = u.phone_per_frame()
        pairs = {"speech": (ph[1:] != SIL) & (ph[:-1] != SIL),
                 "silence": (ph[1:] == SIL) & (ph[:-1] == SIL)}
        for when, mask in pairs.items():
            for region, idx in REGIONS.items():
                s, n = sums.get((region, when), (0.0, 0))
                sums[(region, when)] = (s + v2[mask][:, list(idx)].sum(), n + mask.sum() * len(idx))
    return {f"{r}/{w}": float(np.sqrt(s / n)) for (r, w), (s, n) in sums.items()}


def test_lips_move_during_speech_and_rest_in_silence(default_corpus):
    v = _rms_speeds(default_corpus)
    # The lips move most during speech: about twice as fast as in silence ...
    assert v["lips/speech"] > 1.5 * v["lips/silence"]
    # ... and faster than any other region while speaking (the forehead only follows prosody).
    assert v["lips/speech"] > 1.8 * v["forehead/speech"]
    assert v["lips/speech"] > max(v["cheeks/speech"], v["glasses/speech"])
    # In silence the lips are nearly as still as the forehead: what is left is marker noise
    # (0.15 px per coordinate) and the expressions' onsets and offsets.
    assert v["lips/silence"] < 1.4 * v["forehead/silence"]


def _energy_onset_s(y: np.ndarray, sr: int, *, window_s: float = 0.005,
                    above_floor_db: float = 20.0) -> float:
    """Start of the first 5 ms window whose RMS is 20 dB above the noise floor (the median level
    of the first 100 ms, which are padding silence)."""
    w = int(round(window_s * sr))
    n = len(y) // w
    level = 10 * np.log10((y[: n * w].astype(np.float64).reshape(n, w) ** 2).mean(1) + 1e-20)
    floor = np.median(level[: int(0.1 / window_s)])
    assert -70 < floor < -60  # the configured -66 dBFS noise floor
    return float(np.argmax(level > floor + above_floor_db) * w / sr)


def test_first_phone_starts_at_the_energy_onset(default_corpus):
    errors = []
    for u in default_corpus.utterances:
        first = next(s for s in u.phones if s.phone != "sil")
        errors.append(first.start_s - _energy_onset_s(u.audio, u.sample_rate))
    assert np.abs(errors).max() <= 0.020


def test_audio_duration_matches_the_marker_frames(default_corpus):
    for u in default_corpus.utterances:
        assert abs(len(u.audio) * 30 / u.sample_rate - u.n_frames) <= 1.0
        assert u.phones[0].start_s == 0.0
        assert u.phones[-1].end_s == pytest.approx(len(u.audio) / u.sample_rate, abs=1e-5)
        assert u.phones[0].phone == u.phones[-1].phone == "sil"
