"""The web study's server under load (issue 41): 50 simulated participants at the same time,
over real sockets on 127.0.0.1 (uvicorn, as ``talkingface study serve`` runs it), each opening
the page and posting its 27 judgments as fast as the server answers. Every judgment is kept,
in order, and no slot of the allocation list is given twice.

Each request has a time-out (a server that stops answering fails the test instead of hanging
it); how long the whole takes is not asserted (the machines are shared)."""
from __future__ import annotations

import asyncio
import collections
import csv

import httpx
import pytest

from study.data import Allocation, data_path, read_rows
from study.design import N_TRIALS, RESPONSES, session_trials
from study.web.server_session import WebStudy
from tests.study import web_serving
from tests.study.test_web_server import KEYS, MEASURES, SEED, SITE

N_PARTICIPANTS = 50
REQUEST_TIMEOUT_S = 120.0
MAX_TRIES = 5


@pytest.fixture
def server(tmp_path):
    """``(base url, study folder)`` of a running server, stopped afterwards."""
    study_dir = tmp_path / "study_data"
    study = WebStudy(study_dir, SITE, study_seed=SEED, n_slots=N_PARTICIPANTS + 2)
    with web_serving.running(tmp_path, study) as base:
        yield base, study_dir


async def post(client: httpx.AsyncClient, url: str, body: dict) -> httpx.Response:
    """POST as the page does: a connection the server closed (a kept-alive one it timed out as
    the request left) is tried again, and a judgment that was saved before the reply was lost
    comes back as 409 ``duplicate``, which counts as saved."""
    for attempt in range(MAX_TRIES):
        try:
            return await client.post(url, json=body)
        except httpx.TransportError:
            if attempt == MAX_TRIES - 1:
                raise
    raise AssertionError("unreachable")


async def participant(client: httpx.AsyncClient, pid: str) -> list[int]:
    r = await post(client, "/api/session", {"params": {"participant": pid}})
    r.raise_for_status()
    plan, saved = r.json(), []
    for t in plan["trials"]:
        k = t["trial_index"]
        r = await post(client, "/api/trial", {
            "participant_id": pid, "token": plan["token"], "trial_index": k,
            "stimulus_id": t["stimulus_id"], "response_key": KEYS[RESPONSES[k % 4]],
            "rt_ms": 500.0 + k, "browser": MEASURES})
        if r.status_code == 409 and r.json().get("code") == "duplicate":
            saved.append(k)
            continue
        r.raise_for_status()
        saved.append(r.json()["saved"])
    return saved


async def all_participants(base: str, pids: list[str]) -> list[list[int]]:
    limits = httpx.Limits(max_connections=len(pids), max_keepalive_connections=len(pids))
    async with httpx.AsyncClient(base_url=base, timeout=REQUEST_TIMEOUT_S,
                                 limits=limits) as client:
        return await asyncio.gather(*(participant(client, p) for p in pids))


def test_fifty_participants_at_once_lose_no_trial_and_share_no_slot(server):
    base, study_dir = server
    pids = [f"L{i:02d}" for i in range(N_PARTICIPANTS)]
    saved = asyncio.run(all_participants(base, pids))
    assert saved == [list(range(N_TRIALS))] * N_PARTICIPANTS
    rows = Allocation(study_dir).rows()
    held = [r for r in rows if r["participant_id"]]
    assert sorted(r["participant_id"] for r in held) == pids  # one slot each
    assert len({r["slot"] for r in held}) == N_PARTICIPANTS
    assert {r["status"] for r in held} == {"complete"}
    assert [r["status"] for r in rows if not r["participant_id"]] == ["free", "free"]
    with open(study_dir / "allocation_log.csv", newline="") as f:
        events = collections.Counter((e["event"], e["participant_id"]) for e in csv.DictReader(f))
    assert all(events[("assigned", p)] == 1 for p in pids)
    by_pid = {r["participant_id"]: r for r in held}
    for pid in pids:
        data = read_rows(data_path(study_dir, pid))[0]
        trials = session_trials(pid, by_pid[pid]["sequence"], SEED)
        assert [(int(r["trial_index"]), r["stimulus_id"], r["response"]) for r in data] == \
            [(t.trial_index, t.stimulus_id, RESPONSES[t.trial_index % 4]) for t in trials]
        assert {r["participant_id"] for r in data} == {pid}
