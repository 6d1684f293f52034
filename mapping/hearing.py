"""Recordings heard once, on every core: a parallel pass that fills the recogniser entries of the
content-keyed cache before the serial code reads them (issue 38).

Hearing a corpus with a recogniser (:mod:`mapping.recogniser`; hama's streaming decodes cost a
large fraction of the audio's duration: ``bench/bench_hearing.py``) is the one step of a stage
that grows with its recordings and runs one recording at a time. Every recording is heard on its
own, and what it heard is a pure function of its audio and the settings, so the recordings can
be heard in any order, in any process: :func:`hear_all` takes the *jobs* — one recording each,
e.g. :class:`Windows` (:func:`mapping.recogniser.recognise_windows`) or
:class:`analysis.speech_recogniser.Recognised` — keeps those whose entry the cache already holds
(``reused``), hears the rest (``heard``) in a pool of ``workers`` spawned processes of one
thread each (:func:`groundwork.threads.limit_threads`; either recogniser works on one thread, so
processes are what spread it over the cores), longest first, under a bar counting recordings on
stderr. Each worker makes its entry under the key's lock
(:meth:`groundwork.cache.ArrayCache.get_or_make`), so two passes over the same recordings at the
same time (two stages, two test workers) hear each recording once. The code that then reads the phones
(``build_dataset``, the scores on real speech) runs inside
:func:`mapping.recogniser.hearing_cache` and finds every entry: one key, one computation, so the
arrays are the serial path's, byte for byte (tests/mapping/test_hearing.py).

A job is any picklable object with ``names`` (the arrays its entry holds), ``seconds`` (its
audio's length, for the order), ``key()`` (its cache key, of kind
:data:`mapping.recogniser.HEARD_KIND`) and ``compute()`` (the arrays, heard now, with no memo
and no cache); its module must be importable by name in a spawned process.
"""
from __future__ import annotations

import multiprocessing
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from groundwork.cache import ArrayCache
from groundwork.threads import cores, limit_threads
from mapping.recogniser import HEARD_KIND, hear_windows, windows_key


@dataclass(frozen=True, eq=False)
class Windows:
    """One recording for :func:`mapping.recogniser.recognise_windows`: mono float ``y`` at
    ``sample_rate`` Hz heard by ``recogniser`` with ``delay_frames`` of look-ahead and ``back``
    past frames per window, at ``fps``."""

    y: np.ndarray = field(repr=False)
    sample_rate: int
    fps: int = 30
    delay_frames: int = 3
    back: int = 0
    recogniser: str = "pocketsphinx"
    names = ("windows",)

    @property
    def seconds(self) -> float:
        return len(self.y) / self.sample_rate

    def key(self) -> str:
        return windows_key(self.y, self.sample_rate, fps=self.fps,
                           delay_frames=self.delay_frames, back=self.back,
                           recogniser=self.recogniser)

    def compute(self) -> dict:
        return {"windows": hear_windows(self.y, self.sample_rate, fps=self.fps,
                                        delay_frames=self.delay_frames, back=self.back,
                                        recogniser=self.recogniser, progress=False)}


def corpus_jobs(corpus, context: tuple) -> list[Windows]:
    """A :class:`Windows` job per utterance of ``corpus`` (a loaded corpus) for the mapping's
    recogniser ``context`` ``(back, forward[, recogniser])``, as
    :func:`mapping.dataset.build_dataset` hears them."""
    back, forward, *which = context
    return [Windows(u.audio, u.sample_rate, u.fps, int(forward), int(back),
                    which[0] if which else "pocketsphinx") for u in corpus.utterances]


@dataclass
class Passes:
    """What a pass did: ``heard`` recordings heard now, ``reused`` read from the cache."""

    heard: int = 0
    reused: int = 0

    def __add__(self, other: "Passes") -> "Passes":
        return Passes(self.heard + other.heard, self.reused + other.reused)

    def as_dict(self) -> dict:
        return {"heard": self.heard, "reused": self.reused}


def _present(cache, key: str, names) -> bool:
    arrays = cache.get(HEARD_KIND, key)
    return arrays is not None and set(names) <= set(arrays)


def _init_worker() -> None:
    limit_threads(1)  # one recording per process: the pool gives the parallelism


def _fill(root, key: str, job) -> bool:
    """Make the entry ``key`` of the cache at ``root`` from ``job`` under the key's lock; True
    when this call made it (False: another process made it while this one waited)."""
    cache = ArrayCache(root)
    cache.get_or_make(HEARD_KIND, key, job.compute)
    return cache.misses == 1


def hear_all(jobs, cache, *, workers: int = 0, progress: bool = True,
             desc: str = "hearing") -> Passes:
    """Fill the cache's entries of ``jobs`` (see the module docstring) that it lacks.

    Parameters
    ----------
    jobs : iterable
        One job per recording (:class:`Windows`, ...); jobs with the same key are heard once.
    cache : groundwork.cache.ArrayCache
        Where the entries are read and written (its ``hits`` and ``misses`` count them).
    workers : int
        Processes hearing at once (0: :func:`groundwork.threads.cores`); 1, or a single
        recording to hear, hears in this process.
    progress : bool
        A bar of the recordings (reused ones counted at once) on stderr.
    desc : str
        The bar's label.

    Returns
    -------
    Passes
        Distinct recordings heard now and read from the cache.
    """
    unique: dict = {}
    for job in jobs:
        unique.setdefault(job.key(), job)
    missing = {}
    for key, job in unique.items():
        if _present(cache, key, job.names):
            cache.hits += 1
        else:
            missing[key] = job
    passes = Passes(heard=len(missing), reused=len(unique) - len(missing))
    n = min(int(workers) or cores(), len(missing))
    order = sorted(missing, key=lambda k: -missing[k].seconds)  # the longest first
    with tqdm(total=len(unique), initial=passes.reused, desc=desc, unit="recording",
              file=sys.stderr, disable=not progress or not unique) as bar:
        bar.set_postfix_str(f"{passes.reused} from the cache", refresh=False)
        made = 0
        if n <= 1:
            for key in order:
                before = cache.misses
                cache.get_or_make(HEARD_KIND, key, missing[key].compute)
                made += cache.misses - before
                bar.update()
        else:
            pool = ProcessPoolExecutor(max_workers=n, initializer=_init_worker,
                                       mp_context=multiprocessing.get_context("spawn"))
            try:
                futures = [pool.submit(_fill, cache.root, key, missing[key]) for key in order]
                for fut in as_completed(futures):
                    made += fut.result()
                    bar.update()
            finally:  # on an error or Ctrl-C the recordings not started are not started
                pool.shutdown(wait=True, cancel_futures=True)
            cache.misses += made
            cache.hits += len(missing) - made
    # another process hearing the same recordings at the same time (two stages, two test
    # workers) makes some of them: each entry is made once, under its key's lock
    return Passes(heard=made, reused=passes.reused + len(missing) - made)
