"""The MLflow UI as this project serves it: MLflow's own server app, opening on the runs table.

MLflow 3.17's UI chooses between its GenAI pages (traces, an "Overview" of token usage) and its
model-training pages (the runs table) by the *workflow type*: the URL's ``workflowType`` query
parameter (``genai`` | ``machine_learning``) when it has one, else the browser's localStorage
key ``mlflow.workflowType_v1`` (a JSON string), else ``genai``. An experiment's
``mlflow.experimentKind`` tag is ignored (a feature flag that is on in 3.17), and an experiment
opened without a tab goes to the Overview (genai) or to the Runs tab (machine_learning). So a
fresh browser lands on an empty "Traces 0" page, even for this project's experiments, which
hold only training runs.

:func:`create_app` is an MLflow app plugin (``mlflow server --app-name talkingface``; entry
point group ``mlflow.app`` in ``pyproject.toml``, as MLflow's own ``basic-auth``): MLflow's app,
whose ``index.html`` sets ``mlflow.workflowType_v1`` to ``"machine_learning"`` in a browser
that has not chosen a workflow type yet. A user who switches to GenAI keeps that choice (the
key is then set, and never overwritten).

:func:`find_experiment` and :func:`runs_url` give the link ``ui`` and ``server`` print: straight
to an experiment's runs (``#/experiments/<id>/runs?workflowType=machine_learning``), which works
in any browser and on any MLflow server of this version, plugin or not.

MLflow is imported here only inside :func:`create_app`, which runs in the server's process.
"""
from __future__ import annotations

import importlib.metadata
import json
import re
import sys
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

from face_model.errors import TalkingFaceError

APP_NAME = "talkingface"  # mlflow server --app-name talkingface
APP_TARGET = "talkingface.mlflow_app:create_app"
WORKFLOW_KEY = "mlflow.workflowType_v1"  # MLflow 3.17's key: "<key>_v<version>", JSON value
DEFAULT_WORKFLOW = "machine_learning"
RUNS_QUERY = f"workflowType={DEFAULT_WORKFLOW}"

# Runs before MLflow's own script (a deferred one): the key is set before the UI reads it.
DEFAULT_WORKFLOW_SCRIPT = (
    "<script>/* talkingface: open on the runs table unless this browser chose a workflow "
    "*/(function(){try{var k=" + json.dumps(WORKFLOW_KEY) + ";if(window.localStorage."
    "getItem(k)===null){window.localStorage.setItem(k," + json.dumps(json.dumps(DEFAULT_WORKFLOW))
    + ")}}catch(e){}})();</script>")


def with_default_workflow(html: str) -> str:
    """``index.html`` with :data:`DEFAULT_WORKFLOW_SCRIPT` first in its ``<head>`` (before
    MLflow's scripts); unchanged if it already has it."""
    if DEFAULT_WORKFLOW_SCRIPT in html:
        return html
    head = re.search(r"<head\b[^>]*>", html, flags=re.IGNORECASE)
    at = head.end() if head else 0
    return html[:at] + DEFAULT_WORKFLOW_SCRIPT + html[at:]


def create_app():
    """The app factory MLflow's server runs (``--app-name talkingface``): MLflow's Flask app
    with the patched ``index.html``, wrapped in MLflow's FastAPI app under uvicorn (MLflow's
    default server), as ``mlflow.server.auth:create_app`` does."""
    from mlflow.environment_variables import _MLFLOW_SGI_NAME
    from mlflow.server import app as flask_app

    index = Path(flask_app.static_folder) / "index.html"
    original = flask_app.view_functions["serve"]  # the route "/" (after a --static-prefix)

    def serve_index():
        try:
            html = index.read_text(encoding="utf-8")
        except OSError:  # a source install without the built UI: MLflow's own message
            return original()
        response = flask_app.response_class(with_default_workflow(html), mimetype="text/html")
        response.headers["Cache-Control"] = "no-cache"
        return response

    flask_app.view_functions["serve"] = serve_index
    if _MLFLOW_SGI_NAME.get() == "uvicorn":
        from mlflow.server.fastapi_app import create_fastapi_app

        return create_fastapi_app(flask_app)
    return flask_app  # --gunicorn-opts or --waitress-opts: MLflow serves the Flask app


def check_installed() -> None:
    """Refuse to start a server when this environment does not register the app (an
    install older than the entry point): one line, instead of MLflow's usage error in a log."""
    found = {e.name: e.value for e in importlib.metadata.entry_points(group="mlflow.app")}
    if found.get(APP_NAME) != APP_TARGET:
        raise TalkingFaceError(
            f"the MLflow app '{APP_NAME}' ({APP_TARGET}) is not registered in the environment "
            f"of {sys.executable} (an install older than it): reinstall the project with "
            f"`{sys.executable} -m pip install --no-deps -e .` in its folder (or `make setup`)")


def find_experiment(base_uri: str, name: str, *, timeout: float = 10.0) -> str | None:
    """The id of the active experiment ``name`` on the MLflow server at ``base_uri``, or None
    when there is none (read only: one GET of MLflow's REST API; nothing is created).

    Raises
    ------
    OSError
        The server does not answer, or answers with an error (``urllib.error.HTTPError``).
    ValueError
        It answers with something that is not MLflow's JSON.
    """
    query = urllib.parse.urlencode({"experiment_name": name})
    url = f"{base_uri.rstrip('/')}/api/2.0/mlflow/experiments/get-by-name?{query}"
    try:
        with urllib.request.urlopen(url, timeout=timeout) as r:
            exp = json.loads(r.read())["experiment"]
    except urllib.error.HTTPError as exc:
        body = exc.read()
        if exc.code == 404 and b"RESOURCE_DOES_NOT_EXIST" in body:
            return None
        raise
    except KeyError:
        raise ValueError(f"{url}: no experiment in the answer") from None
    if exp.get("lifecycle_stage", "active") != "active":
        return None  # deleted: the UI lists it only among deleted experiments
    return str(exp["experiment_id"])


def runs_url(base_uri: str, experiment_id: str | None) -> str:
    """The UI's page of an experiment's runs, in the model-training view whatever the browser
    chose before; the UI's front page when there is no experiment."""
    base = base_uri.rstrip("/")
    if experiment_id is None:
        return f"{base}/"
    return f"{base}/#/experiments/{experiment_id}/runs?{RUNS_QUERY}"


def link_text(base_uri: str, name: str, experiment_id: str | None) -> str:
    """The link as ``ui`` and ``server`` print it, with what it opens."""
    if experiment_id is None:
        return (f"{runs_url(base_uri, None)} (no experiment '{name}' in the store yet: it is "
                "listed there once a command logs its first run)")
    return f"{runs_url(base_uri, experiment_id)} (the runs of experiment '{name}')"
