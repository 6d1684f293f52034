"""Shared fixtures: small synthetic corpora (one per test worker), the default-size corpus and a
small finished run (each built once per test run, even with pytest-xdist), plus seeded random
generators.

Every corpus fixture is read-only for the tests: a test that damages a corpus copies it first
(``corpus_copy``), and the loaded corpora have their arrays marked read-only.
"""
from __future__ import annotations

import dataclasses
import functools
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
from groundwork.memory import keep_freed_memory  # noqa: E402
from groundwork.owner import release_all  # noqa: E402
from talkingface.config import Config  # noqa: E402

# The test workers share the cores: each sets its torch and BLAS threads so that workers x
# threads <= cores (groundwork.threads; tiny networks run many times slower when threads compete).
from groundwork.threads import limit_threads, thread_budget  # noqa: E402

limit_threads(thread_budget(int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))))
keep_freed_memory()  # as every process of the project (groundwork.memory)

# Property tests: reproducible examples (derandomize), no wall-clock deadline, no example database.
settings.register_profile("talkingface", derandomize=True, deadline=None, database=None,
                          max_examples=60, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("talkingface")

SEED = Config().seed
SMALL_N_SENTENCES = 4


# Run first: the first users of the folders made once per test run (``build_once``), so that
# they are ready before the other tests that read them, then the longest single tests.
# pytest-xdist's load scheduling hands each worker a block of consecutive tests and the rest as
# workers free up: a long test near the end of the collection would run alone while the other
# worker has nothing left to do; started first, the other worker takes the short tests
# meanwhile. Only the order changes.
RUN_FIRST = (
    "tests/study/test_stimuli.py::test_every_stimulus_of_the_design_in_sync_with_its_audio",
    "tests/talkingface/test_visual_source.py::test_train_on_tracked_mups",
    "tests/talkingface/test_cli_pipeline.py::test_replicate_writes_runs_report_and_mlflow",
    "tests/analysis/test_perception_report.py::test_a_study_report_from_data_alone",
    "tests/talkingface/test_train_ablate.py::test_ui_front_page_answers_http_200",
    "tests/talkingface/test_grid_cluster.py::"
    "test_a_worker_killed_mid_grid_leaves_one_child_per_setting_and_seed",
)


def pytest_collection_modifyitems(session, config, items):
    rank = {nodeid: i for i, nodeid in enumerate(RUN_FIRST)}
    first = sorted((it for it in items if it.nodeid in rank), key=lambda it: rank[it.nodeid])
    items[:] = first + [it for it in items if it.nodeid not in rank]


@pytest.fixture(autouse=True)
def _release_held_folders():
    """What a test that calls the run layer directly (not through the CLI, which releases at
    its end) left held: released after each test (groundwork.owner)."""
    yield
    release_all()


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


def _shared_root(tmp_path_factory) -> Path:
    """A folder common to every pytest-xdist worker of this test run (the run's own folder,
    next to the workers' temporary roots); without xdist, the session's temporary root."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        return tmp_path_factory.getbasetemp().parent
    return tmp_path_factory.getbasetemp()


def build_once(tmp_path_factory, name: str, build) -> Path:
    """The folder ``name``, made by ``build(folder)`` once per test run: under pytest-xdist the
    workers share it, and a file lock lets the first worker build it while the others wait
    (a build that failed is made again by the next worker that asks). Read-only for the tests:
    a test that changes it works on a copy."""
    shared = _shared_root(tmp_path_factory)
    out, done = shared / name, shared / f"{name}.done"
    with FileLock(str(shared / f"{name}.lock")):
        if not done.is_file():
            shutil.rmtree(out, ignore_errors=True)
            out.mkdir(parents=True)
            build(out)
            done.touch()
    return out


@pytest.fixture(scope="session")
def shared_build(tmp_path_factory):
    """``shared_build(name, build)``: the folder ``name`` made by ``build(folder)`` once per test
    run, shared by the pytest-xdist workers (:func:`build_once`)."""
    return functools.partial(build_once, tmp_path_factory)


@pytest.fixture(scope="session")
def default_corpus_dir(tmp_path_factory):
    """The default-size corpus (Config().synth, Config().seed): 100 sentences × 3 expressions,
    built once per test run (:func:`build_once`)."""
    cfg = Config()

    def build(folder):
        synthesize_corpus(folder / "corpus", cfg.synth, cfg.seed, progress=False)

    return build_once(tmp_path_factory, "default_corpus", build) / "corpus"


@pytest.fixture(scope="session")
def default_corpus(default_corpus_dir):
    return _freeze(load_corpus(default_corpus_dir))


@pytest.fixture(scope="session")
def small_run_dir(tmp_path_factory):
    """A working folder with a small finished run ``runs/R`` (corpus, units, mapping, stimuli,
    study data, analysis, report: the settings of ``tests.talkingface.bad_input_cases.QUICK``,
    without MLflow) and a corpus ``c``, made once per test run (:func:`build_once`) by the
    command line. Read-only: tests copy the folders they run commands in."""
    from talkingface.cli.main import main
    from tests.talkingface.bad_input_cases import build_run

    def build(folder):
        with pytest.MonkeyPatch.context() as mp:
            mp.chdir(folder)
            build_run(folder, main)

    return build_once(tmp_path_factory, "small_run", build)
