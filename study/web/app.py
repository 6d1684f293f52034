"""The web study's server: the built experiment's files and the two requests of the contract
(``POST /api/session``, ``POST /api/trial``), as an ASGI app (Starlette) that uvicorn serves
(``talkingface study serve``).

Every request body is read up to :data:`MAX_BODY` bytes (a larger one is refused with 413
before it is parsed), must be a JSON object, and goes to :class:`study.web.server_session.
WebStudy` in a worker thread (its file locks and fsyncs never block the event loop). A refusal
is ``{"error": "<one line>"}`` with its status (and ``"code"`` where the page acts on it); no
refused request changes a file. API replies are never cached.
"""
from __future__ import annotations

import json
from pathlib import Path

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import JSONResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from groundwork.errors import ParameterError
from study.web.server_session import WebError, WebStudy

MAX_BODY = 16 * 1024  # bytes: a judgment's body is well under 2 KB
NO_STORE = {"Cache-Control": "no-store"}


def _error(status: int, message: str, code: str | None = None) -> JSONResponse:
    body = {"error": message}
    if code:
        body["code"] = code
    return JSONResponse(body, status_code=status, headers=NO_STORE)


async def read_json(request: Request) -> dict:
    """The request's JSON object, read up to :data:`MAX_BODY` bytes."""
    declared = request.headers.get("content-length")
    if declared is not None and (not declared.isdigit() or int(declared) > MAX_BODY):
        raise WebError(413, f"the body is {declared} bytes; allowed: at most {MAX_BODY}")
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > MAX_BODY:
            raise WebError(413, f"the body is over {MAX_BODY} bytes; allowed: at most "
                                f"{MAX_BODY}")
        chunks.append(chunk)
    try:
        body = json.loads(b"".join(chunks).decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise WebError(400, f"the body is not JSON ({type(exc).__name__}: "
                            f"{str(exc).splitlines()[0][:120]})") from None
    if not isinstance(body, dict):
        raise WebError(400, "the body must be a JSON object")
    return body


def make_app(web_dir, study: WebStudy) -> Starlette:
    """The app serving the built experiment in ``web_dir`` and ``study``'s two requests."""

    def endpoint(method):
        async def handle(request: Request) -> JSONResponse:
            try:
                body = await read_json(request)
                reply = await run_in_threadpool(method, body)
            except WebError as exc:
                return _error(exc.status, str(exc), exc.code)
            except ParameterError as exc:  # a rule of study.data (the data file, the list)
                return _error(409, str(exc))
            return JSONResponse(reply, headers=NO_STORE)
        return handle

    routes = [Route("/api/session", endpoint(study.start), methods=["POST"]),
              Route("/api/trial", endpoint(study.record), methods=["POST"]),
              Mount("/", StaticFiles(directory=str(Path(web_dir)), html=True))]
    return Starlette(routes=routes)
