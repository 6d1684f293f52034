"""Where the grid stages' tasks run: Dask distributed, or a plain process pool.

Every grid stage (the ablations, the ceiling steps, the voice-robust models, and each of their
seed replicates) is a set of independent tasks. :func:`map_tasks` runs them on the scheduler
named by ``cluster.scheduler``:

``local`` (the default)
    a Dask ``LocalCluster`` started for the stage on this machine: ``workers`` worker processes
    (0: one per core), one thread each, no dashboard; closed when the stage ends.
``tcp://HOST:PORT``
    a running Dask scheduler (``dask scheduler`` and ``dask worker`` on a lab's machines, or a
    dask-jobqueue cluster on SLURM/PBS: see the README). Its workers need the project installed,
    the run folder on a shared file system, and a tracking server all of them reach
    (``mlflow.uri``), since they log their child runs themselves.
``processes``
    a ``concurrent.futures`` process pool (spawned processes, one torch thread each): the
    executor without Dask, whose results a test compares with Dask's.

A task that dies with its worker is run again on another worker by the Dask scheduler (up to
``distributed.scheduler.allowed-failures`` times); tasks are written to be run again safely
(:func:`talkingface.stages.grid.run_child` writes its folder under a temporary name and its
MLflow child run is keyed by setting and seed). Every task's process sets its torch and BLAS
threads so that workers × threads ≤ cores (:mod:`groundwork.threads`): the parallelism is the
workers'.
"""
from __future__ import annotations

import logging
import multiprocessing
import os
import socket
import struct
import sys
import threading
import time
import uuid
from concurrent.futures import CancelledError, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager, suppress

from tqdm import tqdm

from groundwork.errors import ParameterError, TalkingFaceError
from groundwork.memory import keep_freed_memory
from groundwork.threads import cores, limit_threads, thread_budget

SCHEDULERS = ("local", "processes")
CONNECT_TIMEOUT_S = 10
NO_WORKER_WARN_S = 30
LOCAL_NO_WORKER_S = 30  # a LocalCluster without a worker this long has lost them for good
WATCH_EVERY_S = 2


def scheduler_address(value: str) -> tuple[str, int] | None:
    """``(host, port)`` of a ``tcp://HOST:PORT`` scheduler, None for ``local`` and
    ``processes``; anything else is refused, naming what is allowed."""
    if value in SCHEDULERS:
        return None
    host, _, port = value.removeprefix("tcp://").rpartition(":")
    host = host.removeprefix("[").removesuffix("]")  # an IPv6 address in brackets
    if not value.startswith("tcp://") or not host or any(c.isspace() or c == "/" for c in host) \
            or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ParameterError(f"cluster.scheduler is {value!r}; allowed: local (a Dask "
                             "LocalCluster on this machine), processes (a process pool), or a "
                             "running Dask scheduler's address tcp://HOST:PORT (port 1-65535)")
    return host, int(port)


def check_scheduler(value: str) -> None:
    """Refuse a ``cluster.scheduler`` that is neither a known name nor a ``tcp://`` address."""
    scheduler_address(value)


def check_reachable(scheduler: str) -> None:
    """Refuse a ``tcp://`` scheduler that does not accept a connection, or that is not a Dask
    scheduler (checked before a command starts its work, and again when a grid connects: a
    Dask client would wait forever on a server that speaks another protocol); ``local`` and
    ``processes`` need nothing."""
    address = scheduler_address(scheduler)
    if address is None:
        return
    try:
        sock = socket.create_connection(address, timeout=CONNECT_TIMEOUT_S)
    except OSError as exc:
        raise ParameterError(f"cluster.scheduler {scheduler}: no Dask scheduler answers there "
                             f"({exc.strerror or type(exc).__name__}); start one (`dask "
                             "scheduler`) or use cluster.scheduler=local") from None
    with sock:
        greeting = _first_bytes(sock, 16, CONNECT_TIMEOUT_S)
    if not _is_dask_greeting(greeting):
        said = f"it sent {greeting[:16]!r}" if greeting else \
            f"it sent nothing within {CONNECT_TIMEOUT_S} s"
        raise ParameterError(f"cluster.scheduler {scheduler}: something accepts connections "
                             f"there but it is not a Dask scheduler ({said}); check the "
                             "address and port (`dask scheduler` prints them)")


def _first_bytes(sock, n: int, timeout_s: float) -> bytes:
    """Up to ``n`` bytes a server sends on its own after a connection, waiting at most
    ``timeout_s`` seconds in all."""
    deadline = time.monotonic() + timeout_s
    buf = b""
    while len(buf) < n:
        left = deadline - time.monotonic()
        if left <= 0:
            break
        sock.settimeout(left)
        try:
            chunk = sock.recv(n - len(buf))
        except (socket.timeout, OSError):
            break
        if not chunk:
            break
        buf += chunk
    return buf


def _is_dask_greeting(data: bytes) -> bool:
    """Whether ``data`` opens a Dask TCP message, as a scheduler sends one on every new
    connection (its handshake): a little-endian uint64 message length, then the number of
    frames (``distributed.comm.tcp``)."""
    if len(data) < 16:
        return False
    length, frames = struct.unpack("<QQ", data[:16])
    return 8 < length < 2**20 and 1 <= frames <= 64


def _call(fn, args, threads: int = 1):
    limit_threads(threads)  # processes x threads <= cores (groundwork.threads)
    keep_freed_memory()  # no page faults for every epoch's tensors (groundwork.memory)
    return fn(*args)


@contextmanager
def dask_client(scheduler: str, workers: int):
    """A Dask client: of a ``LocalCluster`` started here (``scheduler == "local"``), closed
    with it on exit, or of the running scheduler at ``tcp://HOST:PORT``."""
    from distributed import Client, LocalCluster

    if scheduler == "local":
        n = workers or cores()
        t = str(thread_budget(n))
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                          dashboard_address=None, silence_logs=logging.ERROR,
                          env={"OMP_NUM_THREADS": t, "OPENBLAS_NUM_THREADS": t,
                               "MKL_NUM_THREADS": t}) as cluster, Client(cluster) as client:
            yield client
        return
    check_reachable(scheduler)  # a server that is not Dask's would hang the client
    try:
        client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
    except (OSError, TimeoutError) as exc:
        raise ParameterError(f"cluster.scheduler {scheduler}: no Dask scheduler answered within "
                             f"{CONNECT_TIMEOUT_S} s ({type(exc).__name__}); start one "
                             "(`dask scheduler`) or use cluster.scheduler=local") from None
    with client:
        yield client


def _dask_result(fut, key, scheduler: str):
    """The result of one Dask task; a task that kept killing its workers, or a scheduler lost
    mid-grid, is one line naming the task (the task's own errors pass as they are)."""
    from distributed import KilledWorker
    from distributed.comm.core import CommClosedError

    try:
        return fut.result()
    except KilledWorker as exc:
        raise TalkingFaceError(
            f"grid task {key!r}: every worker that ran it died (on {scheduler}: out of memory, "
            f"or a node that keeps failing?): {' '.join(str(exc).split())}") from None
    except (CommClosedError, CancelledError) as exc:
        raise TalkingFaceError(f"cluster.scheduler {scheduler}: the connection to the Dask "
                               f"scheduler was lost while task {key!r} ran "
                               f"({type(exc).__name__}); the finished tasks' folders are "
                               "kept: run the command again to go on") from None


def _pool_result(fut, key):
    """The result of one process-pool task; a pool whose process died is one line naming the
    task (the task's own errors pass as they are)."""
    try:
        return fut.result()
    except BrokenProcessPool:
        raise TalkingFaceError(
            f"grid task {key!r}: a process of the pool (cluster.scheduler processes) died while "
            "it ran (out of memory, or killed?); the finished tasks' folders are kept: run the "
            "command again to go on") from None


class _WorkerWatch:
    """Watch a grid's workers while its tasks run. A running scheduler (``tcp://``) that has
    had no worker for ``NO_WORKER_WARN_S`` seconds gets one warning on stderr: its tasks wait
    for workers that may still be queued as batch jobs. A ``LocalCluster`` that has had no
    worker for ``LOCAL_NO_WORKER_S`` seconds (its processes and their nannies are gone: killed,
    out of memory) will never get one: the grid's tasks are cancelled and :attr:`failed` says
    why, so that the grid ends in one line instead of waiting forever."""

    def __init__(self, client, scheduler: str, futures):
        self._stop = threading.Event()
        self.failed: str | None = None
        target = self._local if scheduler == "local" else self._remote
        self._thread = threading.Thread(target=target, args=(client, scheduler, futures),
                                        daemon=True)
        self._thread.start()

    @staticmethod
    def _has_workers(client) -> bool:
        return bool(client.scheduler_info().get("workers"))

    def _remote(self, client, scheduler, futures):
        if self._stop.wait(NO_WORKER_WARN_S):
            return
        with suppress(Exception):  # a warning only: the scheduler's own errors are reported
            if not self._has_workers(client):
                print(f"warning: cluster.scheduler {scheduler} has no worker; the tasks wait "
                      "until one joins (`dask worker tcp://HOST:PORT`, or the batch jobs of "
                      "dask-jobqueue)", file=sys.stderr, flush=True)

    def _local(self, client, scheduler, futures):
        since = None
        while not self._stop.wait(WATCH_EVERY_S):
            try:
                alive = self._has_workers(client)
            except Exception:  # the cluster is closing: the grid's own end reports it
                return
            now = time.monotonic()
            since = None if alive else (since or now)
            if since is not None and now - since >= LOCAL_NO_WORKER_S:
                self.failed = (f"cluster.scheduler local: every worker process of this "
                               f"machine's Dask cluster is gone (for {LOCAL_NO_WORKER_S} s: "
                               "killed, or out of memory?) and none restarts; the finished "
                               "tasks' folders are kept: run the command again to go on")
                with suppress(Exception):
                    client.cancel(list(futures))
                return

    def stop(self):
        self._stop.set()


def map_tasks(fn, tasks: dict, *, scheduler: str = "local", workers: int = 0,
              desc: str = "tasks", progress: bool = True) -> dict:
    """``{key: fn(*args)}`` for every ``key: args`` of ``tasks``, run on ``scheduler`` (see the
    module text) with ``workers`` processes for ``local`` and ``processes`` (0: one per core).

    ``fn`` must be importable by name (a module-level function) and its arguments picklable.
    An exception raised by a task is raised here, after the other tasks have been cancelled.
    """
    check_scheduler(scheduler)
    if not tasks:
        return {}
    bar = tqdm(total=len(tasks), desc=desc, unit="run", disable=not progress)
    out = {}
    try:
        if scheduler == "processes":
            n = min(workers or cores(), len(tasks))
            ctx = multiprocessing.get_context("spawn")  # torch is not fork-safe
            pool = ProcessPoolExecutor(max_workers=n, mp_context=ctx)
            try:
                futs = {pool.submit(_call, fn, args, thread_budget(n)): key
                        for key, args in tasks.items()}
                for fut in as_completed(futs):
                    out[futs[fut]] = _pool_result(fut, futs[fut])
                    bar.update()
            finally:  # on an error, the tasks not started yet are not started
                pool.shutdown(wait=True, cancel_futures=True)
            return out
        from distributed import as_completed as dask_completed

        tag = uuid.uuid4().hex[:8]  # the keys of one call, unique on a shared scheduler
        n = min(workers or cores(), len(tasks))
        # a cluster's workers: one thread each (their machines' cores are not known here)
        threads = thread_budget(n) if scheduler == "local" else 1
        with dask_client(scheduler, n) as client:
            futs = {client.submit(_call, fn, args, threads, key=f"{desc}-{tag}-{i}",
                                  pure=False): key
                    for i, (key, args) in enumerate(tasks.items())}
            watch = _WorkerWatch(client, scheduler, futs)
            try:
                for fut in dask_completed(futs):
                    if watch.failed:
                        raise TalkingFaceError(watch.failed)
                    out[futs[fut]] = _dask_result(fut, futs[fut], scheduler)
                    bar.update()
            finally:
                watch.stop()
                client.cancel(list(futs))
        return out
    finally:
        bar.close()
