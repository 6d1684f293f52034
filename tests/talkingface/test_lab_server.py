"""The lab's tracking server (``talkingface server``): PostgreSQL and MLflow from one folder, made
on the first start and reused after, nothing left running after a stop, the links it prints
opening on the runs table in a real (headless) browser; bad input refused in one line; and an
ablation logged to it through the project's own command, compared in the MLflow UI in that
browser (one Chromium per test session, in a fresh profile's state for each use:
tests/browser_session.py).

Everything is started by the tests themselves, on free ports: ``make test`` installs PostgreSQL,
Chromium, chromedriver, psycopg and selenium (``bash tools/setup.sh test``).
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import queue
import shutil
import signal
import socket
import stat
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import psutil
import pytest

from groundwork.errors import TalkingFaceError
from talkingface.cli.main import main
from talkingface.cli.lab_server import EXPERIMENT
from talkingface.experiments.mlflow_app import (WORKFLOW_KEY, grid_link_text, link_text,
                                                pipeline_url)
from talkingface.experiments.server import PG_SEARCH, lab_server, postgres_bin, warn_trusting
from tests.talkingface.browser import (alive, alive_processes, command_lines, local_storage,
                                       processes_mentioning, save_png, wait_gone)
from tests.talkingface.test_ui_landing import KIND, ML, RUNS, STAGE, assert_runs_table

METRIC = "test.utterance.R"


def _free_ports(n: int) -> list[int]:
    """``n`` different TCP ports nothing listens on (bound at once, so they differ)."""
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


@pytest.fixture
def lab_folder():
    """A server folder the ``postgres`` user can reach (pytest's own tmp folders sit under a
    folder of mode 700, which PostgreSQL, run as ``postgres`` when we are root, cannot enter)."""
    parent = Path(tempfile.mkdtemp(prefix="talkingface-lab-"))
    os.chmod(parent, 0o755)
    try:
        yield parent / "server"
    finally:
        # after a failed test only: end what is still running of this folder's server
        for p in alive_processes(processes_mentioning(str(parent))):
            with contextlib.suppress(psutil.Error):
                p.kill()
        shutil.rmtree(parent, ignore_errors=True)


def _one_error_line(capsys) -> str:
    out = capsys.readouterr()
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), out.err
    assert "Traceback" not in out.err
    return lines[0]


def test_server_makes_its_database_once_reuses_it_and_leaves_nothing_running(
        lab_folder, capsys, fresh_browser):
    """The server's whole life on one folder: made on the first start (PostgreSQL with a
    password, MLflow uploading into the folder), a second server refused, everything stopped;
    then the command a lab runs reuses the database, prints the links to the project's runs
    (the landing checks of tests/talkingface/test_ui_landing.py: a fresh browser opens its
    printed link and MLflow's bare link on the runs table), accepts the host names it was
    given and no others, and stops on SIGTERM with nothing left running. (One start of each
    kind for all of it: each costs 10-40 s on 2 cores.)"""
    from mlflow import MlflowClient

    port, db_port = _free_ports(2)
    with lab_server(lab_folder, port=port, db_port=db_port) as server:
        assert server.created
        assert (lab_folder / "pgdata" / "PG_VERSION").is_file()
        assert server.uri == f"http://127.0.0.1:{port}"
        # every process of the server: its command line names the folder (postgres -D
        # DIR/pgdata, mlflow --artifacts-destination DIR/artifacts), or it descends from one
        procs = processes_mentioning(str(lab_folder))
        cmdlines = command_lines(procs)
        assert "postgres" in cmdlines and "mlflow" in cmdlines and "uvicorn" in cmdlines
        assert not _port_free(port) and not _port_free(db_port)
        # the database asks for the password, which only the folder's owner can read
        password = lab_folder / "db-password"
        assert stat.S_IMODE(password.stat().st_mode) == 0o600
        assert "password" not in cmdlines and password.read_text().strip() not in cmdlines
        psql = [str(postgres_bin() / "psql"), "-X", "-h", "127.0.0.1", "-p", str(db_port),
                "-U", "talkingface", "-d", "mlflow", "-tAc", "SELECT 1", "-w"]
        env = {k: v for k, v in os.environ.items() if k != "PGPASSWORD"}
        refused = subprocess.run(psql, env=env, capture_output=True, text=True)
        assert refused.returncode != 0 and "password" in refused.stderr, refused
        allowed = subprocess.run(psql, env={**env, "PGPASSWORD": password.read_text().strip()},
                                 capture_output=True, text=True)
        assert allowed.stdout.strip() == "1", allowed
        assert not warn_trusting(lab_folder / "pgdata")  # no line of it trusts anyone

        # the project's experiment (tagged as model training) with two of the pipeline's runs
        # (tagged with their stage), and a run with a file
        client = MlflowClient(server.uri)
        exp = client.create_experiment(EXPERIMENT, tags=KIND)
        runs = {}
        for name in RUNS:
            landing = client.create_run(exp, run_name=name, tags=STAGE)
            client.log_metric(landing.info.run_id, METRIC, 0.5)
            client.set_terminated(landing.info.run_id)
            runs[name] = landing.info.run_id
        run = client.create_run(exp, run_name="before-restart")
        client.log_metric(run.info.run_id, METRIC, 0.625)
        note = lab_folder.parent / "note.txt"
        note.write_text("kept by the server\n")
        client.log_artifact(run.info.run_id, str(note))
        client.set_terminated(run.info.run_id)
        # clients upload through the server, into the folder's artifact store
        assert client.get_experiment(exp).artifact_location.startswith("mlflow-artifacts:")
        assert [p.read_text() for p in (lab_folder / "artifacts").rglob("note.txt")] == \
            ["kept by the server\n"]
        # a second server on the same folder is refused, and leaves the first one alone
        other, other_db = _free_ports(2)
        postmaster = (lab_folder / "pgdata" / "postmaster.pid").read_text().split()[0]
        capsys.readouterr()
        assert main(["server", "--folder", str(lab_folder), "--port", str(other),
                     "--db-port", str(other_db)]) == 2
        assert f"--folder {lab_folder}: its PostgreSQL is already running" in \
            _one_error_line(capsys)
        assert client.get_run(run.info.run_id).data.metrics[METRIC] == 0.625
        assert (lab_folder / "pgdata" / "postmaster.pid").read_text().split()[0] == postmaster
        assert alive([psutil.Process(int(postmaster))])
    # the context manager stopped everything it started, and freed both ports
    assert wait_gone(procs) == []
    assert alive(processes_mentioning(str(lab_folder))) == []
    assert _port_free(port) and _port_free(db_port)

    # again, as the command a lab runs (with MLflow's job runner too: more processes to stop;
    # with a host name colleagues use), until SIGTERM, as a process manager stops it
    env = {**_env_with_repo(), "HOME": str(lab_folder.parent)}
    env.pop("MLFLOW_TRACKING_URI", None)
    proc = subprocess.Popen([sys.executable, "-m", "talkingface", "server", "--folder",
                             str(lab_folder), "--port", str(port), "--db-port", str(db_port),
                             "--jobs", "--allowed-hosts", "mlflow.lab.example"],
                            cwd=lab_folder.parent, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    lines = _output_lines(proc)
    try:
        banner = _read_until(lines, "server: its UI:")
        line = banner.splitlines()[-1]
        grids = _read_until(lines, "server: its grids' runs:", timeout=30).splitlines()[-1]
        base = f"http://127.0.0.1:{port}"
        assert "reusing the database" in banner  # the same cluster and database
        assert f"export MLFLOW_TRACKING_URI={base}" in banner
        assert f"--set mlflow.uri={base}" in banner
        # the link to the project's runs, and the one to its grids' runs
        assert line == (f"server: its UI: {pipeline_url(base, exp)} (the runs of experiment "
                        f"'{EXPERIMENT}': the pipeline's own runs, newest first; a grid's "
                        "parent run holds its answer); Ctrl-C here stops the server and its "
                        "database")
        assert grids == f"server: its grids' runs: {grid_link_text(base, exp)}"
        client = MlflowClient(base)
        again = client.get_run(run.info.run_id)
        assert again.info.run_name == "before-restart"
        assert again.data.metrics[METRIC] == 0.625
        assert [a.path for a in client.list_artifacts(run.info.run_id)] == ["note.txt"]
        procs = processes_mentioning(str(lab_folder))
        cmdlines = command_lines(procs)
        assert "mlflow.server.jobs" in cmdlines and "--app-name talkingface" in cmdlines
        # the names listed are accepted (with the port a browser adds), others are not
        api = f"{base}/api/2.0/mlflow/experiments/search?max_results=1"
        assert _get(api, f"mlflow.lab.example:{port}") == 200
        assert _get(api, "mlflow.lab.example") == 200
        assert _get(api, f"127.0.0.1:{port}") == 200
        assert _get(api, f"elsewhere.example:{port}") == 403
        with fresh_browser() as driver:
            driver.get(line.split()[3])  # the printed link
            assert_runs_table(driver, exp, runs)
            assert local_storage(driver, WORKFLOW_KEY) == ML
        with fresh_browser() as driver:
            driver.get(f"{base}/#/experiments/{exp}")  # the link MLflow's client prints
            assert_runs_table(driver, exp, runs)
            save_png(driver, _shots(lab_folder.parent), "ui_landing_lab_server.png")
        proc.send_signal(signal.SIGTERM)
        assert _read_until(lines, "server: stopped (SIGTERM)", timeout=180)
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


def _get(url: str, host: str) -> int:
    """The HTTP status of a GET of ``url`` sent with the Host header ``host``."""
    try:
        with urllib.request.urlopen(urllib.request.Request(url, headers={"Host": host}),
                                    timeout=30) as r:
            return r.status
    except urllib.error.HTTPError as exc:
        return exc.code


def _shots(default: Path) -> Path:
    return Path(os.environ.get("TALKINGFACE_TEST_ARTIFACTS") or default)


def _env_with_repo() -> dict:
    repo = str(Path(__file__).resolve().parents[2])
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [
        repo, os.environ.get("PYTHONPATH")]))}


def _output_lines(proc) -> queue.Queue:
    """The lines of the process's output, as a reader thread receives them ("" at its end)."""
    lines: queue.Queue = queue.Queue()

    def read():
        for line in iter(proc.stdout.readline, ""):
            lines.put(line)
        lines.put("")

    threading.Thread(target=read, daemon=True).start()
    return lines


def _read_until(lines: queue.Queue, marker: str, timeout: float = 300.0) -> str:
    """The output up to and including the line that starts with ``marker`` (a silent process
    fails the test after ``timeout`` s instead of hanging it)."""
    seen, deadline = [], time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=1.0)
        except queue.Empty:
            continue
        if not line:
            break  # the process ended
        seen.append(line)
        if line.startswith(marker):
            return "".join(seen)
    raise AssertionError(f"no line {marker!r} from the server; its output: {''.join(seen)}")


def test_bad_input_is_one_line_and_starts_nothing(lab_folder, tmp_path, capsys):
    port, db_port = _free_ports(2)
    with socket.socket() as held:
        held.bind(("127.0.0.1", port))
        held.listen()
        assert main(["server", "--folder", str(lab_folder), "--port", str(port),
                     "--db-port", str(db_port)]) == 2
        line = _one_error_line(capsys)
        assert f"--port {port}: port {port} on 127.0.0.1 is already in use" in line
        assert "choose a free port with --port" in line
        # the database port is checked the same way
        assert main(["server", "--folder", str(lab_folder), "--port", str(db_port),
                     "--db-port", str(port)]) == 2
        assert f"--db-port {port}: port {port} on 127.0.0.1 is already in use" in \
            _one_error_line(capsys)
    assert not lab_folder.exists()  # refused before anything was made

    for args, message in [
            (["--port", "70000"], "--port 70000: allowed: a TCP port from 1 to 65535"),
            (["--port", "0"], "--port 0: allowed: a TCP port from 1 to 65535"),
            (["--db-port", "-1"], "--db-port -1: allowed: a TCP port from 1 to 65535"),
            (["--port", str(port), "--db-port", str(port)],
             f"--port and --db-port are both {port}"),
            (["--host", "192.0.2.222", "--port", str(port)], "--host 192.0.2.222: cannot "
             "listen there")]:
        assert main(["server", "--folder", str(lab_folder), *args]) == 2, args
        assert message in _one_error_line(capsys)

    a_file = tmp_path / "not-a-folder"
    a_file.write_text("x")
    assert main(["server", "--folder", str(a_file), "--port", str(port),
                 "--db-port", str(db_port)]) == 2
    assert f"--folder {a_file}: is a file; allowed: a folder" in _one_error_line(capsys)
    assert not lab_folder.exists()


def test_postgres_that_cannot_start_is_reported_with_its_log(lab_folder, capsys):
    # a cluster folder whose files are gone: PostgreSQL refuses it, and says why in its log
    (lab_folder / "pgdata").mkdir(parents=True)
    version = postgres_bin().parent.name
    (lab_folder / "pgdata" / "PG_VERSION").write_text(f"{version}\n")
    port, db_port = _free_ports(2)
    assert main(["server", "--folder", str(lab_folder), "--port", str(port),
                 "--db-port", str(db_port)]) == 2
    line = _one_error_line(capsys)
    log = lab_folder / "logs" / "postgres.log"
    assert f"PostgreSQL did not start on 127.0.0.1:{db_port}" in line
    assert f"the last lines of its log {log}" in line and "postgresql.conf" in line
    assert alive(processes_mentioning(str(lab_folder))) == []
    assert _port_free(port) and _port_free(db_port)


def test_postgres_programs_are_found_by_version_or_named_as_missing(tmp_path, monkeypatch):
    for v in ("9", "15", "16"):
        d = tmp_path / "pg" / v / "bin"
        d.mkdir(parents=True)
        for prog in ("initdb", "pg_ctl"):
            (d / prog).write_text("#!/bin/sh\n")
            (d / prog).chmod(stat.S_IRWXU)
    search = str(tmp_path / "pg" / "*" / "bin")
    assert postgres_bin(search=search) == tmp_path / "pg" / "16" / "bin"  # 16 > 9 as numbers
    assert postgres_bin("15", search=search) == tmp_path / "pg" / "15" / "bin"
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    with pytest.raises(TalkingFaceError, match=r"made by PostgreSQL 14.*found: 15, 16, 9"):
        postgres_bin("14", search=search)
    with pytest.raises(TalkingFaceError, match=r"were not found in .*nowhere.* or on PATH: run "
                       r"`make server` or `bash tools/setup.sh server`"):
        postgres_bin(search=str(tmp_path / "nowhere" / "*" / "bin"))
    monkeypatch.undo()
    assert postgres_bin(search=PG_SEARCH).joinpath("initdb").is_file()  # the real one


def format_metric(x: float) -> str:
    """A metric as the MLflow UI's compare page prints it (``Utils.formatMetric`` of MLflow
    3.17's JavaScript: 3 decimals below 10, 2 below 100, 1 above, exponential below 1e-3)."""
    if x == 0:
        return "0"
    if abs(x) < 1e-3:
        mantissa, exp = f"{x:.3e}".split("e")
        return f"{mantissa}e{int(exp):+d}"
    digits = 3 if abs(x) < 10 else 2 if abs(x) < 100 else 1
    r = math.floor(x * 10 ** digits + 0.5) / 10 ** digits  # JavaScript's Math.round
    return str(int(r)) if r == int(r) else repr(r)


def test_a_cluster_that_trusts_local_users_is_warned_about(tmp_path, capsys):
    hba = tmp_path / "pg_hba.conf"
    hba.write_text("# local all all trust   (a comment)\n"
                   "host all all 127.0.0.1/32 scram-sha-256\n")
    assert not warn_trusting(tmp_path) and capsys.readouterr().err == ""
    hba.write_text("local all all trust\nhost all all 127.0.0.1/32 trust # made by initdb\n")
    assert warn_trusting(tmp_path)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"warning: {hba} lets every user")
    assert not warn_trusting(tmp_path / "missing")


def test_format_metric_follows_the_ui():
    assert [format_metric(x) for x in (0.0, 0.61234, 0.5, 1.0, 12.345, 123.45, 0.0001234)] == \
        ["0", "0.612", "0.5", "1", "12.35", "123.5", "1.234e-4"]


# The compare page's metrics table (MLflow 3.17) is two virtualised grids scrolled together:
# metric names (links titled "Plot chart") and the runs' values, cells placed at the same
# ``top`` (one row each) and, for values, one ``left`` per run in the page's column order.
_METRIC_ROW_JS = """
const grids = [...document.querySelectorAll('[role=grid]')];
const names = grids.find(g => g.querySelector('a[title="Plot chart"]'));
if (!names) return null;
const values = grids.find(g => g !== names && g.scrollHeight === names.scrollHeight);
const link = [...names.querySelectorAll('a[title="Plot chart"]')]
  .find(a => a.textContent.trim() === arguments[0]);
if (!link || !values) return {grid: values || names, top: null, cells: []};
const top = link.closest('[style*="top"]').style.top;
const cells = [...values.querySelectorAll('[style*="top"]')]
  .filter(c => c.style.position === 'absolute' && c.style.top === top)
  .sort((x, y) => parseFloat(x.style.left) - parseFloat(y.style.left));
return {grid: values, top: parseFloat(top), cells: cells.map(c => c.textContent.trim())};
"""


def _compare_page(driver, uri: str, run_ids: list, experiment_id: str, wait_s: float = 120):
    """Open the compare-runs page of ``run_ids`` (the UI's own route: ``#/compare-runs?runs=
    [...]&experiments=[...]``) and wait until it shows them; ``(run names, values of METRIC)``
    as the page lists them, one per run, in its column order."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.actions.wheel_input import ScrollOrigin
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    driver.get(f"{uri}/#/compare-runs?runs={json.dumps(run_ids)}"
               f"&experiments={json.dumps([experiment_id])}")
    wait = WebDriverWait(driver, wait_s, poll_frequency=0.5)

    def run_names(d):
        cells = d.find_elements(By.XPATH, "//tr[.//*[normalize-space(text())='Run Name:']]/td")
        names = [c.text.strip() for c in cells]
        return names if len(names) == len(run_ids) and all(names) else False

    def metric_row(d):
        row = d.execute_script(_METRIC_ROW_JS, METRIC)
        if row and row["top"] is None:  # not rendered yet: scroll the table on, as a user would
            d.execute_script("arguments[0].scrollIntoView({block: 'center'})", row["grid"])
            ActionChains(d).scroll_from_origin(ScrollOrigin.from_element(row["grid"]), 0,
                                               120).perform()
        return row if row and len(row["cells"]) == len(run_ids) else False

    names = wait.until(run_names)
    row = wait.until(metric_row)
    # the row in view, for the screenshot: the names follow the values' scroll position one
    # scroll event late, so the last step is a small one
    driver.execute_script("arguments[0].scrollIntoView({block: 'center'})", row["grid"])
    scrolled = driver.execute_script("return arguments[0].scrollTop", row["grid"])
    origin = ScrollOrigin.from_element(row["grid"])
    ActionChains(driver).scroll_from_origin(origin, 0, int(row["top"] - scrolled) - 1).perform()
    ActionChains(driver).scroll_from_origin(origin, 0, 1).perform()
    return names, row["cells"]


def test_an_ablation_logged_to_the_server_compares_in_the_browser(lab_folder, tmp_path,
                                                                  monkeypatch, capsys,
                                                                  fresh_browser):
    from mlflow import MlflowClient
    from PIL import Image

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    grid = tmp_path / "grid.yaml"
    grid.write_text("base:\n  mapping.splits: [utterance]\n  mapping.baselines: []\n"
                    "  mapping.train.max_epochs: 20\n"
                    "children:\n  paper: {}\n  classes-1: {mapping.n_classes: 1}\n")
    port, db_port = _free_ports(2)
    shots = Path(os.environ.get("TALKINGFACE_TEST_ARTIFACTS") or tmp_path)
    with lab_server(lab_folder, port=port, db_port=db_port) as server:
        assert main(["ablate", "--name", "tiny", "--grid", str(grid),
                     "--set", "synth.n_sentences=3", "--set", "synth.workers=2",
                     "--set", f"mlflow.uri={server.uri}", "--workers", "2",
                     "--seeds", "2", "--scheduler", "local"]) == 0, capsys.readouterr().err
        client = MlflowClient(server.uri)
        exp = client.get_experiment_by_name("talkingface")
        parents = client.search_runs([exp.experiment_id], "tags.stage = 'ablate'")
        assert len(parents) == 1
        children = client.search_runs(
            [exp.experiment_id], f"tags.mlflow.parentRunId = '{parents[0].info.run_id}'",
            order_by=["attributes.run_name ASC"])
        # a Dask LocalCluster of 2 workers ran 2 settings x 2 seeds; each task logged its
        # child run to the server, under the parent, once
        assert sorted((c.data.tags["ablation.setting"], c.data.tags["ablation.seed"])
                      for c in children) == [("classes-1", "2002"), ("classes-1", "3002"),
                                             ("paper", "2002"), ("paper", "3002")]
        assert {c.info.status for c in children} == {"FINISHED"}
        # named by setting and seed, so the compare page tells the replicates apart
        assert [c.info.run_name for c in children] == [
            "classes-1/2002", "classes-1/3002", "paper/2002", "paper/3002"]
        # the children's files went through the server into the folder's artifact store
        assert len(list((lab_folder / "artifacts").rglob("tables.csv"))) == len(children)

        ids = [c.info.run_id for c in children]
        with fresh_browser(width=700 + 330 * len(ids), height=1000) as driver:
            names, values = _compare_page(driver, server.uri, ids, exp.experiment_id)
            shot = save_png(driver, shots, "lab_server_compare_runs.png")
        assert names == [c.info.run_name for c in children]
        assert values == [format_metric(c.data.metrics[METRIC]) for c in children]
    with Image.open(shot) as img:
        img.load()
        assert img.format == "PNG" and img.width >= 700 and img.height >= 500
        assert len(img.convert("RGB").getcolors(maxcolors=1 << 20) or ()) > 50  # not blank
