"""The content-keyed cache (groundwork.cache) and what the mapping keeps in it: reused across
runs, rebuilt when its inputs change, one valid entry when processes race, a damaged entry
rebuilt, and cleaning."""
from __future__ import annotations

import multiprocessing as mp
import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from face_model.corpus import load_corpus
from face_model.motion_units import fit_corpus_units
from groundwork.cache import ArrayCache, cache_size, clean_cache, content_key
from groundwork.errors import ParameterError
from mapping import dataset
from mapping.dataset import build_dataset


def _make_counted(log: Path, value: float):
    def make():
        with open(log, "a") as f:
            f.write("made\n")
        return {"a": np.full(3, value), "b": np.arange(4)}
    return make


def test_entry_is_made_once_and_read_back_by_another_cache(tmp_path):
    log = tmp_path / "made.log"
    key = content_key("x", 1)
    first = ArrayCache(tmp_path / "cache").get_or_make("thing", key, _make_counted(log, 1.0))
    again = ArrayCache(tmp_path / "cache")  # a later run: a new object on the same folder
    second = again.get_or_make("thing", key, _make_counted(log, 2.0))
    assert log.read_text().count("made") == 1
    assert (again.hits, again.misses) == (1, 0)
    np.testing.assert_array_equal(second["a"], first["a"])
    other = again.get_or_make("thing", content_key("x", 2), _make_counted(log, 2.0))
    assert other["a"][0] == 2.0 and log.read_text().count("made") == 2
    assert cache_size(tmp_path / "cache")[0] == 2


def test_keys_differ_with_any_part():
    assert content_key("features", 10, False) != content_key("features", 13, False)
    assert content_key("features", 10, False) == content_key("features", 10, False)


def test_damaged_entry_is_made_again(tmp_path):
    cache = ArrayCache(tmp_path)
    key = content_key("y")
    cache.get_or_make("thing", key, _make_counted(tmp_path / "log", 1.0))
    path = cache.path("thing", key)
    path.write_bytes(path.read_bytes()[:40])  # a write cut short (a full disk)
    out = cache.get_or_make("thing", key, _make_counted(tmp_path / "log", 5.0))
    assert out["a"][0] == 5.0 and cache.misses == 2
    assert ArrayCache(tmp_path).get("thing", key)["a"][0] == 5.0


def _race(root, log, start, out):
    while time.time() < start:
        time.sleep(0.005)
    cache = ArrayCache(root)

    def make():
        with open(log, "a") as f:
            f.write(f"{os.getpid()}\n")
        time.sleep(0.5)  # long enough for the other process to ask meanwhile
        return {"v": np.arange(1000, dtype=np.float64)}

    arrays = cache.get_or_make("race", content_key("race"), make)
    np.save(out, arrays["v"])


def test_two_processes_racing_for_one_key_leave_one_valid_entry(tmp_path):
    ctx = mp.get_context("spawn")
    start = time.time() + 3.0
    procs = [ctx.Process(target=_race, args=(tmp_path / "cache", tmp_path / "log", start,
                                             tmp_path / f"out{i}.npy")) for i in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    assert len((tmp_path / "log").read_text().split()) == 1  # made once: the other waited
    entries = list((tmp_path / "cache" / "race").glob("*.npz"))
    assert len(entries) == 1 and not entries[0].name.startswith(".")  # no partial left
    np.testing.assert_array_equal(ArrayCache(tmp_path / "cache").get(
        "race", content_key("race"))["v"], np.arange(1000))
    for i in range(2):
        np.testing.assert_array_equal(np.load(tmp_path / f"out{i}.npy"), np.arange(1000))


def test_clean_removes_all_or_the_unused(tmp_path):
    cache = ArrayCache(tmp_path / "c")
    for i in range(3):
        cache.get_or_make("thing", content_key(i), lambda: {"a": np.zeros(10)})
    old = cache.path("thing", content_key(0))
    os.utime(old, (time.time() - 10 * 86400,) * 2)
    n, size = clean_cache(tmp_path / "c", unused_days=5)
    assert n == 1 and size > 0 and not old.exists()
    assert cache_size(tmp_path / "c")[0] == 2
    assert clean_cache(tmp_path / "c")[0] == 2 and not (tmp_path / "c").exists()
    assert clean_cache(tmp_path / "c") == (0, 0)
    with pytest.raises(ParameterError, match="--unused-days must be a number of days >= 0, "
                                             "got -1"):
        clean_cache(tmp_path / "c", unused_days=-1)


@pytest.fixture(scope="module")
def units(small_corpus):
    return fit_corpus_units(small_corpus)[0]


def test_dataset_features_are_reused_across_runs_and_rebuilt_when_inputs_change(
        small_corpus_dir, small_corpus, units, tmp_path, monkeypatch):
    plain = build_dataset(small_corpus, units, n_mfcc=10)
    cache = ArrayCache(tmp_path / "cache")
    first = build_dataset(small_corpus, units, n_mfcc=10, cache=cache)
    for a, b in zip(plain, first):
        np.testing.assert_array_equal(a.features, b.features)
        np.testing.assert_array_equal(a.mups, b.mups)
    assert cache.misses == 1

    real = dataset.audio_features
    monkeypatch.setattr(dataset, "audio_features",
                        lambda *a, **k: pytest.fail("features computed again"))
    later = ArrayCache(tmp_path / "cache")  # another run, the same corpus and settings
    again = build_dataset(small_corpus, units, n_mfcc=10, cache=later)
    assert (later.hits, later.misses) == (1, 0)
    for a, b in zip(plain, again):
        np.testing.assert_array_equal(a.features, b.features)

    monkeypatch.setattr(dataset, "audio_features", real)
    other = build_dataset(small_corpus, units, n_mfcc=13, cache=later)  # another setting
    assert later.misses == 1 and other[0].features.shape[1] == 13

    changed = Path(shutil.copytree(small_corpus_dir, tmp_path / "corpus"))
    wav = changed / "audio" / f"{small_corpus.utterances[0].utt_id}.wav"
    data = bytearray(wav.read_bytes())
    data[-200:] = bytes(200)  # the last samples silenced: another corpus by content
    wav.write_bytes(bytes(data))
    build_dataset(load_corpus(changed), units, n_mfcc=10, cache=later)
    assert later.misses == 2
    assert cache_size(tmp_path / "cache")[0] == 3
