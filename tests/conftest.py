"""Shared fixtures: small synthetic corpora (one per test worker), the default-size corpus, a
quick finished run and the full small replication (each built once per test run, even with
pytest-xdist: ``build_once``), plus seeded random generators; the suite's order and its spread
over the workers (tests/scheduling.py), and one cache for every run the tests make.

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
from talkingface.paths import CACHE_ENV  # noqa: E402
from tests.scheduling import (DurationRecorder, FileScheduling,  # noqa: E402
                              order_items, recorded_costs)
pytest_plugins = ["tests.browser_session"]  # one Chromium per session (tests/browser_session.py)

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


# The content-keyed cache of every run the tests make (the recognisers' passes over the
# real-speech set, a corpus's features): one folder for the whole session and the sessions after
# it (talkingface.paths.CACHE_ENV; `make clean` removes it). Entries are keyed by content, so
# sharing them changes no result; the tests of the cache itself use folders of their own.
os.environ.setdefault(CACHE_ENV, str(REPO_ROOT / "cache"))


def pytest_addoption(parser):
    parser.addoption("--save-durations", metavar="FILE", default=None,
                     help="write each test's measured seconds to FILE (tests/durations.json "
                          "orders the suite: tests/scheduling.py)")


def pytest_configure(config):
    path = config.getoption("--save-durations")
    if path and not hasattr(config, "workerinput"):  # the controller sees every report
        config.pluginmanager.register(DurationRecorder(path), "talkingface-durations")


def pytest_collection_modifyitems(session, config, items):
    """The files that make the shared folders first, then the costliest files
    (tests/scheduling.py)."""
    items[:] = order_items(items, recorded_costs())


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """Whole files handed out in the collection's order (tests/scheduling.py)."""
    return FileScheduling(config, log)


@pytest.fixture(autouse=True)
def _tracking_uri_as_it_was():
    """``mlflow.set_tracking_uri`` (a command that logs, run in-process) also sets
    ``$MLFLOW_TRACKING_URI`` for the whole process: put back as it was after each test, so a
    later test's command does not log to a server an earlier test stopped."""
    before = os.environ.get("MLFLOW_TRACKING_URI")
    yield
    if before is None:
        os.environ.pop("MLFLOW_TRACKING_URI", None)
    else:
        os.environ["MLFLOW_TRACKING_URI"] = before


@pytest.fixture(autouse=True)
def _no_hearing_cache_left():
    """No test leaves a hearing cache active (``mapping.recogniser.hearing_cache``, a context
    variable of the process): a later test's recogniser would read that cache instead of
    hearing its audio (seen once as a missing cost line in tests/talkingface/test_progress.py)."""
    from mapping.recogniser import active_cache

    assert active_cache() is None, "an earlier test left a hearing cache active"
    yield
    assert active_cache() is None, "this test left a hearing cache active"


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
            with open(builds_log(shared, name), "a") as f:  # who made it: tests/test_shared_runs.py
                f.write(f"{os.environ.get('PYTEST_XDIST_WORKER', 'main')} {os.getpid()}\n")
            build(out)
            done.touch()
    return out


def builds_log(shared: Path, name: str) -> Path:
    """The file where :func:`build_once` notes each time it starts making ``name`` (one line:
    the worker and its process)."""
    return shared / f"{name}.builds"


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


@pytest.fixture(scope="session")
def full_run_dir(tmp_path_factory):
    """A working folder with the small full replication ``runs/tiny`` (every stage, the real
    speaker, two voice-robust models, four ceiling steps; ``reports/tiny.pdf``; MLflow's store
    ``mlflow.db`` and ``mlartifacts/``), made once per test run (:func:`build_once`) by the
    command line (tests/talkingface/full_run.py). Read-only: tests copy what they change."""
    from talkingface.cli.main import main
    from tests.talkingface.full_run import build_full_run

    def build(folder):
        with pytest.MonkeyPatch.context() as mp:
            mp.chdir(folder)
            mp.delenv("MLFLOW_TRACKING_URI", raising=False)
            build_full_run(folder, main)

    return build_once(tmp_path_factory, "full_run", build)
