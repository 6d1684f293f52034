"""Thread pools that add up to the cores: one place where a process sets its torch and BLAS
threads.

Every process the project starts to work beside others — a grid's worker, a stage's pool, a
test worker — calls :func:`limit_threads` with :func:`thread_budget` of the number of processes
working at once, so that processes × threads ≤ cores. The networks here are small: a second
torch or OpenBLAS thread buys little even on a quiet machine, and on a loaded one the threads
of several processes competing for two cores spin and wait on each other (a GRU baseline took
10× its quiet time beside the test suite). The limit is set at the process boundary, once, and
inherited by nothing else; a process started alone (the command line) keeps every core.
"""
from __future__ import annotations

import os

from threadpoolctl import threadpool_limits


def cores() -> int:
    """The cores this process may run on (its CPU affinity, else the machine's count; at
    least 1)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def thread_budget(processes: int) -> int:
    """Threads per process when ``processes`` processes work at once.

    Parameters
    ----------
    processes : int
        How many processes share this machine's cores (values below 1 count as 1).

    Returns
    -------
    int
        ``cores() // processes``, at least 1.
    """
    return max(1, cores() // max(1, int(processes)))


def limit_threads(n: int) -> int:
    """Set this process's torch intra-op threads and every loaded BLAS/OpenMP pool to ``n``
    (and the environment, for what it starts).

    Parameters
    ----------
    n : int
        Threads; values below 1 count as 1. Usually :func:`thread_budget` of the processes
        working at once.

    Returns
    -------
    int
        The number of threads set.
    """
    n = max(1, int(n))
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = str(n)
    import torch  # every process that trains imports it anyway

    torch.set_num_threads(n)
    threadpool_limits(n)
    return n
