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

The same ``index.html`` keeps MLflow's assistant panel (an LLM chat, which MLflow 3.17 opens by
itself on a browser's first visit to a local server, over a quarter of the page) closed until the
user opens it with its button: ``mlflow.assistant.fab.autoOpenedOnFirstLoad_v1`` set where unset.

:func:`find_experiment`, :func:`link_text` and :func:`grid_link_text` give the links ``ui`` and
``server`` print, which work in any browser and on any MLflow server of this version, plugin or
not. They use the runs page's own URL state (MLflow 3.17 reads ``searchFilter``, ``orderByKey``,
``orderByAsc``, ``startTime``, ``lifecycleFilter``, ``datasetsFilter`` and
``modelVersionFilter`` from the query of ``#/experiments/<id>/runs``; those it lacks take their
defaults, so the link shows the same list in every browser, whatever it stored before):

- :func:`pipeline_url`, the landing page: the pipeline's own runs (``tags.stage IS NOT NULL``:
  the replicate, train, ablate, speech_eval runs and every grid's parent run, which holds the
  grid's answer), not the hundreds of grid runs below them, as one flat list, newest first. The
  UI nests child runs under their parent, collapsed, only when the table is sorted by its
  "Created" key spelt exactly ``attributes.start_time``; the same order spelt
  ``attributes.`start_time``` is a flat list, so a replication's grid parents are rows of their
  own, one click from the landing page (the sort button reads "Sort: start_time").
- :func:`grid_url`: one grid's runs, one per setting and seed (``tags.grid = 'ablations' AND
  params.setting IS NOT NULL``), sorted by name (``<setting>/<seed>``), also a flat list.

MLflow's saved views (an experiment tag ``mlflow.sharedViewState.<id>`` opened by
``viewStateShareKey=<id>``) could also choose the table's columns, but need a write to the store
and put a "You're viewing a shared view" banner over the table; the links write nothing.

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

from groundwork.errors import TalkingFaceError

APP_NAME = "talkingface"  # mlflow server --app-name talkingface
APP_TARGET = "talkingface.experiments.mlflow_app:create_app"
WORKFLOW_KEY = "mlflow.workflowType_v1"  # MLflow 3.17's key: "<key>_v<version>", JSON value
DEFAULT_WORKFLOW = "machine_learning"
RUNS_QUERY = f"workflowType={DEFAULT_WORKFLOW}"
# set by MLflow 3.17 once it has opened its assistant panel by itself (a JSON boolean)
ASSISTANT_KEY = "mlflow.assistant.fab.autoOpenedOnFirstLoad_v1"
# what index.html stores where the browser has no value yet (raw localStorage strings)
STORAGE_DEFAULTS = {WORKFLOW_KEY: json.dumps(DEFAULT_WORKFLOW), ASSISTANT_KEY: "true"}

# Runs before MLflow's own script (a deferred one): the keys are set before the UI reads them.
DEFAULT_WORKFLOW_SCRIPT = (
    "<script>/* talkingface: open on the runs table unless this browser chose a workflow; "
    "MLflow's assistant panel closed until opened */(function(){try{var d="
    + json.dumps(STORAGE_DEFAULTS) + ";for(var k in d){if(window.localStorage.getItem(k)"
    "===null){window.localStorage.setItem(k,d[k])}}}catch(e){}})();</script>")

# The runs page's URL state (see the module's docstring)
PIPELINE_FILTER = "tags.stage IS NOT NULL"  # the pipeline's runs and the grid parents
NEWEST_FIRST_FLAT = "attributes.`start_time`"  # "Created", without nesting child runs
RUN_NAME = "tags.`mlflow.runName`"  # the UI's "Run Name" sort
GRIDS = ("ablations", "ceiling", "real_steps", "voices")  # the values of the runs' ``grid`` tag


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


def runs_url(base_uri: str, experiment_id: str | None, *, search: str | None = None,
             order_by: str | None = None, ascending: bool | None = None) -> str:
    """The UI's page of an experiment's runs, in the model-training view whatever the browser
    chose before, with the search box holding ``search`` and the table sorted by ``order_by``
    (a key of MLflow's ``order_by``; ``ascending`` or not); the UI's front page when there is
    no experiment."""
    base = base_uri.rstrip("/")
    if experiment_id is None:
        return f"{base}/"
    query = {"searchFilter": search, "orderByKey": order_by,
             "orderByAsc": None if ascending is None else str(bool(ascending)).lower()}
    extra = urllib.parse.urlencode({k: v for k, v in query.items() if v is not None})
    return f"{base}/#/experiments/{experiment_id}/runs?{RUNS_QUERY}" + (
        f"&{extra}" if extra else "")


def pipeline_url(base_uri: str, experiment_id: str | None) -> str:
    """The landing page: the pipeline's own runs and the grid parents, a flat list, newest
    first (the front page when there is no experiment)."""
    return runs_url(base_uri, experiment_id, search=PIPELINE_FILTER, order_by=NEWEST_FIRST_FLAT)


def grid_filter(grid: str = "ablations") -> str:
    """The search for the runs of the grids of kind ``grid``: one per setting and seed."""
    if grid not in GRIDS:
        raise ValueError(f"grid {grid!r}: one of {', '.join(GRIDS)}")
    return f"tags.grid = '{grid}' AND params.setting IS NOT NULL"


def grid_url(base_uri: str, experiment_id: str, grid: str = "ablations") -> str:
    """The runs of the grids of kind ``grid`` (one per setting and seed), sorted by their
    names ``<setting>/<seed>``, a flat list."""
    return runs_url(base_uri, experiment_id, search=grid_filter(grid), order_by=RUN_NAME,
                    ascending=True)


def link_text(base_uri: str, name: str, experiment_id: str | None) -> str:
    """The landing link as ``ui`` and ``server`` print it, with what it opens."""
    if experiment_id is None:
        return (f"{runs_url(base_uri, None)} (no experiment '{name}' in the store yet: it is "
                "listed there once a command logs its first run)")
    return (f"{pipeline_url(base_uri, experiment_id)} (the runs of experiment '{name}': the "
            "pipeline's own runs, newest first; a grid's parent run holds its answer)")


def grid_link_text(base_uri: str, experiment_id: str | None) -> str | None:
    """The second line ``ui`` and ``server`` print: where the grids' own runs are (None when
    there is no experiment)."""
    if experiment_id is None:
        return None
    return (f"{grid_url(base_uri, experiment_id)} (the ablation grids' runs, one per setting "
            "and seed; write ceiling or voices for ablations in the search box for another "
            "grid, or clear the search box for every run)")
