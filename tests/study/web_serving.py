"""The web study's app served as ``talkingface study serve`` serves it (uvicorn on
127.0.0.1, a free port), in a thread, for the tests of tests/study/test_web_*.py."""
from __future__ import annotations

import contextlib
import socket
import threading

import httpx
import uvicorn

from study.web.app import make_app

STOP_WAIT_S = 120.0  # a server that does not stop fails the test instead of hanging it


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def running(web_dir, study):
    """``with running(web_dir, study) as base:`` the base URL of the app serving the built
    experiment in ``web_dir`` and ``study``'s requests, stopped on leaving."""
    port = free_port()
    srv = uvicorn.Server(uvicorn.Config(make_app(web_dir, study), host="127.0.0.1", port=port,
                                        log_level="warning", access_log=False))
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    while not srv.started:
        if not thread.is_alive():
            raise RuntimeError("the study's server did not start")
        thread.join(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        srv.should_exit = True
        thread.join(STOP_WAIT_S)
        assert not thread.is_alive(), "the study's server did not stop"


@contextlib.contextmanager
def client(web_dir, study):
    """``with client(web_dir, study) as c:`` an httpx client on the running app."""
    with running(web_dir, study) as base, httpx.Client(base_url=base, timeout=STOP_WAIT_S) as c:
        yield c
