"""The MLflow UI that ``talkingface ui`` and ``talkingface server`` start opens experiments on
their runs table, in a real (headless) browser with a fresh profile: from the front page, from
the bare ``#/experiments/<id>`` link MLflow's client prints, and from the link the command
prints. A browser whose user chose MLflow's GenAI view keeps it.

MLflow 3.17 reads the view (its "workflow type") from the URL's ``workflowType`` parameter, else
from localStorage ``mlflow.workflowType_v1``, else ``genai``, whatever the experiment's
``mlflow.experimentKind`` tag says; the project's MLflow app (``talkingface/mlflow_app.py``)
sets that key to ``"machine_learning"`` where it is unset.
"""
from __future__ import annotations

import contextlib
import os
import queue
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path
from types import SimpleNamespace

import psutil
import pytest

from talkingface.cli import _print_link_when_up, main
from talkingface.mlflow_app import (DEFAULT_WORKFLOW_SCRIPT, WORKFLOW_KEY, create_app,
                                    find_experiment, link_text, runs_url, with_default_workflow)
from talkingface.server import lab_server
from talkingface.server_cli import EXPERIMENT
from tests.talkingface.browser import (alive, alive_processes, headless_chromium, local_storage,
                                       page_headings, processes_mentioning, save_png,
                                       set_local_storage, wait_gone, wait_until)

REPO = Path(__file__).resolve().parents[2]
KIND = {"mlflow.experimentKind": "custom_model_development"}  # as experiment_log tags it
METRIC = "utterance.mean_test_R"
RUNS = ("landing-alpha", "landing-beta")
ML, GENAI = '"machine_learning"', '"genai"'  # localStorage values (JSON strings)
START_S = 400  # a server's start on 2 loaded cores: seconds to a few minutes


def _free_ports(n: int) -> list[int]:
    socks = [socket.socket() for _ in range(n)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def _port_free(port: int) -> bool:
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
        return True


def _env(home: Path) -> dict:
    env = {**os.environ, "HOME": str(home), "PYTHONPATH": os.pathsep.join(filter(None, [
        str(REPO), os.environ.get("PYTHONPATH")]))}
    env.pop("MLFLOW_TRACKING_URI", None)
    return env


def _output_lines(proc) -> queue.Queue:
    """The lines of the process's output as a reader thread receives them ("" at its end); the
    thread keeps draining the pipe, so the server never blocks on it."""
    lines: queue.Queue = queue.Queue()

    def read():
        for line in iter(proc.stdout.readline, ""):
            lines.put(line)
        lines.put("")

    threading.Thread(target=read, daemon=True).start()
    return lines


def _read_until(lines: queue.Queue, marker: str, timeout: float = START_S) -> tuple[str, str]:
    """``(the line starting with marker, all output up to it)``; fails the test after
    ``timeout`` s or when the process ends first."""
    seen, deadline = [], time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=1.0)
        except queue.Empty:
            continue
        if not line:
            break
        seen.append(line)
        if line.startswith(marker):
            return line.rstrip("\n"), "".join(seen)
    raise AssertionError(f"no line {marker!r}; the output: {''.join(seen)[-3000:]}")


def _stop(proc, procs, port: int) -> None:
    """SIGTERM to the command (as a process manager stops it), which stops its server: then
    nothing of it runs and its port is free; whatever a failure left is killed."""
    try:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=180)
        assert wait_gone(procs, timeout=60) == []
        assert _port_free(port)
    finally:
        for p in alive_processes(procs):
            with contextlib.suppress(psutil.Error):
                p.kill()
        if proc.poll() is None:
            proc.kill()
            proc.wait()


# -- the store and `talkingface ui` on it (one server for the tests of this module) ------------
@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """A SQLite store with the project's experiment (tagged as model training) holding two
    finished runs with a metric, and a deleted experiment."""
    from mlflow import MlflowClient

    folder = tmp_path_factory.mktemp("ui-landing")
    uri = f"sqlite:///{folder / 'mlflow.db'}"
    client = MlflowClient(uri)
    exp = client.create_experiment(EXPERIMENT, tags=KIND,
                                   artifact_location=(folder / "mlartifacts").as_uri())
    runs = {}
    for k, name in enumerate(RUNS):
        run = client.create_run(exp, run_name=name)
        client.log_metric(run.info.run_id, METRIC, 0.5 + k / 10)
        client.set_terminated(run.info.run_id)
        runs[name] = run.info.run_id
    gone = client.create_experiment("gone", tags=KIND)
    client.delete_experiment(gone)
    return SimpleNamespace(folder=folder, uri=uri, experiment_id=exp, runs=runs)


@pytest.fixture(scope="module")
def ui(store):
    """``talkingface ui`` on ``store`` (a free port), until the tests of this module are done;
    then stopped by SIGTERM, with nothing of it left running."""
    port, = _free_ports(1)
    proc = subprocess.Popen([sys.executable, "-m", "talkingface", "ui", "--port", str(port),
                             "--set", f"mlflow.uri={store.uri}"], cwd=store.folder,
                            env=_env(store.folder), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    lines = _output_lines(proc)
    procs = []
    try:
        link_line, output = _read_until(lines, "MLflow UI: ")
        procs = processes_mentioning(str(store.folder))  # the command, MLflow and its workers
        yield SimpleNamespace(base=f"http://127.0.0.1:{port}", port=port, output=output,
                              link_line=link_line, procs=procs)
    finally:
        _stop(proc, procs + processes_mentioning(str(store.folder)), port)


def _shots() -> Path:
    return Path(os.environ.get("TALKINGFACE_TEST_ARTIFACTS") or tempfile.gettempdir())


# -- what the browser shows ---------------------------------------------------------------------
# a run's name in the runs table: a link to that run's page
_RUN_LINKS_JS = """
return arguments[0].filter(([name, id]) =>
  [...document.querySelectorAll(`a[href*="/runs/${id}"]`)]
    .some(a => a.textContent.trim() === name)).map(([name]) => name);
"""


def _tab(driver) -> str:
    """The path of the UI's route (the URL's fragment without its query)."""
    return urllib.parse.urlsplit(driver.current_url).fragment.split("?")[0]


def assert_runs_table(driver, experiment_id: str, runs: dict, timeout: float = 180) -> None:
    """The page is the experiment's Runs tab listing ``runs`` (name → id), not MLflow's GenAI
    overview of traces."""
    want = [[name, run_id] for name, run_id in runs.items()]

    def shown(d):
        if _tab(d) != f"/experiments/{experiment_id}/runs":
            return False
        return len(d.execute_script(_RUN_LINKS_JS, want)) == len(want)

    wait_until(driver, shown, f"runs table of experiment {experiment_id} listing "
               f"{sorted(runs)}", timeout)
    assert "workflowType=genai" not in driver.current_url
    headings = page_headings(driver)
    assert "Runs" in headings and "Overview" not in headings, headings
    body = driver.find_element("tag name", "body").text
    assert "No data available" not in body


def assert_genai_overview(driver, experiment_id: str, timeout: float = 180) -> None:
    """The page is MLflow's GenAI overview of the experiment (its traces, token usage)."""
    wait_until(driver, lambda d: _tab(d).startswith(f"/experiments/{experiment_id}/overview")
               and "Overview" in page_headings(d), f"GenAI overview of experiment "
               f"{experiment_id}", timeout)
    assert "workflowType=genai" in driver.current_url


# -- the tests -------------------------------------------------------------------------------
def test_ui_prints_its_address_and_the_link_to_the_runs(ui, store):
    assert (f"MLflow UI on {ui.base} (store: {store.uri}); Ctrl-C stops it"
            in ui.output.splitlines())
    assert ui.link_line == (f"MLflow UI: {ui.base}/#/experiments/{store.experiment_id}/runs"
                            f"?workflowType=machine_learning (the runs of experiment "
                            f"'{EXPERIMENT}')")
    # the server runs the project's app
    cmdlines = [" ".join(p.cmdline()) for p in alive_processes(ui.procs)]
    assert any("--app-name talkingface" in c for c in cmdlines), cmdlines


def test_a_fresh_browser_goes_from_the_front_page_to_the_runs(ui, store):
    from selenium.webdriver.common.by import By

    with headless_chromium() as driver:
        driver.get(f"{ui.base}/")
        link = wait_until(driver, lambda d: next(
            (a for a in d.find_elements(By.CSS_SELECTOR,
                                        f'a[href="#/experiments/{store.experiment_id}"]')
             if a.text.strip() == EXPERIMENT and a.is_displayed()), False),
            f"link to experiment {EXPERIMENT!r} on the front page")
        assert local_storage(driver, WORKFLOW_KEY) == ML  # set by the app's index.html
        driver.execute_script("arguments[0].scrollIntoView({block: 'center'})", link)
        link.click()
        assert_runs_table(driver, store.experiment_id, store.runs)
        save_png(driver, _shots(), "ui_landing_from_front_page.png")


def test_the_experiment_link_mlflow_prints_opens_the_runs(ui, store, capsys):
    from mlflow import MlflowClient

    # a run logged through the UI's server: MLflow's client prints its links, as after any run
    client = MlflowClient(ui.base)
    run = client.create_run(store.experiment_id, run_name="landing-gamma")
    capsys.readouterr()
    client.set_terminated(run.info.run_id)
    printed = re.search(r"View experiment at: (\S+)", capsys.readouterr().out)
    assert printed, "MLflow printed no experiment link"
    assert printed.group(1) == f"{ui.base}/#/experiments/{store.experiment_id}"
    runs = {**store.runs, "landing-gamma": run.info.run_id}
    with headless_chromium() as driver:
        driver.get(printed.group(1))
        assert_runs_table(driver, store.experiment_id, runs)
        assert local_storage(driver, WORKFLOW_KEY) == ML
        save_png(driver, _shots(), "ui_landing_from_mlflow_link.png")


def test_the_link_ui_prints_opens_the_runs(ui, store):
    printed = ui.link_line.split()[2]
    assert printed == runs_url(ui.base, store.experiment_id)
    with headless_chromium() as driver:
        driver.get(printed)
        assert_runs_table(driver, store.experiment_id, store.runs)


def test_a_browser_that_chose_genai_keeps_it(ui, store):
    from selenium.webdriver.common.by import By

    bare = f"{ui.base}/#/experiments/{store.experiment_id}"
    # the user switches to GenAI in the sidebar: MLflow stores the choice, the app keeps it
    with headless_chromium() as driver:
        driver.get(bare)
        assert_runs_table(driver, store.experiment_id, store.runs)
        toggle = [e for e in driver.find_elements(By.CSS_SELECTOR, "aside [role=button]")
                  if e.text.strip() == "GenAI"]
        assert len(toggle) == 1, [e.text for e in driver.find_elements(
            By.CSS_SELECTOR, "aside [role=button]")]
        toggle[0].click()
        assert_genai_overview(driver, store.experiment_id)
        assert local_storage(driver, WORKFLOW_KEY) == GENAI
        driver.get(f"{ui.base}/")  # a new page load runs the app's index.html again
        wait_until(driver, lambda d: page_headings(d), "front page")
        assert local_storage(driver, WORKFLOW_KEY) == GENAI
        driver.get(bare)
        assert_genai_overview(driver, store.experiment_id)
        # the printed link opens the runs all the same, and leaves the choice as it is
        driver.get(runs_url(ui.base, store.experiment_id))
        assert_runs_table(driver, store.experiment_id, store.runs)
        assert local_storage(driver, WORKFLOW_KEY) == GENAI
    # a browser that stored "genai" before it ever loaded the UI
    with headless_chromium() as driver:
        set_local_storage(driver, f"{ui.base}/health", {WORKFLOW_KEY: GENAI})
        driver.get(bare)
        assert_genai_overview(driver, store.experiment_id)
        assert local_storage(driver, WORKFLOW_KEY) == GENAI


def test_the_served_page_and_the_lookup_change_nothing(ui, store, capsys):
    from mlflow import MlflowClient

    with urllib.request.urlopen(f"{ui.base}/", timeout=30) as r:
        html = r.read().decode()
        assert r.headers["Cache-Control"] == "no-cache"
    assert DEFAULT_WORKFLOW_SCRIPT in html
    assert html.index(DEFAULT_WORKFLOW_SCRIPT) < html.index("<script defer")  # before MLflow's
    before = [e.experiment_id for e in MlflowClient(store.uri).search_experiments(view_type=3)]
    assert find_experiment(ui.base, EXPERIMENT) == store.experiment_id
    assert find_experiment(ui.base, "gone") is None  # deleted
    assert find_experiment(ui.base, "no-such-experiment") is None
    # the line `ui` prints for a store without the experiment: the front page, and why
    _print_link_when_up(ui.base, "no-such-experiment", threading.Event())
    assert capsys.readouterr().out == (
        f"MLflow UI: {ui.base}/ (no experiment 'no-such-experiment' in the store yet: it is "
        "listed there once a command logs its first run)\n")
    after = [e.experiment_id for e in MlflowClient(store.uri).search_experiments(view_type=3)]
    assert after == before  # read only: nothing was created
    with pytest.raises(OSError):  # nothing answers there: an error, not "no experiment"
        find_experiment(f"http://127.0.0.1:{_free_ports(1)[0]}", EXPERIMENT, timeout=5)


# -- the app without a server -------------------------------------------------------------------
def test_the_script_goes_first_in_mlflows_index_html():
    import mlflow.server

    index = Path(mlflow.server.app.static_folder, "index.html").read_text()
    html = with_default_workflow(index)
    assert html.startswith(index[:index.index("<head>") + 6] + DEFAULT_WORKFLOW_SCRIPT)
    assert html.replace(DEFAULT_WORKFLOW_SCRIPT, "") == index
    assert with_default_workflow(html) == html  # once
    # only when unset; a stored choice is never overwritten
    assert 'if(window.localStorage.getItem(k)===null)' in DEFAULT_WORKFLOW_SCRIPT
    assert with_default_workflow("<p>no head</p>") == DEFAULT_WORKFLOW_SCRIPT + "<p>no head</p>"


def test_the_app_under_gunicorn_or_waitress_is_mlflows_flask_app(monkeypatch):
    from mlflow.server import app as flask_app

    monkeypatch.setitem(flask_app.view_functions, "serve", flask_app.view_functions["serve"])
    monkeypatch.delenv("_MLFLOW_SGI_NAME", raising=False)
    app = create_app()
    assert app is flask_app
    page = app.test_client().get("/")
    assert page.status_code == 200 and DEFAULT_WORKFLOW_SCRIPT in page.get_data(as_text=True)


def test_ui_refuses_when_the_app_is_not_installed(workdir, monkeypatch, capsys):
    import talkingface.cli as cli
    import talkingface.mlflow_app as mlflow_app

    monkeypatch.setattr(mlflow_app.importlib.metadata, "entry_points", lambda **kw: [])
    started = []
    monkeypatch.setattr(cli, "serve", lambda cmd: started.append(cmd) or 0)
    assert main(["ui", "--port", str(_free_ports(1)[0])]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: the MLflow app 'talkingface'"), err
    assert "is not registered" in err[0] and "pip install --no-deps -e ." in err[0]
    assert started == []


# -- the lab's server (PostgreSQL) --------------------------------------------------------------
@pytest.fixture
def lab_folder():
    """A server folder the ``postgres`` user can reach (not under pytest's mode-700 folders)."""
    parent = Path(tempfile.mkdtemp(prefix="talkingface-ui-lab-"))
    os.chmod(parent, 0o755)
    try:
        yield parent / "server"
    finally:
        for p in alive_processes(processes_mentioning(str(parent))):
            with contextlib.suppress(psutil.Error):
                p.kill()
        shutil.rmtree(parent, ignore_errors=True)


def _get(url: str, host: str) -> int:
    """The HTTP status of a GET of ``url`` sent with the Host header ``host``."""
    try:
        with urllib.request.urlopen(urllib.request.Request(url, headers={"Host": host}),
                                    timeout=30) as r:
            return r.status
    except urllib.error.HTTPError as exc:
        return exc.code


def test_the_lab_server_prints_the_runs_link_and_opens_on_the_runs(lab_folder, capsys):
    from mlflow import MlflowClient

    port, db_port = _free_ports(2)
    with lab_server(lab_folder, port=port, db_port=db_port) as server:
        client = MlflowClient(server.uri)
        exp = client.create_experiment(EXPERIMENT, tags=KIND)
        runs = {}
        for name in RUNS:
            run = client.create_run(exp, run_name=name)
            client.log_metric(run.info.run_id, METRIC, 0.5)
            client.set_terminated(run.info.run_id)
            runs[name] = run.info.run_id
    capsys.readouterr()

    # the command a lab runs, on the same database; with a host name colleagues use
    proc = subprocess.Popen([sys.executable, "-m", "talkingface", "server", "--folder",
                             str(lab_folder), "--port", str(port), "--db-port", str(db_port),
                             "--allowed-hosts", "mlflow.lab.example"],
                            cwd=lab_folder.parent, env=_env(lab_folder.parent),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    lines = _output_lines(proc)
    procs = []
    try:
        line, banner = _read_until(lines, "server: its UI:")
        procs = processes_mentioning(str(lab_folder))
        base = f"http://127.0.0.1:{port}"
        assert line == (f"server: its UI: {base}/#/experiments/{exp}/runs?workflowType="
                        f"machine_learning (the runs of experiment '{EXPERIMENT}'); Ctrl-C "
                        "here stops the server and its database")
        assert f"export MLFLOW_TRACKING_URI={base}" in banner and "reusing the database" in banner
        assert "--app-name talkingface" in " ".join(" ".join(p.cmdline()) for p in procs)
        # the names listed are accepted (with the port a browser adds), others are not
        api = f"{base}/api/2.0/mlflow/experiments/search?max_results=1"
        assert _get(api, f"mlflow.lab.example:{port}") == 200
        assert _get(api, "mlflow.lab.example") == 200
        assert _get(api, f"127.0.0.1:{port}") == 200
        assert _get(api, f"elsewhere.example:{port}") == 403
        with headless_chromium() as driver:
            driver.get(line.split()[3])  # the printed link
            assert_runs_table(driver, exp, runs)
            assert local_storage(driver, WORKFLOW_KEY) == ML
        with headless_chromium() as driver:
            driver.get(f"{base}/#/experiments/{exp}")  # the link MLflow's client prints
            assert_runs_table(driver, exp, runs)
            save_png(driver, _shots(), "ui_landing_lab_server.png")
        proc.send_signal(signal.SIGTERM)
        _read_until(lines, "server: stopped (SIGTERM)", timeout=180)
        assert proc.wait(timeout=180) == 0
        assert wait_gone(procs) == []
        assert alive(processes_mentioning(str(lab_folder))) == []
        assert _port_free(port) and _port_free(db_port)
    finally:
        if proc.poll() is None:  # a failed test: let the command stop what it started
            proc.terminate()
            proc.wait(timeout=180)
    # a link to the front page, and why, when the store has no such experiment yet
    assert link_text(base, "other", None) == (
        f"{base}/ (no experiment 'other' in the store yet: it is listed there once a command "
        "logs its first run)")
