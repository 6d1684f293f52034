"""The web study's server (issue 41): the lab's rules over HTTP. A participant's plan is the
lab's trial order and slot; every judgment is kept as it is answered; a closed page continues
at the next trial; bad requests change no file; a completed participant is not run again;
another participant's data can be neither read nor written.

The requests go over a socket to the app as ``talkingface study serve`` runs it
(tests/study/web_serving.py); the load test (50 participants at once) is in
tests/study/test_web_load.py and a whole session in a browser in tests/study/test_web_browser.py."""
from __future__ import annotations

import contextlib
import hashlib
import json

import pytest

from study.data import Allocation, data_path, read_rows, sidecar_path
from study.design import N_TRIALS, RESPONSES, allocation_sequences, session_trials
from study.web.app import MAX_BODY
from study.web.server_session import WebStudy, token_digest
from talkingface.config import Config
from tests.study import web_serving

SEED = Config().seed
KEYS = dict(zip(RESPONSES, ("n", "h", "s", "u")))
SITE = {"format": 1, "keys": KEYS, "practice": True, "manifest_digest": "d" * 64,
        "source": "/stimuli"}
MEASURES = {"browser": "Chrome 156", "refresh_hz": 60.0, "stimulus_onset_ms": 100.0,
            "stimulus_end_ms": 1600.0, "response_onset_ms": 1601.5, "response_ms": 2400.25,
            "fullscreen": True, "focused": True}


@pytest.fixture
def serve(tmp_path):
    """``serve(study_dir, **settings)``: an httpx client on a running server of a WebStudy
    (stopped when the test ends)."""
    with contextlib.ExitStack() as stack:
        def start(study_dir, **kw):
            study = WebStudy(study_dir, SITE, study_seed=SEED, n_slots=kw.pop("n_slots", 8),
                             **kw)
            return stack.enter_context(web_serving.client(tmp_path, study))
        yield start


def answer(trial) -> str:
    """A fixed answer per trial (all four responses occur)."""
    return RESPONSES[(trial.trial_index * 7) % 4]


def post_trial(client, plan, trial: dict, **change):
    body = {"participant_id": plan["participant_id"], "token": plan["token"],
            "trial_index": trial["trial_index"], "stimulus_id": trial["stimulus_id"],
            "response_key": KEYS[RESPONSES[(trial["trial_index"] * 7) % 4]], "rt_ms": 812.5,
            "browser": MEASURES, **change}
    return client.post("/api/trial", json=body)


def snapshot(folder) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and not p.name.endswith(".lock")}


@pytest.fixture
def study_dir(tmp_path):
    return tmp_path / "study_data"


def test_a_new_participant_gets_the_labs_slot_order_and_a_token(study_dir, serve):
    client = serve(study_dir)
    r = client.post("/api/session", json={"params": {"participant": "P01"}})
    assert r.status_code == 200, r.text
    plan = r.json()
    first = Allocation(study_dir).rows()[0]
    assert (plan["participant_id"], plan["sequence"]) == ("P01", first["sequence"]) == \
        (first["participant_id"], allocation_sequences(8, SEED)[0])
    lab = session_trials("P01", plan["sequence"], SEED)
    assert [t["stimulus_id"] for t in plan["trials"]] == [t.stimulus_id for t in lab]
    assert [t["trial_index"] for t in plan["trials"]] == list(range(N_TRIALS))
    assert [t["opens_part"] for t in plan["trials"] if t["opens_part"]] == \
        ["visual-0", "audio-0", "bimodal-1", "bimodal-2"]
    assert plan["practice"] and plan["session"] == 1 and plan["start"] == 0
    assert plan["answers"] is None and plan["completion"] is None
    side = json.loads(sidecar_path(study_dir, "P01").read_text())
    assert side["web"]["token_sha256"] == token_digest(plan["token"]) != plan["token"]
    assert plan["token"] not in sidecar_path(study_dir, "P01").read_text()
    assert side["site"] == "web" and side["sessions"][0]["end_state"] == "running"
    # a second participant takes the next slot
    second = client.post("/api/session", json={"params": {"participant": "P02"}}).json()
    assert second["sequence"] == allocation_sequences(8, SEED)[1]


def test_a_whole_session_writes_the_contract_rows_with_what_the_browser_measured(study_dir,
                                                                               serve):
    client = serve(study_dir, completion_code="C0DE42",
                   completion_url="https://app.prolific.com/submissions/complete?cc={code}")
    params = {"PROLIFIC_PID": "5f3a9c0e1b2d4e5f6a7b8c9d", "STUDY_ID": "abc", "SESSION_ID": "x1"}
    plan = client.post("/api/session", json={"params": params}).json()
    pid = plan["participant_id"]
    assert pid == params["PROLIFIC_PID"]
    for t in plan["trials"]:
        reply = post_trial(client, plan, t).json()
        assert reply["saved"] == t["trial_index"]
    assert reply["complete"] and reply["completion"] == {
        "code": "C0DE42", "url": "https://app.prolific.com/submissions/complete?cc=C0DE42"}
    rows = read_rows(data_path(study_dir, pid))[0]
    lab = session_trials(pid, plan["sequence"], SEED)
    assert [(int(r["trial_index"]), r["stimulus_id"], r["block"], r["face"], r["expression"],
             r["audio"]) for r in rows] == \
        [(t.trial_index, t.stimulus_id, t.block, t.face, t.expression, t.audio) for t in lab]
    assert [r["response"] for r in rows] == [answer(t) for t in lab]
    assert {r["site"] for r in rows} == {"web"} and {r["rt_s"] for r in rows} == {"0.8125"}
    assert rows[0]["browser"] == "Chrome 156" and rows[0]["fullscreen"] == "true"
    assert rows[0]["response_ms"] == "2400.25" and rows[0]["simulated"] == "false"
    side = json.loads(sidecar_path(study_dir, pid).read_text())
    assert side["web"]["recruitment"] == params and side["sessions"][-1]["end_state"] == \
        "complete"
    assert [r["status"] for r in Allocation(study_dir).rows() if r["participant_id"] == pid] \
        == ["complete"]
    received = (data_path(study_dir, pid).parent / "web" / "received.jsonl").read_text()
    assert len(received.splitlines()) == N_TRIALS and plan["token"] not in received
    # opened again: not run again, shown the code again; nothing written
    before = snapshot(study_dir)
    again = client.post("/api/session", json={"params": params, "token": plan["token"]}).json()
    assert again["complete"] and again["trials"] == [] and again["completion"]["code"] == \
        "C0DE42"
    assert snapshot(study_dir) == before


def test_a_page_closed_mid_way_continues_at_the_next_trial(study_dir, serve):
    client = serve(study_dir)
    plan = client.post("/api/session", json={"params": {"participant": "P07"}}).json()
    for t in plan["trials"][:11]:
        assert post_trial(client, plan, t).status_code == 200
    # the tab is closed; the page is opened again from the same browser (its token)
    again = client.post("/api/session", json={"params": {"participant": "P07"},
                                               "token": plan["token"]}).json()
    assert (again["start"], again["session"], again["practice"]) == (11, 2, False)
    assert again["token"] == plan["token"] and again["sequence"] == plan["sequence"]
    assert again["trials"] == [dict(t, opens_part=t["opens_part"] or (
        f"{t['block']}-{t['period']}" if t["trial_index"] == 11 else None))
        for t in plan["trials"][11:]]  # its part's instruction is shown again
    for t in again["trials"]:
        assert post_trial(client, again, t).status_code == 200
    rows = read_rows(data_path(study_dir, "P07"))[0]
    assert [int(r["trial_index"]) for r in rows] == list(range(N_TRIALS))
    assert [r["session"] for r in rows] == ["1"] * 11 + ["2"] * 16
    side = json.loads(sidecar_path(study_dir, "P07").read_text())
    assert [s["end_state"] for s in side["sessions"]] == ["interrupted", "complete"]


def test_a_row_cut_short_is_asked_again(study_dir, serve):
    client = serve(study_dir)
    plan = client.post("/api/session", json={"params": {"participant": "P03"}}).json()
    for t in plan["trials"][:5]:
        post_trial(client, plan, t)
    path = data_path(study_dir, "P03")
    path.write_bytes(path.read_bytes() + b"P03,A,SR,bimodal")  # the server died mid-write
    again = client.post("/api/session", json={"params": {"participant": "P03"},
                                               "token": plan["token"]}).json()
    assert again["start"] == 5 and path.read_bytes().endswith(b"\n")


@pytest.mark.parametrize("case", ["unknown participant", "posted twice", "out of order",
                                  "malformed JSON", "not an object", "huge body", "wrong token",
                                  "no token", "bad id", "bad key", "other stimulus",
                                  "bad measure", "negative rt", "other's token"])
def test_bad_requests_get_one_line_and_change_no_file(study_dir, case, serve):
    client = serve(study_dir)
    plan = client.post("/api/session", json={"params": {"participant": "P01"}}).json()
    other = client.post("/api/session", json={"params": {"participant": "P02"}}).json()
    t0, t1 = plan["trials"][0], plan["trials"][1]
    assert post_trial(client, plan, t0).status_code == 200
    before = snapshot(study_dir)
    status, message = {
        "unknown participant": (404, "participant P09 has no session on this server; open the "
                                     "study's page first"),
        "posted twice": (409, "trial 0 of participant P01 is already recorded; nothing was "
                              "written"),
        "out of order": (409, "trial 2 of participant P01 is out of order: trial 1 comes next; "
                              "nothing was written"),
        "malformed JSON": (400, "the body is not JSON (JSONDecodeError: "),
        "not an object": (400, "the body must be a JSON object"),
        "huge body": (413, f"allowed: at most {MAX_BODY}"),
        "wrong token": (403, "participant P01's session was started in another browser (its "
                             "token does not match); continue it in that browser"),
        "no token": (403, "participant P01's session was started in another browser"),
        "bad id": (400, "participant id '../P01'"),
        "bad key": (400, "response_key 'x'; allowed: n, h, s, u"),
        "other stimulus": (400, f"trial 1 of participant P01 plays {t1['stimulus_id']}, not "
                                "audio-bad; nothing was written"),
        "bad measure": (400, "browser.focused 'yes'; allowed: true or false"),
        "negative rt": (400, "rt_ms -5; allowed: a number in [0, 600000]"),
        "other's token": (403, "participant P01's session was started in another browser"),
    }[case]
    if case == "unknown participant":
        r = post_trial(client, dict(plan, participant_id="P09"), t1)
    elif case == "posted twice":
        r = post_trial(client, plan, t0, response_key="s")
    elif case == "out of order":
        r = post_trial(client, plan, plan["trials"][2])
    elif case == "malformed JSON":
        r = client.post("/api/trial", content=b'{"participant_id": "P01",',
                        headers={"content-type": "application/json"})
    elif case == "not an object":
        r = client.post("/api/trial", json=[1, 2])
    elif case == "huge body":
        r = post_trial(client, plan, t1, padding="x" * (MAX_BODY + 1))
    elif case == "wrong token":
        r = post_trial(client, dict(plan, token="A" * 32), t1)
    elif case == "no token":
        r = post_trial(client, dict(plan, token=None), t1)
    elif case == "bad id":
        r = post_trial(client, dict(plan, participant_id="../P01"), t1)
    elif case == "bad key":
        r = post_trial(client, plan, t1, response_key="x")
    elif case == "other stimulus":
        r = post_trial(client, plan, t1, stimulus_id="audio-bad")
    elif case == "bad measure":
        r = post_trial(client, plan, t1, browser=dict(MEASURES, focused="yes"))
    elif case == "negative rt":
        r = post_trial(client, plan, t1, rt_ms=-5)
    else:  # P02's token on P01's data
        r = post_trial(client, dict(plan, token=other["token"]), t1)
    assert r.status_code == status, r.text
    body = r.json()
    assert message in body["error"] and "\n" not in body["error"]
    assert body.get("code") == ("duplicate" if case == "posted twice" else None)
    assert snapshot(study_dir) == before


def test_another_browser_cannot_continue_or_read_a_session(study_dir, serve):
    client = serve(study_dir)
    plan = client.post("/api/session", json={"params": {"participant": "P01"}}).json()
    post_trial(client, plan, plan["trials"][0])
    before = snapshot(study_dir)
    r = client.post("/api/session", json={"params": {"participant": "P01"}})
    assert r.status_code == 403 and "trials" not in r.json()
    r = client.post("/api/session", json={"params": {"participant": "P01"}, "token": "x" * 30})
    assert r.status_code == 403
    assert snapshot(study_dir) == before


def test_bad_session_requests_are_refused_before_any_file(study_dir, serve):
    client = serve(study_dir)
    before = snapshot(study_dir)
    for body, status, message in [
            ({"params": {"participant": "P 01"}}, 400, "participant id 'P 01'"),
            ({"params": {"participant": "x" * 40}}, 400, "use 1-32 letters or digits"),
            ({"params": ["P01"]}, 400, "params: allowed at most 20 URL parameters"),
            ({"params": {f"k{i}": "v" for i in range(21)}}, 400, "at most 20 URL parameters"),
            ({"params": {}, "browser": "chrome"}, 400, "browser 'chrome'; allowed: an object")]:
        r = client.post("/api/session", json=body)
        assert r.status_code == status and message in r.json()["error"], r.text
    assert snapshot(study_dir) == before
    # an unknown API path is not a file of the experiment
    assert client.post("/api/other", json={}).status_code in (404, 405)


def test_a_lab_participant_is_not_continued_in_a_browser(study_dir, serve):
    """A participant whose sidecar was written by ``study run`` (no web token) is refused."""
    sidecar_path(study_dir, "P05").parent.mkdir(parents=True)
    sidecar_path(study_dir, "P05").write_text(json.dumps({"participant_id": "P05",
                                                          "sessions": []}))
    client = serve(study_dir)
    before = snapshot(study_dir)
    r = client.post("/api/session", json={"params": {"participant": "P05"}})
    assert r.status_code == 409 and "session ran in the lab" in r.json()["error"]
    assert snapshot(study_dir) == before


def test_a_full_list_refuses_a_new_participant(study_dir, serve):
    client = serve(study_dir, n_slots=2)
    for pid in ("P01", "P02"):
        assert client.post("/api/session", json={"params": {"participant": pid}}).status_code \
            == 200
    before = snapshot(study_dir)
    r = client.post("/api/session", json={"params": {"participant": "P03"}})
    assert r.status_code == 409 and "every slot of" in r.json()["error"]
    assert snapshot(study_dir) == before


def test_a_participant_without_an_id_gets_one(study_dir, serve):
    client = serve(study_dir)
    plan = client.post("/api/session", json={"params": {}}).json()
    assert plan["participant_id"].startswith("W") and len(plan["participant_id"]) == 13
    again = client.post("/api/session", json={"params": {}, "token": plan["token"],
                                               "participant_id": plan["participant_id"]}).json()
    assert again["participant_id"] == plan["participant_id"] and again["session"] == 2


def test_simulated_observers_answer_as_in_the_lab(study_dir, serve):
    """``serve --inject flmp``: the answers reaching the page are those the lab's injected
    observer gives the same participant, keyed by trial index; on reopening, the remaining
    ones, from the same random stream."""
    def observer(pid):
        state = {"n": 0}

        def respond(trial):
            state["n"] += 1
            return RESPONSES[(trial.trial_index + state["n"]) % 4], 0.5 + state["n"] / 100
        return respond

    client = serve(study_dir, observer=observer, responder_model="flmp-test")
    plan = client.post("/api/session", json={"params": {"participant": "P01"}}).json()
    trials = session_trials("P01", plan["sequence"], SEED)
    ref = observer("P01")
    want = {str(t.trial_index): dict(zip(("response", "rt_s"), ref(t))) for t in trials}
    assert plan["answers"] == {k: {"key": KEYS[v["response"]], "rt_s": v["rt_s"]}
                               for k, v in want.items()}
    for t in plan["trials"][:4]:
        post_trial(client, plan, t, response_key=plan["answers"][str(t["trial_index"])]["key"])
    again = client.post("/api/session", json={"params": {"participant": "P01"},
                                               "token": plan["token"]}).json()
    assert again["answers"] == {k: v for k, v in plan["answers"].items() if int(k) >= 4}
    rows = read_rows(data_path(study_dir, "P01"))[0]
    assert {(r["simulated"], r["responder_model"]) for r in rows} == {("true", "flmp-test")}
