"""Grid tasks on Dask distributed: the same figures as the process pool, a worker killed
mid-grid leaves a complete grid with exactly one child run per setting and seed, and a
scheduler that does not answer is one clear line.

The reference grid of the plain process pool is trained once for the module (``pool_grid``):
the killed-worker grid compares its figures with it, and the finished-task test starts from
one of its folders."""
import contextlib
import json
import os
import signal
import socket
import threading
import time

import pytest

from groundwork.errors import ParameterError
from talkingface.cli.main import main
from talkingface.cli.runs import check_workers_log
from talkingface.config import apply_overrides, load_config
from talkingface.executor import check_reachable, map_tasks
from talkingface.stages.child_runs import KEY_TAG, OLD_KEY_TAG, ChildLog
from talkingface.stages.foundation import fit_units_folder
from talkingface.stages.grid import child_metrics, replicate_folder, run_grid

SETTINGS = {"paper": {}, "context-1": {"context_back": 1, "context_forward": 1}}


@pytest.fixture(scope="module")
def units_path(small_corpus_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("units")
    fit_units_folder(small_corpus_dir, out, load_config(None, []))
    return out / "motion_units.npz"


@pytest.fixture(scope="module")
def pool_grid(small_corpus_dir, units_path, tmp_path_factory):
    """``(folder, results)`` of the test grid (2 settings x 2 seeds) on the plain process pool,
    nothing killed, nothing logged; read-only, tests that change a folder copy it."""
    out = tmp_path_factory.mktemp("pool") / "grid"
    results = run_grid(_jobs(small_corpus_dir, units_path), out, seeds=2,
                       scheduler="processes", workers=2, progress=False)
    return out, results


def _jobs(corpus, units):
    base = load_config(None, ["mapping.splits=[utterance]", "mapping.baselines=[]",
                              "mapping.train.max_epochs=5"])
    return {name: (corpus, units, apply_overrides(base, {"mapping": ch}))
            for name, ch in SETTINGS.items()}


def _store(tmp_path, name):
    """A fresh SQLite store with an experiment and a parent run: its ChildLog."""
    from mlflow.tracking import MlflowClient

    uri = f"sqlite:///{tmp_path / f'{name}.db'}"
    client = MlflowClient(uri)
    exp = client.create_experiment("grid", artifact_location=(tmp_path / f"{name}-art").as_uri())
    parent = client.create_run(exp, run_name="parent").info.run_id
    return ChildLog(uri, exp, parent)


def _figures(results):
    """Every figure of every child but its timings."""
    return {key: {k: v for k, v in child_metrics(r["summary"], "gated_mlp").items()
                  if "seconds" not in k} for key, r in results.items()}


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_worker_killed_mid_grid_leaves_one_child_per_setting_and_seed(
        small_corpus_dir, units_path, pool_grid, tmp_path):
    from distributed import Client, LocalCluster

    jobs = _jobs(small_corpus_dir, units_path)
    pool = pool_grid[1]  # the reference: the plain process pool, nothing killed

    # Dask: a cluster of two worker processes, reached by its address as a lab's would be
    dask_log = _store(tmp_path, "dask")
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        out = {}
        runner = threading.Thread(target=lambda: out.update(run_grid(
            jobs, tmp_path / "dask", seeds=2, scheduler=cluster.scheduler_address, workers=2,
            progress=False, log=dask_log, stage="ablate")))
        runner.start()
        busy = []
        while not busy and runner.is_alive():  # a worker in the middle of a task
            busy = [w for w, tasks in client.processing().items() if tasks]
            time.sleep(0.05)
        assert busy, "the grid ended before any task was seen running"
        pids = client.run(os.getpid)
        before = set(pids)
        os.kill(pids[busy[0]], signal.SIGKILL)
        runner.join(timeout=600)
        assert not runner.is_alive()
        after = set(client.scheduler_info()["workers"])
        assert busy[0] not in after and after != before  # the killed worker was replaced
    # a complete grid: every setting and seed, with the pool's figures bit for bit
    assert set(out) == set(pool) == {(n, k) for n in SETTINGS for k in (0, 1)}
    assert _figures(out) == _figures(pool)
    # exactly one finished child run per setting and seed in the store, nothing half-logged
    children = dask_log.children()
    keys = sorted(r.data.tags[KEY_TAG] for r in children)
    assert keys == sorted(f"{n}/seed-{s}" for n in SETTINGS for s in (2002, 3002))
    assert {r.info.status for r in children} == {"FINISHED"}
    for r in children:
        n, s = r.data.tags["ablation.setting"], int(r.data.tags["ablation.seed"])
        k = (s - 2002) // 1000
        assert r.data.metrics["test.utterance.R"] == out[n, k]["summary"]["ranking"][
            "utterance"][0]["R"]
    # every folder complete, no partial folder left by the killed attempt
    for n, k in out:
        folder = replicate_folder(tmp_path / "dask", n, 2002 + 1000 * k, k)
        assert json.loads((folder / "summary.json").read_text())["seed"] == 2002 + 1000 * k
    assert not [p for p in (tmp_path / "dask").rglob("*")
                if ".partial" in p.name or p.name.endswith(".replaced")]


def test_a_child_logged_twice_half_logged_or_by_racing_attempts_is_one_child_run(
        tmp_path, monkeypatch):
    log = _store(tmp_path, "twice")
    from mlflow.tracking import MlflowClient

    client = MlflowClient(log.uri)
    # what a worker killed while logging leaves: a run with the key that never finished
    dead = client.create_run(log.experiment_id, run_name="paper", tags={
        "mlflow.parentRunId": log.parent_run_id, KEY_TAG: "paper/seed-2002"}).info.run_id
    args = dict(tags={"ablation.setting": "paper"}, params={"seed": 2002},
                metrics={"utterance.mean_test_R": 0.5})
    first = log.log("paper", 2002, **args)
    again = log.log("paper", 2002, **{**args, "metrics": {"utterance.mean_test_R": 0.9}})
    assert again == first  # a finished child is kept, not logged a second time
    assert client.get_run(first).info.run_name == "paper/seed-2002"
    # the unfinished run may be a live attempt's: it goes only when the grid has ended
    assert {r.info.run_id for r in log.children()} == {first, dead}
    assert log.prune() == 1
    children = log.children()
    assert len(children) == 1 and children[0].info.status == "FINISHED"
    assert children[0].data.metrics["utterance.mean_test_R"] == 0.5
    other = log.log("paper", 3002, **args)  # another seed is another child
    assert other != first and len(log.children()) == 2

    # two attempts of one task that both looked before either had finished: each logs its
    # run, then both keep the earlier one
    looked = {"n": 0}
    real = ChildLog._with_key

    def first_look_finds_nothing(self, client, key):
        looked["n"] += 1
        return [] if looked["n"] == 1 else real(self, client, key)

    monkeypatch.setattr(ChildLog, "_with_key", first_look_finds_nothing)
    racer = log.log("paper", 2002, **{**args, "metrics": {"utterance.mean_test_R": 0.9}})
    assert racer == first
    assert sorted(r.info.run_id for r in log.children()) == sorted([first, other])
    assert log.prune() == 0


def test_a_child_logged_under_the_old_key_tag_is_found_not_logged_again(tmp_path):
    log = _store(tmp_path, "old-key")
    from mlflow.tracking import MlflowClient

    client = MlflowClient(log.uri)
    old = client.create_run(log.experiment_id, run_name="paper/seed-2002", tags={
        "mlflow.parentRunId": log.parent_run_id, OLD_KEY_TAG: "paper/seed-2002"}).info.run_id
    client.set_terminated(old, "FINISHED")
    assert KEY_TAG == "grid.key" != OLD_KEY_TAG
    kept = log.log("paper", 2002, tags={}, params={"seed": 2002}, metrics={"test.R": 0.5})
    assert kept == old and [r.info.run_id for r in log.children()] == [old]
    new = log.log("paper", 3002, tags={}, params={"seed": 3002}, metrics={"test.R": 0.5})
    assert client.get_run(new).data.tags[KEY_TAG] == "paper/seed-3002"


def test_a_finished_task_is_found_not_trained_again_and_racing_attempts_keep_one_folder(
        small_corpus_dir, units_path, pool_grid, tmp_path, monkeypatch):
    import shutil

    from talkingface.stages import grid

    (name, (corpus, units, cfg)), = list(_jobs(small_corpus_dir, units_path).items())[:1]
    out = tmp_path / "grid" / name
    # the task as the pool's grid ran it (run_child, replicate 0), its folder copied here
    first = pool_grid[1][name, 0]
    shutil.copytree(replicate_folder(pool_grid[0], name, cfg.seed, 0), out)
    made = (out / "summary.json").read_bytes()
    trained = []
    real_train = grid.train_and_evaluate
    monkeypatch.setattr(grid, "train_and_evaluate",
                        lambda *a, **k: trained.append(a[2]) or real_train(*a, **k))
    # the same task again (a retried task, a resumed grid): found, logged, not trained
    log = _store(tmp_path, "again")
    again = grid.run_child(name, 0, str(corpus), str(units), str(out), cfg, log, "ablate")
    assert trained == [] and again["summary"] == first["summary"]
    assert (out / "summary.json").read_bytes() == made
    assert [r.data.tags[KEY_TAG] for r in log.children()] == [f"{name}/seed-2002"]
    # where or how fast it runs is not part of the task; any result setting is
    fast = apply_overrides(cfg, {"cluster": {"scheduler": "processes"},
                                 "ablations": {"workers": 1}})
    assert grid.task_key(corpus, units, fast) == grid.task_key(corpus, units, cfg)
    other = apply_overrides(cfg, {"mapping": {"train": {"max_epochs": 4}}})
    assert grid.task_key(corpus, units, other) != grid.task_key(corpus, units, cfg)
    assert grid.task_key(corpus, tmp_path / "u.npz", cfg) != grid.task_key(corpus, units, cfg)
    grid.run_child(name, 0, str(corpus), str(units), str(out), other)
    assert len(trained) == 1 and json.loads((out / "summary.json").read_text())[
        "task_key"] == grid.task_key(corpus, units, other)
    # two attempts that both trained: the one that finishes second keeps the first's folder
    key = grid.task_key(corpus, units, other)
    kept = (out / "summary.json").read_bytes()
    late = tmp_path / "grid" / f"{name}.partial-late"
    late.mkdir()
    (late / "summary.json").write_text(json.dumps({"task_key": key, "late": True}))
    assert "late" not in grid._keep_one(late, out, key, {"late": True})
    assert (out / "summary.json").read_bytes() == kept and not late.exists()
    # ... and when both swap at once, the one whose rename fails finds the other's folder
    looks = {"n": 0}
    real_finished = grid.finished_task

    def not_yet_then_finished(folder, k):
        looks["n"] += 1
        return None if looks["n"] == 1 else real_finished(folder, k)

    def collides(partial, folder):
        raise OSError(39, "Directory not empty")

    monkeypatch.setattr(grid, "finished_task", not_yet_then_finished)
    monkeypatch.setattr(grid, "swap_in", collides)
    late.mkdir()
    assert "late" not in grid._keep_one(late, out, key, {"late": True}) and not late.exists()
    assert looks["n"] == 2 and (out / "summary.json").read_bytes() == kept


def test_an_unreachable_scheduler_is_one_line(tmp_path, monkeypatch, capsys):
    port = _free_port()  # nothing listens there
    with pytest.raises(ParameterError, match=rf"cluster.scheduler tcp://127.0.0.1:{port}: no "
                                             "Dask scheduler answers there"):
        check_reachable(f"tcp://127.0.0.1:{port}")
    with pytest.raises(ParameterError, match="no Dask scheduler answers there"):
        map_tasks(max, {"a": (1, 2)}, scheduler=f"tcp://127.0.0.1:{port}", progress=False)
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    # a lab's scheduler with the default store: the workers could not share ./mlflow.db
    with pytest.raises(ParameterError, match=rf"cluster.scheduler tcp://127.0.0.1:{port}: its "
                       rf"workers .* cannot share the tracking store sqlite:///{tmp_path}"):
        check_workers_log(load_config(None, [f"cluster.scheduler=tcp://127.0.0.1:{port}"]))
    check_workers_log(load_config(None, [f"cluster.scheduler=tcp://127.0.0.1:{port}",
                                         "mlflow.uri=http://127.0.0.1:5000"]))
    check_workers_log(load_config(None, [f"cluster.scheduler=tcp://127.0.0.1:{port}",
                                         "mlflow.enabled=false"]))
    # a database every worker reaches is a shared store; a file is not, however it is named
    check_workers_log(load_config(None, [f"cluster.scheduler=tcp://127.0.0.1:{port}",
                                         "mlflow.uri=postgresql://tf@db.lab:5432/mlflow"]))
    for local in (f"file://{tmp_path}/mlruns", "sqlite:///x.db"):
        with pytest.raises(ParameterError, match=f"cannot share the tracking store {local}"):
            check_workers_log(load_config(None, [f"cluster.scheduler=tcp://127.0.0.1:{port}",
                                                 f"mlflow.uri={local}"]))
    (tmp_path / "grid.yaml").write_text("children:\n  paper: {}\n")
    code = main(["ablate", "--grid", "grid.yaml", "--name", "x", "--set",
                 "synth.n_sentences=2", "--scheduler", f"tcp://127.0.0.1:{port}",
                 "--set", "mlflow.enabled=false"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert err.startswith(f"error: cluster.scheduler tcp://127.0.0.1:{port}: no Dask")
    assert not (tmp_path / "runs" / "x").exists()  # refused before anything was written
    code = main(["ablate", "--grid", "grid.yaml", "--name", "x", "--set",
                 f"mlflow.uri=http://127.0.0.1:{port}"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert err.startswith(f"error: mlflow.uri http://127.0.0.1:{port}: no tracking server")
    assert not (tmp_path / "runs" / "x").exists()


_RUNNING_BEFORE: set = set()  # (pid, start time) of the descendants from before the test


@pytest.fixture(autouse=True)
def _descendants_before():
    """What this process ran before the test (the session's shared Chromium, a pytest-xdist
    worker's own children): :func:`_children_alive` leaves them out."""
    import psutil

    _RUNNING_BEFORE.clear()
    for p in psutil.Process().children(recursive=True):
        with contextlib.suppress(psutil.Error):
            _RUNNING_BEFORE.add((p.pid, p.create_time()))
    yield


def _children_alive() -> list:
    """This process's descendants started during the test and still running (a zombie counts
    as ended), but for multiprocessing's resource tracker, which a process keeps, by design,
    from its first spawned child to its own end."""
    import psutil

    from tests.talkingface.browser import wait_gone

    def kept(p):
        try:
            return ((p.pid, p.create_time()) in _RUNNING_BEFORE
                    or "multiprocessing.resource_tracker" in " ".join(p.cmdline()))
        except psutil.Error:
            return False

    return wait_gone([p for p in psutil.Process().children(recursive=True) if not kept(p)])


def test_the_local_executor_and_dask_agree_on_any_function_and_leave_nothing_running():
    assert _children_alive() == []
    tasks = {i: (i, 3) for i in range(5)}
    assert map_tasks(pow, tasks, scheduler="local", workers=2, progress=False) == \
        map_tasks(pow, tasks, scheduler="processes", workers=2, progress=False) == \
        {i: i ** 3 for i in range(5)}
    assert _children_alive() == []  # the LocalCluster's scheduler and workers, the pool's
    with pytest.raises(ZeroDivisionError):  # a task's own error reaches the caller
        map_tasks(divmod, {"x": (1, 0), "y": (4, 2)}, scheduler="local", workers=1,
                  progress=False)
    assert _children_alive() == []  # nothing left running after an error either


def test_a_tracking_uri_that_is_not_mlflow_is_one_line_before_any_work(tmp_path, monkeypatch,
                                                                      capsys):
    from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

    class Answer(BaseHTTPRequestHandler):
        code = 404

        def do_GET(self):
            self.send_error(Answer.code)

        def log_message(self, *args):
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Answer)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    uri = f"http://127.0.0.1:{server.server_address[1]}"
    monkeypatch.chdir(tmp_path)
    for var in ("MLFLOW_TRACKING_USERNAME", "MLFLOW_TRACKING_PASSWORD", "MLFLOW_TRACKING_TOKEN"):
        monkeypatch.delenv(var, raising=False)
    try:
        for code, says in ((404, "a web server answers there but not MLflow's (HTTP 404"),
                           (401, "the tracking server asks for a log-in (HTTP 401)"),
                           (503, "the tracking server answers with HTTP 503")):
            Answer.code = code
            assert main(["evaluate-speech", "--model", "none.npz", "--set",
                         f"mlflow.uri={uri}"]) == 2
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and err.startswith(f"error: mlflow.uri {uri}: {says}"), err
    finally:
        server.shutdown()
        server.server_close()
    assert list(tmp_path.iterdir()) == []


def test_the_tracked_corpus_on_dask_is_the_process_pools_byte_for_byte(small_corpus, units_path,
                                                                      tmp_path):
    from functools import partial

    from face_model.tracked_corpus import track_corpus
    from face_model.corpus import Corpus
    from face_model.motion_units import MotionUnits

    subset = Corpus(root=small_corpus.root, info=small_corpus.info,
                    utterances=[small_corpus[f"s00_{e}_001"] for e in ("neutral", "smile")])
    units = MotionUnits.load(units_path)
    pool = track_corpus(subset, units, tmp_path / "pool", seed=3, workers=2, progress=False)
    dask = track_corpus(subset, units, tmp_path / "dask", seed=3, progress=False,
                        map_fn=partial(map_tasks, scheduler="local", workers=2,
                                       progress=False))
    assert {k: v for k, v in dask.items() if k != "seconds"} == \
        {k: v for k, v in pool.items() if k != "seconds"}
    for u in subset.utterances:
        name = f"markers/{u.utt_id}.npy"
        assert (tmp_path / "dask" / name).read_bytes() == (tmp_path / "pool" / name).read_bytes()
    assert (tmp_path / "dask" / "tracking.csv").read_text() == \
        (tmp_path / "pool" / "tracking.csv").read_text()
    assert _children_alive() == []


def _close_worker_and_its_nanny(code: int) -> None:
    """A task that closes its Dask worker and the nanny that would restart it, then ends the
    worker's process: the cluster has no worker left, and nothing to make one."""
    from distributed import get_worker

    worker = get_worker()
    worker.loop.add_callback(worker.close, nanny=True, executor_wait=False)
    time.sleep(10)
    os._exit(code)


def test_a_local_cluster_that_lost_every_worker_ends_in_one_line(monkeypatch):
    """No worker and no nanny to restart one: the grid cannot go on, and says so (it used to
    wait forever)."""
    from groundwork.errors import TalkingFaceError
    import talkingface.executor as executor

    # no worker for 1 s is gone for good here; the watch looks 4 times a second
    monkeypatch.setattr(executor, "LOCAL_NO_WORKER_S", 1)
    monkeypatch.setattr(executor, "WATCH_EVERY_S", 0.25)
    with pytest.raises(TalkingFaceError, match=r"^cluster.scheduler local: every worker process "
                                               r"of this machine's Dask cluster is gone") as info:
        map_tasks(_close_worker_and_its_nanny, {"x": (3,), "y": (4,)}, scheduler="local",
                  workers=1, progress=False)
    assert "\n" not in str(info.value) and "run the command again" in str(info.value)
    assert _children_alive() == []


def test_a_task_that_kills_every_worker_it_runs_on_is_one_line():
    import dask

    from groundwork.errors import TalkingFaceError

    # os._exit ends the worker process itself: the scheduler runs the task again on the
    # restarted worker until its allowed failures are spent (one here: a task killed twice,
    # not Dask's default four times, each death a worker process started again)
    with dask.config.set({"distributed.scheduler.allowed-failures": 1}), \
            pytest.raises(TalkingFaceError, match=r"^grid task 'x': every worker that ran it "
                                                  r"died \(on local: out of memory") as info:
        map_tasks(os._exit, {"x": (3,)}, scheduler="local", workers=1, progress=False)
    assert "\n" not in str(info.value)  # the CLI prints it as one line
    assert _children_alive() == []
    # the process pool has no retries: its first dead process is the line
    with pytest.raises(TalkingFaceError, match=r"^grid task 'x': a process of the pool "
                                               r"\(cluster.scheduler processes\) died") as info:
        map_tasks(os._exit, {"x": (3,)}, scheduler="processes", workers=1, progress=False)
    assert "\n" not in str(info.value)
    assert _children_alive() == []
