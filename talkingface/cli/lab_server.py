"""``talkingface server``: the lab's MLflow tracking server on PostgreSQL, until Ctrl-C.

    talkingface server [--folder mlflow-server] [--host 127.0.0.1] [--port 5000] [--db-port 5433]

It prints the address colleagues log to, and the link to the runs of the project's experiment
in the UI (:mod:`talkingface.experiments.mlflow_app`).

The library is :mod:`talkingface.experiments.server`; this module only parses, prints and waits.
"""
from __future__ import annotations

import signal
from pathlib import Path

from groundwork.errors import TalkingFaceError
from talkingface.config import MlflowConfig
from talkingface.experiments.mlflow_app import find_experiment, grid_link_text, link_text
from talkingface.experiments.server import (DEFAULT_DB_PORT, DEFAULT_FOLDER, DEFAULT_HOST, DEFAULT_PORT,
                                LabServer)


# the experiment the project's commands log to by default (``mlflow.experiment``)
EXPERIMENT = MlflowConfig().experiment


class _Stop(Exception):
    """Ctrl-C or SIGTERM: leave the ``with`` block, which stops everything."""


def _stop_on_signals() -> dict:
    """SIGINT and SIGTERM raise :class:`_Stop` once; later ones are ignored while the server
    stops (a second Ctrl-C must not leave PostgreSQL running). Returns the old handlers."""
    def handler(signum, frame):
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)
        raise _Stop(signal.Signals(signum).name)

    return {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}


def cmd_server(args) -> int:
    server = LabServer(args.folder, host=args.host, port=args.port, db_port=args.db_port,
                       start_timeout=args.start_timeout, allowed_hosts=args.allowed_hosts,
                       jobs=args.jobs,
                       progress=lambda line: print(f"server: {line}", flush=True))
    server.check()  # bad input is refused before any signal handler is changed
    old = _stop_on_signals()
    try:
        with server:
            print(_banner(server, _ui_link(server)), flush=True)
            code = server.wait()
        raise TalkingFaceError(f"the MLflow server stopped by itself (exit status {code}); "
                               f"its log: {server.logs / 'mlflow.log'}")
    except _Stop as why:
        print(f"server: stopped ({why}): the MLflow server and PostgreSQL are down; the data "
              f"stays in {server.folder}", flush=True)
        return 0
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


def _ui_link(server: LabServer) -> tuple[str, str | None]:
    """The UI's links: to the pipeline's runs of the project's experiment (the default
    ``mlflow.experiment``), looked up through the server (read only), and to its grids' runs;
    its front page (and None) when the store has no such experiment yet (said so), or when the
    lookup gets no answer."""
    try:
        found = find_experiment(server.uri, EXPERIMENT, timeout=30)
    except (OSError, ValueError):
        return f"{server.share_uri}/", None
    return (link_text(server.share_uri, EXPERIMENT, found),
            grid_link_text(server.share_uri, found))


def _banner(server: LabServer, ui: tuple[str, str | None] | None = None) -> str:
    link, grids = ui or (server.share_uri, None)
    state = ("made the database" if server.created else "reusing the database")
    lines = [
        f"server: up on {server.uri} ({state} in {server.pgdata}, PostgreSQL on "
        f"127.0.0.1:{server.db_port}; artifacts in {server.artifacts}; logs in {server.logs})",
        "server: colleagues log to it with",
        f"  export MLFLOW_TRACKING_URI={server.share_uri}",
        f"  or: talkingface ... --set mlflow.uri={server.share_uri}",
    ]
    lines.append(f"server: its UI: {link}; Ctrl-C here stops the server and its database")
    if grids:
        lines.append(f"server: its grids' runs: {grids}")
    if server.host in ("127.0.0.1", "localhost", "::1"):
        lines.insert(4, "server: only this machine can reach it; --host ADDRESS (this "
                     "machine's address on the lab's network) shares it")
    return "\n".join(lines)


def add_parser(sub) -> None:
    """Register ``talkingface server`` on the top-level sub-command parsers."""
    s = sub.add_parser("server", help="start the lab's MLflow tracking server (PostgreSQL "
                       "database and artifact store in one folder) until Ctrl-C")
    s.add_argument("--folder", type=Path, default=DEFAULT_FOLDER,
                   help="the server's folder: pgdata/ (the database), artifacts/, logs/ "
                   f"(default: ./{DEFAULT_FOLDER}; made on the first start, reused after)")
    s.add_argument("--host", default=DEFAULT_HOST,
                   help="address to listen on (default: 127.0.0.1, this machine only; this "
                   "machine's LAN address, or 0.0.0.0, to share it)")
    s.add_argument("--port", type=int, default=DEFAULT_PORT,
                   help=f"the server's port (default: {DEFAULT_PORT})")
    s.add_argument("--db-port", type=int, default=DEFAULT_DB_PORT,
                   help=f"PostgreSQL's port, on 127.0.0.1 only (default: {DEFAULT_DB_PORT})")
    s.add_argument("--allowed-hosts", help="host names colleagues reach the server by, when "
                   "not an IP address (mlflow server --allowed-hosts; default: localhost and "
                   "private IPs)")
    s.add_argument("--jobs", action="store_true", help="also run MLflow's job runner (its "
                   "GenAI features: LLM judges, prompt optimisation; ~8 more processes)")
    s.add_argument("--start-timeout", type=float, default=300.0,
                   help="seconds to wait for the server to answer (default: 300)")
    s.set_defaults(func=cmd_server)
