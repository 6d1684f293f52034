"""The web study's server under load (issue 41): N participants at the same time on 127.0.0.1
(uvicorn serving ``study.web.app``, as ``talkingface study serve`` does), each opening the page
(``POST /api/session``) and posting its 27 judgments one after the other, as fast as the server
answers. Prints the wall time, judgments per second, the latency of the judgment requests (p50,
p99, max: each is appended and fsync'ed to the participant's data file, and its received record
too, before the reply), how many were tried again after a dropped connection, and whether every
judgment was kept in order with one allocation slot per participant.

    python bench/bench_web_load.py [--participants 50] [--json]
"""
from __future__ import annotations

import argparse
import asyncio
import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import httpx  # noqa: E402
import numpy as np  # noqa: E402
from _common import report  # noqa: E402

from study.data import Allocation, data_path, read_rows  # noqa: E402
from study.design import N_TRIALS, RESPONSES, session_trials  # noqa: E402

SEED = 2002
KEYS = dict(zip(RESPONSES, ("n", "h", "s", "u")))
REPO = Path(__file__).resolve().parent.parent
SERVER = """
import json, sys
sys.path.insert(0, {repo!r})
import uvicorn
from study.web.app import make_app
from study.web.server_session import WebStudy
study = WebStudy({study_dir!r}, json.loads({site!r}), study_seed={seed}, n_slots={n})
uvicorn.run(make_app({web!r}, study), host="127.0.0.1", port={port}, log_level="warning",
            access_log=False)
"""
SITE = {"format": 1, "keys": KEYS, "practice": True, "manifest_digest": "", "source": ""}


async def participant(client, pid: str, latencies: list, retries: list) -> None:
    async def post(url, body):
        for attempt in range(5):
            try:
                t0 = time.perf_counter()
                r = await client.post(url, json=body)
                latencies.append(time.perf_counter() - t0) if url.endswith("trial") else None
                return r
            except httpx.TransportError:
                retries.append(url)
                if attempt == 4:
                    raise

    plan = (await post("/api/session", {"params": {"participant": pid}})).json()
    for t in plan["trials"]:
        r = await post("/api/trial", {
            "participant_id": pid, "token": plan["token"], "trial_index": t["trial_index"],
            "stimulus_id": t["stimulus_id"], "response_key": KEYS[RESPONSES[t["trial_index"] % 4]],
            "rt_ms": 700.0, "browser": {"browser": "bench", "fullscreen": True, "focused": True}})
        if r.status_code != 200 and r.json().get("code") != "duplicate":
            raise RuntimeError(r.text)


async def load(base: str, pids: list, latencies: list, retries: list) -> None:
    limits = httpx.Limits(max_connections=len(pids), max_keepalive_connections=len(pids))
    async with httpx.AsyncClient(base_url=base, timeout=120, limits=limits) as client:
        await asyncio.gather(*(participant(client, p, latencies, retries) for p in pids))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--participants", type=int, default=50)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-web-") as tmp:
        study_dir = Path(tmp) / "study_data"
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        # the server in a process of its own, as `study serve` runs (no GIL shared with the
        # participants' client)
        server = subprocess.Popen([sys.executable, "-c", SERVER.format(
            repo=str(REPO), study_dir=str(study_dir), web=tmp, site=json.dumps(SITE),
            seed=SEED, n=args.participants, port=port)])
        try:
            base = f"http://127.0.0.1:{port}"
            for _ in range(600):
                try:
                    httpx.get(base + "/", timeout=1)
                    break
                except httpx.TransportError:
                    time.sleep(0.1)
            pids = [f"B{i:03d}" for i in range(args.participants)]
            latencies, retries = [], []
            t0 = time.perf_counter()
            asyncio.run(load(base, pids, latencies, retries))
            wall = time.perf_counter() - t0
        finally:
            server.terminate()
            server.wait()
        slots = {r["participant_id"]: r for r in Allocation(study_dir).rows()}
        kept = all([int(r["trial_index"]) for r in read_rows(data_path(study_dir, pid))[0]]
                   == list(range(N_TRIALS)) and [r["stimulus_id"] for r in read_rows(
                       data_path(study_dir, pid))[0]] == [t.stimulus_id for t in session_trials(
                           pid, slots[pid]["sequence"], SEED)] for pid in pids)
        lat = np.array(latencies) * 1000
        report({"participants": args.participants, "judgments": len(pids) * N_TRIALS,
                "wall_s": wall, "judgments_per_s": len(pids) * N_TRIALS / wall,
                "judgment_latency_p50_ms": float(np.percentile(lat, 50)),
                "judgment_latency_p99_ms": float(np.percentile(lat, 99)),
                "judgment_latency_max_ms": float(lat.max()),
                "retried_requests": len(retries), "every_judgment_kept_in_order": kept,
                "distinct_slots": len({slots[p]["slot"] for p in pids})}, args.json)


if __name__ == "__main__":
    main()
