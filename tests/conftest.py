"""Shared fixtures: small synthetic corpora (one per test worker) and the default-size corpus
(built once per test run, even with pytest-xdist), plus seeded random generators.

Every corpus fixture is read-only for the tests: a test that damages a corpus copies it first
(``corpus_copy``), and the loaded corpora have their arrays marked read-only.
"""
from __future__ import annotations

import dataclasses
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from filelock import FileLock
from hypothesis import HealthCheck, settings

REPO_ROOT = Path(__file__).resolve().parents[1]
if str(REPO_ROOT) not in sys.path:
    sys.path.insert(0, str(REPO_ROOT))

from data_synth.generate import synthesize_corpus  # noqa: E402
from face_model.corpus import load_corpus  # noqa: E402
from talkingface.config import Config  # noqa: E402

# The test workers share the cores: each sets its torch and BLAS threads so that workers x
# threads <= cores (face_model.threads; tiny networks run many times slower when threads compete).
from face_model.threads import limit_threads, thread_budget  # noqa: E402

limit_threads(thread_budget(int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))))

# Property tests: reproducible examples (derandomize), no wall-clock deadline, no example database.
settings.register_profile("talkingface", derandomize=True, deadline=None, database=None,
                          max_examples=60, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("talkingface")

SEED = Config().seed
SMALL_N_SENTENCES = 4


def small_synth_config(**changes):
    """The default synthesis settings shrunk to a few sentences (× 3 expressions)."""
    base = dict(n_sentences=SMALL_N_SENTENCES, workers=2)
    base.update(changes)
    return dataclasses.replace(Config().synth, **base)


def _freeze(corpus):
    for u in corpus.utterances:
        u.audio.setflags(write=False)
        u.markers.setflags(write=False)
    return corpus


@pytest.fixture
def synth_config():
    """``synth_config(**changes)``: the small synthesis settings with some values changed."""
    return small_synth_config


@pytest.fixture
def rng():
    """A fresh, seeded generator for each test."""
    return np.random.default_rng(20020704)


@pytest.fixture(scope="session")
def small_corpus_dir(tmp_path_factory):
    """A 4-sentence × 3-expression corpus with the default seed (12 utterances)."""
    out = tmp_path_factory.mktemp("small") / "corpus"
    return synthesize_corpus(out, small_synth_config(), SEED, progress=False)


@pytest.fixture(scope="session")
def small_corpus(small_corpus_dir):
    return _freeze(load_corpus(small_corpus_dir))


@pytest.fixture
def corpus_copy(small_corpus_dir, tmp_path):
    """A private copy of the small corpus that a test may damage."""
    return Path(shutil.copytree(small_corpus_dir, tmp_path / "corpus"))


@pytest.fixture(scope="session")
def default_corpus_dir(tmp_path_factory):
    """The default-size corpus (Config().synth, Config().seed): 100 sentences × 3 expressions.

    Built once per test run: under pytest-xdist the workers share one folder next to their own
    temporary roots, and a file lock lets the first worker build it while the others wait.
    """
    cfg = Config()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = tmp_path_factory.getbasetemp().parent  # the run's folder, common to all workers
    else:
        shared = tmp_path_factory.mktemp("default")
    out = shared / "default_corpus"
    with FileLock(str(shared / "default_corpus.lock")):
        if not (out / "corpus.json").is_file():  # corpus.json is the last file written
            shutil.rmtree(out, ignore_errors=True)
            synthesize_corpus(out, cfg.synth, cfg.seed, progress=False)
    return out


@pytest.fixture(scope="session")
def default_corpus(default_corpus_dir):
    return _freeze(load_corpus(default_corpus_dir))
