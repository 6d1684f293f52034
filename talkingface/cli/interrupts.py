"""Ctrl-C for the commands that start worker processes: one line, no tracebacks from them.

A terminal's Ctrl-C sends SIGINT to every process of the foreground process group: the command,
and the worker processes it started (Dask's workers, the speech synthesis pool, a process pool).
Each worker then raises ``KeyboardInterrupt`` wherever it is (often while still importing) and
prints its traceback to the terminal, after the command's own ``interrupted: ...`` line; and a
Dask cluster whose workers died half-started fails again when Python closes it at exit.

:func:`interrupts_for_this_process` keeps SIGINT to the command alone: while it is active, SIGINT
is blocked in the command's threads, so every process they start inherits it blocked (a blocked
signal stays blocked across ``fork`` and ``exec``) and never sees a Ctrl-C; one thread of the
command waits for it (``sigwait``) and raises ``KeyboardInterrupt`` in the main thread, waking it
from a blocking call. The command then ends its workers the way it ends them on any error (a
Dask cluster closes with its context, a pool is terminated), and :func:`end_after_interrupt`
closes, without a word, a Dask cluster cut while it started.

An interrupt raised where Python cannot pass it on is not lost: in an ``os.fork`` hook (a pool
forking a worker runs logging's, for one), a finaliser or a weak reference's callback, Python
reports a ``KeyboardInterrupt`` as "unraisable" ("Exception ignored in ...", with a traceback)
and drops it. While the block is active, ``sys.unraisablehook`` takes such a one without a word
and has the waiting thread raise it again in the main thread, as for a new Ctrl-C, so that it
surfaces in the next ordinary code (the hook cannot raise it itself: Python would raise it in
the hook, which drops it too); one still waiting when the block ends is raised as it ends.
Other unraisable exceptions go to the hook there was before, which is put back on exit.

A worker that never sees the Ctrl-C must not outlive the command. Spawned workers (Dask's, a
spawn pool's) end by themselves when the command has gone (Dask's watch their parent; a pool's
read EOF). A forked worker shares the command's pipes and locks and would wait for ever (a pool
cut while it was being made, or a worker forked to replace one that ended): every process forked
meanwhile watches for its parent's end and ends with it (:func:`_forked_child`).

(multiprocessing's resource tracker unblocks SIGINT in the thread that starts it; it is started
before SIGINT is blocked, so that it is not started again from a thread that blocks it.)
"""
from __future__ import annotations

import _thread
import atexit
import contextlib
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from multiprocessing import resource_tracker

# The commands that start worker processes (Dask, process pools, the speech synthesis pool,
# the pool that hears recordings).
WORKER_COMMANDS = ("replicate", "train", "track", "ablate", "synth", "units",
                   "evaluate-speech")
INTERRUPTED = ("interrupted: finished stages and files are kept; unfinished ones were not "
               "written under their names (a grid's finished tasks are: the same command goes "
               "on from them)")

TRACKER_WARNINGS = "ignore::UserWarning:multiprocessing.resource_tracker"

# a signal whose delivery to the main thread interrupts the call it is blocked in (a lock, a
# wait for a child); by default it is ignored, and it is restored on exit
_WAKE = signal.SIGURG


def _no_op(signum, frame) -> None:
    return None


def interrupts_for(command: str) -> contextlib.AbstractContextManager:
    """:func:`interrupts_for_this_process` for a command of :data:`WORKER_COMMANDS`; nothing
    for the others (a server forwards Ctrl-C to its process itself)."""
    if command in WORKER_COMMANDS:
        return interrupts_for_this_process()
    return contextlib.nullcontext()


@contextlib.contextmanager
def interrupts_for_this_process() -> Iterator[None]:
    """SIGINT (Ctrl-C) raises ``KeyboardInterrupt`` in this process's main thread only; the
    processes started meanwhile, by any of its threads, do not receive it (see the module
    docstring). Does nothing outside the main thread or where signals cannot be blocked."""
    if threading.current_thread() is not threading.main_thread() \
            or not hasattr(signal, "pthread_sigmask"):
        yield
        return
    _start_resource_tracker()
    main_id = threading.main_thread().ident
    owner = os.getpid()
    old_wake = signal.signal(_WAKE, _no_op)
    old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    was_active, _keep["active"] = _keep["active"], True
    stop = threading.Event()
    dropped = threading.Event()  # an interrupt Python dropped, not raised again yet

    def wait_for_ctrl_c() -> None:  # SIGINT is blocked here too (inherited): sigwait takes it
        while True:
            signal.sigwait({signal.SIGINT})
            if stop.is_set():
                return
            dropped.clear()  # raised again now, with this one
            _thread.interrupt_main(signal.SIGINT)  # KeyboardInterrupt at the next bytecode
            with contextlib.suppress(ProcessLookupError, OSError):
                signal.pthread_kill(main_id, _WAKE)  # ... or now, out of a blocking call

    waiter = threading.Thread(target=wait_for_ctrl_c, name="ctrl-c", daemon=True)
    old_hook = sys.unraisablehook

    def keep_interrupts(unraisable) -> None:
        """A ``KeyboardInterrupt`` Python could not raise, raised again (module docstring)."""
        if not (isinstance(unraisable.exc_type, type)
                and issubclass(unraisable.exc_type, KeyboardInterrupt)
                and os.getpid() == owner and threading.get_ident() == main_id):
            old_hook(unraisable)
            return
        try:
            _raise_again(dropped, stop, waiter)
        except KeyboardInterrupt:  # another one, raised here: kept the same way
            _raise_again(dropped, stop, waiter)

    waiter.start()
    sys.unraisablehook = keep_interrupts
    ended = interrupted = False
    try:
        yield
        ended = True
    except KeyboardInterrupt:
        interrupted = True
        raise
    finally:
        stop.set()
        with contextlib.suppress(ProcessLookupError, OSError):
            signal.pthread_kill(waiter.ident, signal.SIGINT)  # ends its sigwait
        waiter.join(timeout=5)
        if ended:  # else a pool cut short may still fork workers: they die with the process
            _keep["active"] = was_active
        signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)
        signal.signal(_WAKE, old_wake)
        if sys.unraisablehook is keep_interrupts:
            sys.unraisablehook = old_hook
        if dropped.is_set() and not interrupted:  # dropped, and the waiter has gone
            raise KeyboardInterrupt


def _raise_again(dropped: threading.Event, stop: threading.Event,
                 waiter: threading.Thread) -> None:
    """Have the waiting thread raise a dropped interrupt again in the main thread (as for a
    Ctrl-C); once the block is ending, it raises it as it ends (``dropped``)."""
    dropped.set()
    if not stop.is_set():
        with contextlib.suppress(ProcessLookupError, OSError):
            signal.pthread_kill(waiter.ident, signal.SIGINT)


def _start_resource_tracker() -> None:
    """multiprocessing's resource tracker, started now: the first process a pool spawns starts
    it otherwise, and it unblocks SIGINT in the thread that starts it. It cleans up what the
    workers registered (their semaphores) and says so on stderr for a worker that ended without
    releasing them, as workers ended by an interrupt do: it is started with its own warnings
    off (:data:`TRACKER_WARNINGS`), which changes no clean-up."""
    if getattr(resource_tracker._resource_tracker, "_fd", None) is not None:
        return  # running already (its warnings as they were)
    sys.warnoptions.append(TRACKER_WARNINGS)
    try:
        resource_tracker.ensure_running()
    finally:
        sys.warnoptions.remove(TRACKER_WARNINGS)


def end_after_interrupt(wait_s: float = 10.0) -> None:
    """After an interrupt, before the command exits: Dask's and asyncio's loggers quieted, and
    Dask's clusters not closed yet closed now, without a word (one cut while its workers
    started fails its own close at exit, with a traceback)."""
    if "distributed" not in sys.modules:
        return
    # and asyncio's: the tasks of a worker cut while it started report their end when collected
    for name in ("distributed", "asyncio"):
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)
    from distributed.deploy import spec

    atexit.unregister(spec.close_clusters)
    for cluster in list(spec.SpecCluster._instances):
        if getattr(getattr(cluster, "status", None), "name", "closed") != "closed":
            with contextlib.suppress(BaseException):
                cluster.close(timeout=wait_s)


# -- forked workers end with the command ---------------------------------------------------------
_keep = {"active": False, "forker": 0}  # copied into each forked child with the memory
WATCH_PARENT_S = 1.0  # how often a forked child looks for its parent


def _before_fork() -> None:
    _keep["forker"] = os.getpid()


def _forked_child() -> None:
    """In a child forked while :func:`interrupts_for_this_process` is active: a daemon thread
    that ends the child once the process that forked it has gone. A forked worker shares the
    command's pipes and locks, does not see the Ctrl-C, and would otherwise wait for ever (a
    pool cut while it was being made, or a worker forked to replace one that ended). A child
    that runs another program (``exec``) loses the thread with the rest of its memory."""
    if not _keep["active"]:
        return
    parent = _keep["forker"]

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(WATCH_PARENT_S)
        os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(before=_before_fork, after_in_child=_forked_child)
