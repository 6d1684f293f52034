"""Thread pools that add up to the cores (groundwork.threads), at every process boundary the
project starts: a grid's workers (Dask and the process pool) and the test workers."""
from __future__ import annotations

import os

import pytest
import torch
from threadpoolctl import threadpool_info

from groundwork import threads
from groundwork.threads import cores, limit_threads, thread_budget
from talkingface.executor import map_tasks


def test_budget_divides_the_cores(monkeypatch):
    monkeypatch.setattr(threads, "cores", lambda: 8)
    assert [thread_budget(p) for p in (1, 2, 3, 8, 16, 0)] == [8, 4, 2, 1, 1, 8]


def test_limit_sets_torch_blas_and_the_environment(monkeypatch):
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.setenv(var, "7")
    before = torch.get_num_threads()
    try:
        assert limit_threads(1) == 1
        assert torch.get_num_threads() == 1
        assert all(i["num_threads"] == 1 for i in threadpool_info())
        assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
    finally:
        limit_threads(before)


def test_this_test_worker_keeps_within_its_share():
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    assert torch.get_num_threads() * workers <= max(cores(), workers)


def task_threads(_):
    return torch.get_num_threads(), max(i["num_threads"] for i in threadpool_info()
                                        if i["user_api"] == "blas")


@pytest.mark.parametrize("scheduler", ["processes", "local"])
def test_grid_workers_times_threads_within_the_cores(scheduler):
    n = 2
    out = map_tasks(task_threads, {i: (i,) for i in range(4)}, scheduler=scheduler, workers=n,
                    progress=False)
    for torch_threads, blas_threads in out.values():
        assert torch_threads == blas_threads == thread_budget(n)
        assert torch_threads * n <= max(cores(), n)
