"""The MLflow UI that ``talkingface ui`` starts (as a user starts it: one server for this module,
which also proves it serves MLflow's front page and stops whole on SIGTERM) opens experiments on
their runs table, in a real (headless) browser in a fresh profile's state (one Chromium per
test session, cleared for each use: tests/browser_session.py): from the front page, from
the bare ``#/experiments/<id>`` link MLflow's client prints, and from the link the command
prints. A browser whose user chose MLflow's GenAI view keeps it.

MLflow 3.17 reads the view (its "workflow type") from the URL's ``workflowType`` parameter, else
from localStorage ``mlflow.workflowType_v1``, else ``genai``, whatever the experiment's
``mlflow.experimentKind`` tag says; the project's MLflow app (``talkingface/experiments/mlflow_app.py``)
sets that key to ``"machine_learning"`` where it is unset.

The printed link lists the pipeline's own runs and the grids' parent runs, not the grids' many
runs: from it a person reaches a real ablation grid's answer (the best setting, its difference
with its interval and Holm p, the table of every setting) in at most two clicks, and finds the
forest plot and ``summary.csv`` at the top of the parent's artifacts; a second printed link
lists the grid's runs, one per setting and seed.
"""
from __future__ import annotations

import contextlib
import os
import queue
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse
import urllib.request
from pathlib import Path
from types import SimpleNamespace

import psutil
import pytest

from talkingface.cli.lab_server import EXPERIMENT
from talkingface.cli.main import _print_link_when_up, main
from talkingface.experiments.mlflow_app import (ASSISTANT_KEY, DEFAULT_WORKFLOW_SCRIPT, NEWEST_FIRST_FLAT,
                                    PIPELINE_FILTER, RUN_NAME, WORKFLOW_KEY, create_app,
                                    find_experiment, grid_filter, grid_link_text, grid_url,
                                    pipeline_url, runs_url, with_default_workflow)
from tests.talkingface.browser import (alive_processes, click, command_lines, displayed_with_text,
                                       local_storage, page_headings, processes_mentioning,
                                       save_png, set_local_storage,
                                       wait_gone, wait_until)

REPO = Path(__file__).resolve().parents[2]
KIND = {"mlflow.experimentKind": "custom_model_development"}  # as experiment_log tags it
STAGE = {"stage": "train"}  # as `talkingface train` tags its run: one of the pipeline's runs
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


def _group_gone(pgid: int, timeout: float = 60.0) -> bool:
    """Wait up to ``timeout`` s until no process of group ``pgid`` is left (zombies count)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.1)
    return False


def _stop(proc, procs, port: int) -> None:
    """SIGTERM to the command alone (as a process manager stops it), which stops its server
    and its workers too: then nothing of its process group runs, nor any of ``procs``, and its
    port is free; whatever a failure left is killed."""
    try:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=180)
        assert _group_gone(proc.pid), "the MLflow server outlived `talkingface ui`"
        assert wait_gone(procs, timeout=60) == []
        assert _port_free(port)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
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
    finished runs of the pipeline (tagged with their stage) with a metric, and a deleted
    experiment."""
    from mlflow import MlflowClient

    folder = tmp_path_factory.mktemp("ui-landing")
    uri = f"sqlite:///{folder / 'mlflow.db'}"
    client = MlflowClient(uri)
    exp = client.create_experiment(EXPERIMENT, tags=KIND,
                                   artifact_location=(folder / "mlartifacts").as_uri())
    runs = {}
    for k, name in enumerate(RUNS):
        run = client.create_run(exp, run_name=name, tags=STAGE)
        client.log_metric(run.info.run_id, METRIC, 0.5 + k / 10)
        client.set_terminated(run.info.run_id)
        runs[name] = run.info.run_id
    gone = client.create_experiment("gone", tags=KIND)
    client.delete_experiment(gone)
    return SimpleNamespace(folder=folder, uri=uri, experiment_id=exp, runs=runs)


@pytest.fixture(scope="module")
def ui(store):
    """``talkingface ui`` as a user starts it, in the store's folder (its default store there:
    ``./mlflow.db``; MLflow's server with one web worker and no job runner), on a free port,
    until the tests of this module are done; then stopped by SIGTERM to the command alone, as a
    process manager stops it, with nothing of its process group left running and its port
    free (:func:`_stop`)."""
    port, = _free_ports(1)
    proc = subprocess.Popen([sys.executable, "-m", "talkingface", "ui", "--port", str(port)],
                            cwd=store.folder, env=_env(store.folder), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    lines = _output_lines(proc)
    procs = []
    try:
        link_line, output = _read_until(lines, "MLflow UI: ")
        grid_line, _ = _read_until(lines, "MLflow UI: ", timeout=30)
        procs = processes_mentioning(str(store.folder))  # MLflow's server and its workers
        yield SimpleNamespace(base=f"http://127.0.0.1:{port}", port=port, output=output,
                              link_line=link_line, grid_line=grid_line, procs=procs)
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


def _assistant_open(driver) -> bool:
    """MLflow's assistant panel is open: its question box shows."""
    return driver.execute_script(
        "return [...document.querySelectorAll('textarea, input')].some(e => "
        "(e.placeholder || '').startsWith('Ask a question') && e.offsetParent !== null)")


# -- the tests -------------------------------------------------------------------------------
def test_ui_prints_its_address_and_the_link_to_the_runs(ui, store):
    assert (f"MLflow UI on {ui.base} (store: {store.uri}); Ctrl-C stops it"
            in ui.output.splitlines())
    runs = f"{ui.base}/#/experiments/{store.experiment_id}/runs?workflowType=machine_learning"
    # the pipeline's runs (those with a stage), newest first, not nested: MLflow's URL state
    assert ui.link_line == (
        f"MLflow UI: {runs}&searchFilter=tags.stage+IS+NOT+NULL&orderByKey=attributes."
        f"%60start_time%60 (the runs of experiment '{EXPERIMENT}': the pipeline's own runs, "
        "newest first; a grid's parent run holds its answer)")
    # and where the grid runs are: the ablation grids' runs by name
    assert ui.grid_line == (
        f"MLflow UI: {runs}&searchFilter=tags.grid+%3D+%27ablations%27+AND+params.setting+IS+"
        "NOT+NULL&orderByKey=tags.%60mlflow.runName%60&orderByAsc=true (the ablation grids' "
        "runs, one per setting and seed; write ceiling or voices for ablations in the search "
        "box for another grid, or clear the search box for every run)")
    assert ui.link_line.split()[2] == pipeline_url(ui.base, store.experiment_id)
    assert ui.grid_line.split()[2] == grid_url(ui.base, store.experiment_id)
    # the server runs the project's app
    cmdlines = command_lines(ui.procs)
    assert "--app-name talkingface" in cmdlines, cmdlines


def test_a_fresh_browser_goes_from_the_front_page_to_the_runs(ui, store, fresh_browser):
    from selenium.webdriver.common.by import By

    with fresh_browser() as driver:
        driver.get(f"{ui.base}/")
        link = wait_until(driver, lambda d: next(
            (a for a in d.find_elements(By.CSS_SELECTOR,
                                        f'a[href="#/experiments/{store.experiment_id}"]')
             if a.text.strip() == EXPERIMENT and a.is_displayed()), False),
            f"link to experiment {EXPERIMENT!r} on the front page")
        assert local_storage(driver, WORKFLOW_KEY) == ML  # set by the app's index.html
        assert local_storage(driver, ASSISTANT_KEY) == "true"  # its assistant panel stays shut
        driver.execute_script("arguments[0].scrollIntoView({block: 'center'})", link)
        link.click()
        assert_runs_table(driver, store.experiment_id, store.runs)
        save_png(driver, _shots(), "ui_landing_from_front_page.png")


def test_the_experiment_link_mlflow_prints_opens_the_runs(ui, store, capsys, fresh_browser):
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
    with fresh_browser() as driver:
        driver.get(printed.group(1))
        assert_runs_table(driver, store.experiment_id, runs)
        assert local_storage(driver, WORKFLOW_KEY) == ML
        save_png(driver, _shots(), "ui_landing_from_mlflow_link.png")


def test_the_link_ui_prints_opens_the_runs(ui, store, fresh_browser):
    printed = ui.link_line.split()[2]
    assert printed == pipeline_url(ui.base, store.experiment_id)
    with fresh_browser() as driver:
        driver.get(printed)
        assert_runs_table(driver, store.experiment_id, store.runs)
        search = driver.find_element("css selector", "input[placeholder*='metrics.rmse']")
        assert search.get_attribute("value") == "tags.stage IS NOT NULL"
        # MLflow's assistant (an LLM chat) does not open by itself over a quarter of the page
        assert not _assistant_open(driver)
    # (as MLflow opens it in a browser that says it has not done so yet)
    with fresh_browser() as driver:
        set_local_storage(driver, f"{ui.base}/health", {ASSISTANT_KEY: "false"})
        driver.get(printed)
        wait_until(driver, _assistant_open, "MLflow's assistant panel, opened by itself")


def test_a_browser_that_chose_genai_keeps_it(ui, store, fresh_browser):
    from selenium.webdriver.common.by import By

    bare = f"{ui.base}/#/experiments/{store.experiment_id}"
    # the user switches to GenAI in the sidebar: MLflow stores the choice, the app keeps it
    with fresh_browser() as driver:
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
        driver.get(pipeline_url(ui.base, store.experiment_id))
        assert_runs_table(driver, store.experiment_id, store.runs)
        assert local_storage(driver, WORKFLOW_KEY) == GENAI
    # a browser that stored "genai" before it ever loaded the UI
    with fresh_browser() as driver:
        set_local_storage(driver, f"{ui.base}/health", {WORKFLOW_KEY: GENAI})
        driver.get(bare)
        assert_genai_overview(driver, store.experiment_id)
        assert local_storage(driver, WORKFLOW_KEY) == GENAI


def test_the_shared_browser_forgets_what_pages_stored(ui, fresh_browser):
    """Each ``with fresh_browser()`` starts as a new profile (tests/browser_session.py): what
    pages of two origins stored (localStorage, a cookie) is gone, and the window has the size
    asked for."""
    origins = [ui.base, ui.base.replace("127.0.0.1", "localhost")]
    with fresh_browser() as driver:
        for origin in origins:
            set_local_storage(driver, f"{origin}/health", {WORKFLOW_KEY: GENAI})
            driver.add_cookie({"name": "seen", "value": "1"})
            assert local_storage(driver, WORKFLOW_KEY) == GENAI
            assert driver.get_cookie("seen")
    with fresh_browser(width=900, height=700) as driver:
        assert driver.current_url == "about:blank"
        assert driver.get_window_size() == {"width": 900, "height": 700}
        for origin in origins:
            driver.get(f"{origin}/health")
            assert local_storage(driver, WORKFLOW_KEY) is None, origin
            assert driver.get_cookies() == [], origin


def test_the_served_page_and_the_lookup_change_nothing(ui, store, capsys):
    """The front page answers 200 with MLflow's page and the app's script first; looking the
    experiment up through the server writes nothing."""
    from mlflow import MlflowClient

    with urllib.request.urlopen(f"{ui.base}/", timeout=30) as r:
        html = r.read().decode()
        assert r.status == 200 and r.headers["Cache-Control"] == "no-cache"
    assert "mlflow" in html.lower()  # MLflow's front page
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


# -- a real ablation grid, as a person reads it ------------------------------------------------
GRID_YAML = ("base:\n  mapping.splits: [utterance]\n  mapping.train.max_epochs: 5\n"
             "children:\n  paper: {}\n  baseline-linear: {mapping.method: linear}\n")
TINY = ["--set", "synth.n_sentences=4", "--set", "synth.workers=2", "--set", "real_speaker.corpus=''"]

# the runs the table lists (a run's name is a link to its page), top to bottom
_RUN_ROWS_JS = """
return [...document.querySelectorAll('a[href*="/runs/"]')]
  .filter(a => a.offsetParent !== null && a.textContent.trim())
  .map(a => [a.textContent.trim(), a.getBoundingClientRect().top])
  .sort((x, y) => x[1] - y[1]).map(x => x[0]);
"""
# the rows of the tables of a run's page (metrics, parameters): their cells' texts
_TABLE_ROWS_JS = """
return [...document.querySelectorAll('[role=row]')]
  .map(r => [...r.querySelectorAll('[role=cell]')].map(c => c.textContent.trim()));
"""
# the rows of the artifact view's table of a .csv file
_CSV_ROWS_JS = """
return [...document.querySelectorAll('tbody tr')].filter(tr => tr.offsetParent !== null)
  .map(tr => [...tr.cells].map(td => td.textContent.trim())).filter(r => r.some(c => c));
"""


def _earlier_replication(client, experiment_id: str) -> None:
    """The runs of a replication as ``replicate`` nests them (made up; started one after
    the other, now): its run, a grid's parent run inside it and one run of that grid."""
    start = int(time.time() * 1000)
    rep = client.create_run(experiment_id, run_name="replication", start_time=start,
                            tags={"stage": "replicate"}).info.run_id
    parent = client.create_run(experiment_id, run_name="ceiling", start_time=start + 1, tags={
        "mlflow.parentRunId": rep, "stage": "ceiling", "grid": "ceiling"}).info.run_id
    child = client.create_run(experiment_id, run_name="ours/2002", start_time=start + 2,
                              tags={"mlflow.parentRunId": parent, "grid": "ceiling"}).info.run_id
    client.log_param(child, "setting", "ours")
    for run_id in (child, parent, rep):
        client.set_terminated(run_id)


@pytest.fixture(scope="module")
def grid(store, tmp_path_factory):
    """``talkingface ablate`` of a tiny real grid (2 settings x 2 seeds) in a working folder of
    its own, logging to ``store`` after an earlier replication's runs: its parent run, its runs
    (name -> id), and the reference and best setting as the parent records them."""
    from mlflow import MlflowClient

    _earlier_replication(MlflowClient(store.uri), store.experiment_id)
    work = tmp_path_factory.mktemp("ui-grid")
    (work / "grid.yaml").write_text(GRID_YAML)
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(work)
        mp.setenv("MLFLOW_TRACKING_URI", store.uri)
        assert main(["ablate", "--grid", "grid.yaml", "--name", "a", *TINY, "--workers", "2",
                     "--seeds", "2"]) == 0
    client = MlflowClient(store.uri)
    parent, = client.search_runs([store.experiment_id], "tags.stage = 'ablate'")
    pid = parent.info.run_id
    children = client.search_runs([store.experiment_id],
                                  f"tags.`mlflow.parentRunId` = '{pid}'")
    assert len(children) == 4
    return SimpleNamespace(parent=parent.info.run_name, parent_id=pid,
                           children={r.info.run_name: r.info.run_id for r in children},
                           settings={"paper", "baseline-linear"},
                           reference=parent.data.params["reference"],
                           best=parent.data.params["best.utterance"])


def _run_rows(driver, want, what: str) -> list[str]:
    """The run names the table lists, once it lists all of ``want``."""
    return wait_until(driver, lambda d: (lambda names: set(want) <= set(names) and names)(
        d.execute_script(_RUN_ROWS_JS)), what)


def test_the_ablation_answer_is_two_clicks_from_the_printed_link(ui, store, grid,
                                                                  fresh_browser):
    from selenium.webdriver.common.by import By

    shots, clicks = _shots(), 0
    with fresh_browser() as driver:
        # landing: the pipeline's runs, newest first, the grid's parent among them, no grid
        # run; one flat list: a replication's grid parent is a row, not folded inside it
        driver.get(ui.link_line.split()[2])
        names = _run_rows(driver, [grid.parent, "ceiling", "replication", *RUNS],
                          "the grid's parent on the landing page")
        assert names[:3] == [grid.parent, "ceiling", "replication"], names
        assert sorted(names[3:]) == sorted(RUNS), names  # no grid run
        save_png(driver, shots, "ui_grid_1_landing.png")

        # click 1: the parent's name opens its page, whose description answers
        link, = [a for a in driver.find_elements(By.CSS_SELECTOR,
                                                 f'a[href*="/runs/{grid.parent_id}"]')
                 if a.text.strip() == grid.parent]
        click(driver, link)
        clicks += 1
        wait_until(driver, lambda d: _tab(d) == (f"/experiments/{store.experiment_id}/runs/"
                                                 f"{grid.parent_id}"), "the parent's page")
        heading = wait_until(driver, lambda d: next(iter(displayed_with_text(
            d, "Description", "h4")), False), "the parent's description")
        driver.execute_script("arguments[0].scrollIntoView({block: 'start'})", heading)
        note = driver.find_element(By.CSS_SELECTOR, "[data-testid=note-editor-preview-content]")
        save_png(driver, shots, "ui_grid_2_parent_description_folded.png")
        # click 2: MLflow shows a long description folded, "Show more" unfolds it
        more = displayed_with_text(driver, "Show more", "button")
        if more:
            click(driver, more[0])
            clicks += 1
            wait_until(driver, lambda d: displayed_with_text(d, "Show less", "button"),
                       "the unfolded description")
            driver.execute_script("arguments[0].scrollIntoView({block: 'start'})", heading)
        assert clicks <= 2
        text = " ".join(note.text.split())
        if grid.best == grid.reference:
            assert f"best: the reference {grid.reference} itself" in text, text
        else:  # the best setting, its difference with its interval, Holm's p and the verdict
            assert re.search(
                rf"best: {re.escape(grid.best)}: R [\d.]+ ± [\d.]+, Δ [+-][\d.]+ ± [\d.]+ "
                r"\([\d.]+ %\), p \(Holm\) \S+: "
                r"(significantly better|no difference from the reference)",
                text), text
        # the table of every setting, rendered as a table, with intervals
        table = note.find_element(By.TAG_NAME, "table")
        assert table.is_displayed()
        header = [th.text.strip() for th in table.find_elements(By.CSS_SELECTOR, "thead th")]
        rows = [[td.text.strip() for td in tr.find_elements(By.TAG_NAME, "td")]
                for tr in table.find_elements(By.CSS_SELECTOR, "tbody tr")]
        assert header[0] == "setting" and "p (Holm)" in header, header
        assert {r[0] for r in rows} == grid.settings, rows
        assert all("±" in r[header.index("test R ± 95 % CI")] for r in rows), rows
        save_png(driver, shots, "ui_grid_3_parent_answer.png")

        # its artifacts: the forest plot and summary.csv at the top, no folder to open
        tab, = displayed_with_text(driver, "Artifacts", "button")
        click(driver, tab)

        def node(name):
            return lambda d: next((e for e in d.find_elements(
                By.CSS_SELECTOR, f'[data-testid=artifact-tree-node][artifact-name="{name}"]')
                if e.is_displayed()), False)

        forest = wait_until(driver, node("forest.png"), "forest.png in the artifacts")
        csv_node = wait_until(driver, node("summary.csv"), "summary.csv in the artifacts")
        click(driver, forest)
        wait_until(driver, lambda d: d.execute_script(
            "return [...document.images].some(i => i.alt === 'forest.png' && "
            "i.naturalWidth > 300 && i.getBoundingClientRect().width > 300)"),
            "the forest plot drawn")
        save_png(driver, shots, "ui_grid_4_forest_png.png")
        click(driver, csv_node)
        csv_rows = wait_until(driver, lambda d: (lambda r: {row[1] for row in r if len(row) > 1}
                                                 >= grid.settings and r)(
            d.execute_script(_CSV_ROWS_JS)), "summary.csv as a table")
        assert all(row[0] == "utterance" for row in csv_rows), csv_rows
        save_png(driver, shots, "ui_grid_5_summary_csv.png")

        # the second printed link: the grid's runs by name; a run's page shows its setting
        driver.get(ui.grid_line.split()[2])
        names = _run_rows(driver, grid.children, "the grid's runs")
        assert names == sorted(grid.children), names
        save_png(driver, shots, "ui_grid_6_grid_runs.png")
        first = names[0]
        link, = [a for a in driver.find_elements(
            By.CSS_SELECTOR, f'a[href*="/runs/{grid.children[first]}"]')
            if a.text.strip() == first]
        click(driver, link)
        setting = first.split("/")[0]
        wait_until(driver, lambda d: ["setting", setting] in d.execute_script(_TABLE_ROWS_JS),
                   f"the parameter setting = {setting} on the page of {first}")
        for h in driver.find_elements(By.XPATH, "//h4[starts-with(normalize-space(.), "
                                      "'Parameters')]"):
            driver.execute_script("arguments[0].scrollIntoView({block: 'start'})", h)
        save_png(driver, shots, "ui_grid_7_grid_run.png")


def test_the_links_searches_are_the_stores(store, grid):
    """What the links put in the search box, MLflow's store answers: the pipeline's runs and
    the grid's parent, or the grid's runs, in the links' order."""
    from mlflow import MlflowClient

    client = MlflowClient(store.uri)

    def names(search, order):
        return [r.info.run_name for r in client.search_runs(
            [store.experiment_id], search, order_by=[order])]

    listed = names(PIPELINE_FILTER, f"{NEWEST_FIRST_FLAT} DESC")
    assert listed[:3] == [grid.parent, "ceiling", "replication"]
    assert sorted(listed[3:]) == sorted(RUNS)
    assert names(grid_filter(), f"{RUN_NAME} ASC") == sorted(grid.children)
    assert names(grid_filter("ceiling"), f"{RUN_NAME} ASC") == ["ours/2002"]
    with pytest.raises(ValueError):
        grid_filter("nope")
    assert runs_url("http://h:1/", "7") == ("http://h:1/#/experiments/7/runs?workflowType="
                                           "machine_learning")
    assert pipeline_url("http://h:1", None) == "http://h:1/"
    assert grid_link_text("http://h:1", None) is None


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
    assert f'"{WORKFLOW_KEY}": "\\"machine_learning\\""' in DEFAULT_WORKFLOW_SCRIPT
    assert f'"{ASSISTANT_KEY}": "true"' in DEFAULT_WORKFLOW_SCRIPT
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
    import talkingface.cli.main as cli
    import talkingface.experiments.mlflow_app as mlflow_app

    monkeypatch.setattr(mlflow_app.importlib.metadata, "entry_points", lambda **kw: [])
    started = []
    monkeypatch.setattr(cli, "serve", lambda cmd: started.append(cmd) or 0)
    assert main(["ui", "--port", str(_free_ports(1)[0])]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: the MLflow app 'talkingface'"), err
    assert "is not registered" in err[0] and "pip install --no-deps -e ." in err[0]
    assert started == []


# -- the lab's server (PostgreSQL) --------------------------------------------------------------
# `talkingface server` prints the same two links, its MLflow accepts the host names it is given,
# and a fresh browser opens its printed link and MLflow's bare link on the runs table: checked
# on the one server of tests/talkingface/test_lab_server.py::
# test_server_makes_its_database_once_reuses_it_and_leaves_nothing_running (one start of the
# command for both; each start costs 10-40 s).
