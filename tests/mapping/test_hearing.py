"""Recordings heard once, on every core (issue 38): the parallel pass of mapping.hearing fills
one cache entry per recording with exactly the arrays the serial path hears; a second pass
hears nothing; a change of the audio (one sample) or of a setting, or a damaged entry, is
heard again; and the tables read through the cache are the tables heard one by one."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import soxr

from analysis import speech_recogniser
from analysis.speech_eval import NATIVE, model_jobs, rate_audio, score_model
from analysis.speech_recogniser import recognised, recogniser_jobs, recogniser_scores
from analysis.speech_set import load_speech_set
from groundwork.cache import ArrayCache
from mapping import recogniser
from mapping.hearing import Passes, Windows, corpus_jobs, hear_all
from mapping.recogniser import HEARD_KIND, hear_windows, hearing_cache, recognise_windows
from tests.mapping.small_mapping import train_small

SR = 22050  # the mapping's rate: both streams resample from it
IDS = ["ps_cards_001", "praatio_bobby", "fsdd_0_george_0"]  # 1.1 s, 1.2 s, 0.4 s (8 kHz)
RECOGNISERS = ("pocketsphinx", "hama", "causal")


@pytest.fixture(scope="module")
def items():
    return load_speech_set(ids=IDS)


@pytest.fixture(scope="module")
def audio(items):
    return [soxr.resample(it.audio.astype(np.float32), it.sr, SR).astype(np.float32)
            for it in items]


def window_jobs(audio, which, delay=3, back=3):
    return [Windows(y, SR, 30, delay, back, which) for y in audio]


@pytest.fixture(autouse=True)
def fresh(monkeypatch):
    """No windows remembered in memory: every call reads the cache or hears."""
    monkeypatch.setattr(recogniser, "_HEARD", {})


@pytest.fixture(scope="module")
def heard(tmp_path_factory, audio, items):
    """One parallel pass (2 processes) over every job kind: the windows of each recogniser and
    the recognisers' whole and streaming labels of the same recordings."""
    cache = ArrayCache(tmp_path_factory.mktemp("cache"))
    jobs = [j for w in RECOGNISERS for j in window_jobs(audio, w)] + recogniser_jobs(items)
    passes = hear_all(jobs, cache, workers=2, progress=False)
    return cache, passes, len(jobs)


def no_hearing(monkeypatch):
    def refuse(*a, **k):
        raise AssertionError("the recogniser was called")

    monkeypatch.setattr(recogniser, "hear_windows", refuse)
    monkeypatch.setattr(speech_recogniser, "_recognised_now", refuse)


def test_the_parallel_pass_hears_every_recording_once(heard):
    cache, passes, n = heard
    assert passes == Passes(heard=n, reused=0) and n == 3 * len(IDS) + 3 * len(IDS)
    assert (cache.misses, cache.hits) == (n, 0)
    assert len(list((cache.root / HEARD_KIND).glob("*.npz"))) == n


@pytest.mark.parametrize("which", RECOGNISERS)
def test_the_parallel_pass_gives_the_serial_windows_byte_for_byte(heard, audio, which):
    cache = heard[0]
    for y in audio:
        serial = hear_windows(y, SR, delay_frames=3, back=3, recogniser=which)
        with hearing_cache(cache):
            cached = recognise_windows(y, SR, delay_frames=3, back=3, recogniser=which)
        assert cached.dtype == serial.dtype and cached.tobytes() == serial.tobytes()
        assert serial.shape == (int(np.ceil(len(y) * 30 / SR)), 7)


@pytest.mark.parametrize("which", RECOGNISERS)
def test_the_parallel_pass_gives_the_serial_recognised_labels(heard, items, which):
    cache = heard[0]
    for it in items:
        y, sr, _ = rate_audio(it, NATIVE)  # as recogniser_scores hears them
        whole, streams = speech_recogniser._recognised_now(which, y, sr, 30)
        with hearing_cache(cache):
            before = cache.misses
            c_whole, c_streams = recognised(which, y, sr, 30)
            assert cache.misses == before  # read, not heard
        assert c_whole.tobytes() == np.asarray(whole).tobytes()
        assert sorted(c_streams) == sorted(streams)
        for k, s in streams.items():
            assert c_streams[k].dtype == np.asarray(s).dtype
            assert c_streams[k].tobytes() == np.asarray(s).tobytes()


def test_a_second_pass_reads_every_entry_and_hears_nothing(heard, audio, items, monkeypatch):
    cache, _, n = heard
    again = ArrayCache(cache.root)
    no_hearing(monkeypatch)
    jobs = [j for w in RECOGNISERS for j in window_jobs(audio, w)] + recogniser_jobs(items)
    assert hear_all(jobs + jobs[:2], again, workers=2, progress=False) == Passes(0, n)
    assert (again.hits, again.misses) == (n, 0)
    with hearing_cache(again):  # the serial code reads them too
        recognise_windows(audio[0], SR, delay_frames=3, back=3, recogniser="hama")
        recognised("pocketsphinx", *rate_audio(items[0], NATIVE)[:2])
    assert (again.hits, again.misses) == (n + 2, 0)


@pytest.mark.parametrize("change", ["one sample", "delay_frames", "back", "recogniser",
                                    "rate"])
def test_an_entry_is_heard_again_when_its_audio_or_a_setting_changes(tmp_path, audio, change):
    cache = ArrayCache(tmp_path / "cache")
    y = audio[2]
    same = Windows(y, SR, 30, 3, 3, "pocketsphinx")
    job = {"one sample": Windows(np.r_[y[:100], y[100] + 1e-4, y[101:]].astype(np.float32), SR,
                                 30, 3, 3, "pocketsphinx"),
           "delay_frames": Windows(y, SR, 30, 2, 3, "pocketsphinx"),
           "back": Windows(y, SR, 30, 3, 1, "pocketsphinx"),
           "recogniser": Windows(y, SR, 30, 3, 3, "hama"),
           "rate": Windows(y, 24000, 30, 3, 3, "pocketsphinx")}[change]
    assert hear_all([same], cache, workers=1, progress=False) == Passes(1, 0)
    assert hear_all([same, job], cache, workers=1, progress=False) == Passes(1, 1)
    with hearing_cache(cache):
        np.testing.assert_array_equal(
            recognise_windows(job.y, job.sample_rate, delay_frames=job.delay_frames,
                              back=job.back, recogniser=job.recogniser),
            job.compute()["windows"])


def test_a_damaged_entry_is_heard_again(tmp_path, audio, monkeypatch):
    cache = ArrayCache(tmp_path / "cache")
    job = Windows(audio[2], SR, 30, 3, 3, "pocketsphinx")
    assert hear_all([job], cache, progress=False) == Passes(1, 0)
    path = cache.path(HEARD_KIND, job.key())
    good = np.load(path)["windows"]
    path.write_bytes(path.read_bytes()[:40])  # a truncated write
    assert hear_all([job], cache, progress=False) == Passes(1, 0)
    np.testing.assert_array_equal(np.load(path)["windows"], good)
    np.savez(path, other=np.zeros(3))  # an entry without the arrays it must hold
    with hearing_cache(cache):
        np.testing.assert_array_equal(
            recognise_windows(job.y, SR, delay_frames=3, back=3), good)
    np.testing.assert_array_equal(np.load(path)["windows"], good)


def test_corpus_jobs_hear_what_build_dataset_hears(small_corpus, tmp_path, monkeypatch):
    from mapping.dataset import build_dataset
    from face_model.motion_units import fit_corpus_units

    units, _ = fit_corpus_units(small_corpus)
    cache = ArrayCache(tmp_path / "cache")
    context = (3, 3, "pocketsphinx")
    passes = hear_all(corpus_jobs(small_corpus, context), cache, workers=1, progress=False)
    assert passes == Passes(len(small_corpus.utterances), 0)
    no_hearing(monkeypatch)
    data = build_dataset(small_corpus, units, recognise_context=context, cache=cache)
    assert all(d.recognised.shape == (d.n_frames, 7) for d in data)


def _rows_json(rows) -> str:
    return json.dumps(rows, default=float, sort_keys=True)


def test_the_tables_are_the_same_with_the_cache_on_and_off(small_corpus, items, heard, tmp_path,
                                                            monkeypatch):
    """The model's and the recognisers' tables heard one by one (no cache) equal the tables
    read from entries made by parallel passes: the model's recordings heard here, the
    recognisers' by the module's pass (``heard``, whose entries are copied in: the same
    recordings, already heard once in parallel)."""
    t = train_small(small_corpus, split="random_frames", gate_front_end="recogniser",
                    mlp_input="phones", phone_training="labels", min_class_frames=5, epochs=5)
    rates = (NATIVE, 8000)
    off = score_model("m", t.mapping, t.units, items, rates=rates, progress=False)
    rec_off = recogniser_scores(items, progress=False, summary=False)
    cache = ArrayCache(tmp_path / "cache")
    shutil.copytree(heard[0].root, cache.root)
    jobs = model_jobs(t.mapping, items, rates) + recogniser_jobs(items)
    assert len(jobs) == len(rates) * len(items) + 3 * len(items)
    passes = hear_all(jobs, cache, workers=2, progress=False)
    assert passes.reused >= 3 * len(items) and passes.heard >= 1  # the model's 8 kHz are new
    recogniser._HEARD.clear()
    no_hearing(monkeypatch)
    with hearing_cache(cache):
        on = score_model("m", t.mapping, t.units, items, rates=rates, progress=False)
        rec_on = recogniser_scores(items, progress=False, summary=False)
    assert _rows_json(on.per_file_rows("s")) == _rows_json(off.per_file_rows("s"))
    assert _rows_json(rec_on) == _rows_json(rec_off)
