"""A tracked copy of a corpus: its markers as the MU-constrained tracker sees them (paper §V).

The paper did not have marker positions; it had video, and its tracker's output was the
audio-visual training data. :func:`track_corpus` does the same to a synthetic corpus: every
utterance is rendered as marker video (:func:`face_model.marker_video.render_marker_video`, sensor
noise ``noise_sd``), its first-frame markers are placed (found in the image by default), and
:class:`face_model.tracker.MUTracker` tracks it. The tracked markers are written as a corpus in
the contract of DESIGN.md — same manifest, audio and phones, the tracked markers in the original
marker coordinates — so every stage can read it; training the mapping on it is
``mapping.visual_source: tracked``.

Beside the corpus files: ``tracking.csv`` (per utterance: frames, mean and max marker error of
the tracked against the original markers, pixels; mean fit residual) and ``corpus.json`` with
``source: tracked``, the tracker settings and the original corpus's hash.
"""
from __future__ import annotations

import csv
import json
import multiprocessing as mp
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
from tqdm.auto import tqdm

from face_model.alignment import speaker_neutrals
from face_model.corpus import corpus_hash, read_manifest, write_manifest
from face_model.marker_video import (INITS, VideoDifficulty, first_frame_markers,
                                     render_marker_video)
from face_model.tracker import MUTracker
from groundwork.atomic import fresh_partial_folder, swap_in
from groundwork.errors import ParameterError
from groundwork.memory import keep_freed_memory
from groundwork.threads import limit_threads, thread_budget


@dataclass(frozen=True)
class TrackedUtterance:
    """One utterance as the tracker saw it.

    Attributes
    ----------
    utt_id : str
        The utterance's id in the corpus.
    markers : ndarray of float32, shape (n_frames, 79, 2)
        The tracked markers, pixels, in the corpus's marker coordinates.
    mups : ndarray, shape (n_frames, A_0 + A_k)
        The fitted Motion Unit parameters of each frame (paper §V, Eq. 5).
    error_px : ndarray, shape (n_frames,)
        Mean distance of the tracked markers to the original ones per frame, pixels.
    residual_px : ndarray, shape (n_frames,)
        RMS residual of the fit per frame, pixels.
    """

    utt_id: str
    markers: np.ndarray
    mups: np.ndarray
    error_px: np.ndarray
    residual_px: np.ndarray


def track_utterance(utt, units, neutral, *, noise_sd: float = 10.0, init: str = "image",
                    seed: int = 0, tracker=None) -> TrackedUtterance:
    """Render one corpus utterance as marker video and track it (paper §V).

    Parameters
    ----------
    utt : Utterance
        A corpus utterance (``utt_id``, ``expression``, ``markers`` (n_frames, 79, 2) pixels).
    units : MotionUnits
        The tracker's fitted MU model.
    neutral : ndarray, shape (79, 2)
        The speaker's neutral face, pixels (:func:`face_model.alignment.speaker_neutrals`).
    noise_sd : float
        Image sensor noise of the rendered video, grey levels.
    init : {"image", "corners", "markers"}
        How the first frame's markers are placed
        (:func:`face_model.marker_video.first_frame_markers`).
    seed : int
        Seeds the video (skin texture, noise).
    tracker : MUTracker, optional
        The tracker; a default :class:`face_model.tracker.MUTracker` when omitted.

    Returns
    -------
    TrackedUtterance
    """
    tracker = MUTracker() if tracker is None else tracker
    frames, mapping = render_marker_video(utt.markers, seed=seed,
                                          difficulty=VideoDifficulty(noise_sd=float(noise_sd)))
    truth = mapping.to_image(utt.markers)
    p0 = first_frame_markers(frames[0], truth[0], units, utt.expression, neutral, init)
    res = tracker.track(frames, units, utt.expression, neutral=neutral, init_markers=p0)
    markers = mapping.to_markers(res.markers)
    err = np.linalg.norm(markers - utt.markers, axis=-1).mean(1)
    return TrackedUtterance(utt.utt_id, markers.astype(np.float32), res.mups, err,
                            res.residual_px)


_WORKER: dict = {}


def _init_worker(units, neutrals, noise_sd: float, init: str, threads: int = 1) -> None:
    cv2.setNumThreads(1)  # one core per process: the pool gives the parallelism
    limit_threads(threads)
    keep_freed_memory()
    _WORKER.update(units=units, neutrals=neutrals, noise_sd=noise_sd, init=init)


def _track_one(job) -> TrackedUtterance:
    utt_id, speaker, expression, markers, seed = job
    w = _WORKER
    u = SimpleNamespace(utt_id=utt_id, speaker=speaker, expression=expression, markers=markers)
    return track_utterance(u, w["units"], w["neutrals"][speaker], noise_sd=w["noise_sd"],
                           init=w["init"], seed=seed)


def track_job(setup: tuple, job: tuple) -> TrackedUtterance:
    """One utterance tracked in a process of its own (a task of a scheduler's ``map_fn``).

    Parameters
    ----------
    setup : tuple
        ``(units, neutrals, noise_sd, init)``: the MU model, ``{speaker: neutral (79, 2)}``,
        the video noise (grey levels) and the first-frame placement.
    job : tuple
        ``(utt_id, speaker, expression, markers, seed)``, markers (n_frames, 79, 2) pixels.

    Returns
    -------
    TrackedUtterance
    """
    with _Serial(setup) as serial:
        cv2.setNumThreads(1)
        return next(serial.imap(_track_one, [job]))


def track_corpus(corpus, units, out_dir, *, noise_sd: float = 10.0, init: str = "image",
                 seed: int = 0, workers: int = 0, progress: bool = True,
                 overwrite: bool = False, map_fn=None) -> dict:
    """Track every utterance of ``corpus`` and write the tracked corpus to ``out_dir``.

    The folder is built beside ``out_dir`` and swapped in when complete
    (:mod:`groundwork.atomic`): an interrupted run leaves a previous ``out_dir`` as it was.

    Parameters
    ----------
    corpus : Corpus
        A loaded corpus (``face_model.corpus.load_corpus``) with its ``root``.
    units : MotionUnits
        The tracker's MU model.
    out_dir : path-like
        The tracked corpus's folder.
    noise_sd : float
        Image sensor noise of the rendered video, grey levels.
    init : {"image", "corners", "markers"}
        How the first frame's markers are placed
        (:func:`face_model.marker_video.first_frame_markers`).
    seed : int
        Seeds each utterance's video (skin texture, noise).
    workers : int
        Processes (0: all cores; 1: this process).
    progress : bool
        Show a progress bar (this machine's pool only).
    overwrite : bool
        Replace an existing ``out_dir``; otherwise an existing folder is refused.
    map_fn : callable, optional
        Where the utterances are tracked instead of this machine's process pool:
        ``map_fn(track_job, {i: (setup, job)})`` returns ``{i: TrackedUtterance}`` (e.g. the
        project's executor on a Dask cluster; ``workers`` is then its business). The result
        is the same wherever it runs: each utterance has its own seed.

    Returns
    -------
    dict
        Summary: utterances, frames, mean and 95th-percentile marker error (pixels), seconds.

    Raises
    ------
    ParameterError
        An unknown ``init``, a negative or non-finite ``noise_sd``, or an existing ``out_dir``
        without ``overwrite``.
    """
    if init not in INITS:
        raise ParameterError(f"init {init!r}; allowed: {', '.join(INITS)}")
    if not (np.isfinite(noise_sd) and noise_sd >= 0):
        raise ParameterError(f"noise_sd must be a finite number >= 0, got {noise_sd!r}")
    out = Path(out_dir)
    if out.exists() and not overwrite:
        raise ParameterError(f"{out} exists; pass overwrite=True to replace it")
    t0 = time.perf_counter()
    setup, jobs = _setup_and_jobs(corpus, units, noise_sd=noise_sd, init=init, seed=seed)
    tmp = fresh_partial_folder(out)
    results = _track_all(setup, jobs, tmp / "markers", workers=workers, progress=progress,
                         map_fn=map_fn)
    src = Path(corpus.root)
    _write_corpus_files(src, tmp, results)
    _write_tracking_csv(tmp / "tracking.csv", results)
    summary = _summary(results, time.perf_counter() - t0)
    info = dict(corpus.info)
    info.update(source="tracked", source_corpus_hash=corpus_hash(src),
                tracker={"noise_sd": float(noise_sd), "init": init, "seed": int(seed)},
                tracking=summary)
    (tmp / "corpus.json").write_text(json.dumps(info, indent=1))
    swap_in(tmp, out)
    return summary


def _setup_and_jobs(corpus, units, *, noise_sd: float, init: str, seed: int
                    ) -> tuple[tuple, list[tuple]]:
    """What every worker needs (:func:`track_job`'s ``setup``) and one job per utterance, in
    corpus order, each with its own seed drawn from ``seed``."""
    neutrals = speaker_neutrals(corpus, model=units.metadata_.get("alignment", "similarity"))
    seeds = np.random.SeedSequence(seed).generate_state(len(corpus.utterances))
    jobs = [(u.utt_id, u.speaker, u.expression, np.asarray(u.markers), int(sd))
            for u, sd in zip(corpus.utterances, seeds)]
    return (units, neutrals, float(noise_sd), init), jobs


def _track_all(setup: tuple, jobs: list[tuple], markers_dir: Path, *, workers: int,
               progress: bool, map_fn=None) -> list[TrackedUtterance]:
    """Every job tracked, in job order, by ``map_fn`` or by this machine's pool of ``workers``
    processes (0: one per core); each one's markers saved in ``markers_dir`` (as it comes
    from the pool)."""
    markers_dir.mkdir()
    n = len(jobs)
    if map_fn is not None:
        done = map_fn(track_job, {i: (setup, job) for i, job in enumerate(jobs)})
        results = [done[i] for i in range(n)]
        for r in results:
            _save_markers(markers_dir, r)
        return results
    workers = min(os.cpu_count() or 1, n) if workers <= 0 else min(workers, n)
    results = []
    with _process_pool(setup, workers) as pool, \
            tqdm(total=n, desc="tracking corpus", unit="utt", disable=not progress) as bar:
        for r in pool.imap(_track_one, jobs):
            _save_markers(markers_dir, r)
            results.append(r)
            bar.update()
    return results


def _save_markers(markers_dir: Path, r: TrackedUtterance) -> None:
    np.save(markers_dir / f"{r.utt_id}.npy", r.markers, allow_pickle=False)


def _process_pool(setup: tuple, workers: int):
    """A pool of ``workers`` processes, each set up with ``setup`` and its share of the cores'
    threads; for one worker, this process (:class:`_Serial`). Used as a context manager."""
    if workers <= 1:
        return _Serial(setup)
    # spawn, not fork: a process that has run OpenCV or torch holds thread pools that a
    # forked child inherits half-locked (it hangs)
    return mp.get_context("spawn").Pool(workers, initializer=_init_worker,
                                        initargs=(*setup, thread_budget(workers)))


def _write_corpus_files(src: Path, dest: Path, results: list[TrackedUtterance]) -> None:
    """The manifest of the utterances tracked, in corpus order, their audio and phone files
    copied from the corpus at ``src`` and their markers the tracked ones."""
    listed = {row["utt_id"]: row for row in read_manifest(src / "manifest.csv")}
    manifest = []
    for r in results:
        row = dict(listed[r.utt_id])
        for key in ("audio", "phones"):
            (dest / row[key]).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src / row[key], dest / row[key])
        row["markers"] = f"markers/{r.utt_id}.npy"
        manifest.append(row)
    write_manifest(dest, manifest)


def _write_tracking_csv(path: Path, results: list[TrackedUtterance]) -> None:
    """``tracking.csv``: per utterance, frames, mean and max marker error and mean fit residual
    (pixels)."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["utt_id", "frames", "error_px_mean", "error_px_max", "residual_px_mean"])
        for r in results:
            w.writerow([r.utt_id, len(r.error_px), f"{r.error_px.mean():.4f}",
                        f"{r.error_px.max():.4f}", f"{np.nanmean(r.residual_px):.4f}"])


def _summary(results: list[TrackedUtterance], seconds: float) -> dict:
    """Utterances, frames, mean and 95th-percentile marker error (pixels), ``seconds``."""
    all_err = np.concatenate([r.error_px for r in results])
    return {"utterances": len(results), "frames": int(len(all_err)),
            "error_px_mean": float(all_err.mean()),
            "error_px_p95": float(np.percentile(all_err, 95)),
            "seconds": seconds}


class _Serial:
    """``Pool``'s ``imap`` in this process (workers=1)."""

    def __init__(self, setup):
        self.setup = setup

    def __enter__(self):
        self.saved = dict(_WORKER)
        _WORKER.update(zip(("units", "neutrals", "noise_sd", "init"), self.setup))
        return self

    def __exit__(self, *exc):
        _WORKER.clear()
        _WORKER.update(self.saved)
        return False

    def imap(self, fn, items):
        return map(fn, items)
