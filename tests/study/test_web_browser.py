"""The web study in a real browser (issue 41): headless Chromium at the built page
(study/web/static/experiment.js), answered with real key presses and clicks (selenium), against
the real server (uvicorn, tests/study/web_serving.py) of a WebStudy over a temporary study
folder.

Which trial a response screen asks is read from the page (the face image's ``<sid>-last.png``,
or the speaker symbol) and the participant's trial order (the lab's, study.design); no answer
goes through the API by hand. A whole web session writes the rows a lab session (study.runner,
headless under Xvfb, same participant, seed and answers) writes; a page closed mid-way continues
at the next trial; another browser cannot take a participant's session over; simulated
observers answer through the page with jsPsych's simulation.

The built folder is copied with a 0.1 s fixation and inter-trial interval (the lab test's
``study.fixation_s`` setting, as ``--set`` gives it) to keep the run short.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from study.data import Allocation, data_path, read_rows, sidecar_path
from study.design import N_TRIALS, RESPONSES, session_trials
from study.web.server_session import WebStudy
from talkingface.config import Config
from tests.browser_session import reset
from tests.study import web_serving
from tests.study.test_runner import TIMEOUT, XVFB, _kill_group, env  # noqa: F401 (lab's env)
from tests.study.web_browser import Participant, shown_stimulus
from tests.study.web_fixtures import web_build, web_stimuli  # noqa: F401
from tests.talkingface.browser import headless_chromium, wait_until

SEED = Config().seed
N_SLOTS = 8
FAST_S = 0.1  # fixation and inter-trial interval of the copied page (s)
CODE = "TESTCODE1"
FLMP_RT_S = 0.3  # the simulated observers' median response time (s); the default is 1.2
# the rows a lab and a web session of one participant share, column for column
SHARED = ("participant_id", "group", "sequence", "block", "period", "trial_index", "face",
          "expression", "audio", "stimulus_id", "response", "response_key", "session")
TIMES = ("stimulus_onset_ms", "stimulus_end_ms", "response_onset_ms", "response_ms")


def rule(trial) -> str:
    """The fixed answer of a trial (all four responses occur)."""
    return RESPONSES[(7 * trial.trial_index) % 4]


# the lab session of the same participant, answering with the same rule as rule()
LAB = """
import json, sys
from study.design import RESPONSES
from study.runner import run_session
def responder(trial):
    return RESPONSES[(7 * trial.trial_index) % 4], 0.3
res = run_session(sys.argv[1], sys.argv[2], sys.argv[3], study_seed=int(sys.argv[4]),
                  n_slots=int(sys.argv[5]), fixation_s=0.02, iti_s=0.02, audio_backend="none",
                  responder=responder, responder_model="test-rule")
print(json.dumps(res))
"""


@pytest.fixture(scope="module")
def web_dir(web_build, tmp_path_factory):
    """The built page with a short fixation and inter-trial interval."""
    out = tmp_path_factory.mktemp("web_fast") / "web"
    shutil.copytree(web_build, out)
    site = json.loads((out / "study.json").read_text())
    site.update(fixation_s=FAST_S, iti_s=FAST_S)
    (out / "study.json").write_text(json.dumps(site, indent=1))
    return out


@pytest.fixture(scope="module")
def site(web_dir):
    return json.loads((web_dir / "study.json").read_text())


@pytest.fixture
def serve(web_dir, site):
    """``serve(study_dir, **settings)``: the base URL of a running server of a WebStudy."""
    with contextlib.ExitStack() as stack:
        def start(study_dir, **kw):
            study = WebStudy(study_dir, site, study_seed=SEED, n_slots=N_SLOTS, **kw)
            return stack.enter_context(web_serving.running(web_dir, study))
        yield start


def rows_of(study_dir, pid) -> list[dict]:
    rows, torn = read_rows(data_path(study_dir, pid))
    assert not torn
    return rows


def n_rows(study_dir, pid) -> int:
    path = data_path(study_dir, pid)
    return len(read_rows(path)[0]) if path.is_file() else 0


def wait_rows(driver, study_dir, pid, n: int) -> None:
    """Wait (bounded) until the data file holds ``n`` judgments."""
    wait_until(driver, lambda d: n_rows(study_dir, pid) == n, f"{n} rows in {pid}'s file", 60)


def plan_of(study_dir, pid) -> list:
    """The participant's trial order, from the slot the server gave them."""
    side = json.loads(sidecar_path(study_dir, pid).read_text())
    return session_trials(pid, side["allocation"]["sequence"], SEED)


def open_page(driver, site, study_dir, base, pid, *, start: int = 0) -> Participant:
    """Open ``pid``'s link; a Participant at the page, its next study trial ``start``."""
    driver.get(f"{base}/?participant={pid}")
    return Participant(driver, site, lambda: plan_of(study_dir, pid), rule, next=start)


def snapshot(folder) -> dict:
    return {str(q.relative_to(folder)): hashlib.sha256(q.read_bytes()).hexdigest()
            for q in sorted(folder.rglob("*")) if q.is_file() and not q.name.endswith(".lock")}


def check_shown(site, plan, shown) -> None:
    """Each response screen showed its trial's last frame (or the speaker symbol)."""
    for k, src in shown:
        assert src == shown_stimulus(site, plan[k]), (k, plan[k].stimulus_id, src)


# --- (1) a whole session in the browser writes the lab's rows ---------------------------------
def test_a_whole_session_in_the_browser_writes_what_the_lab_writes(
        fresh_browser, serve, site, web_stimuli, env, tmp_path):  # noqa: F811
    """P01 answers the whole page with keys (consent clicked, each check answered, the
    practice, 27 trials answered by :func:`rule`); the lab's runner runs P01 with the same
    answers in another study folder: same columns, same rows but for the site and what only
    a browser measures, same slot of the same list; the end screen shows the code."""
    web, lab = tmp_path / "web_study", tmp_path / "lab_study"
    pid = "P01"
    proc = subprocess.Popen(  # the lab session of the same slot, at the same time (Xvfb)
        [*XVFB, sys.executable, "-c", LAB, str(lab), str(web_stimuli), pid, str(SEED),
         str(N_SLOTS)], env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, start_new_session=True)
    try:
        base = serve(web, completion_code=CODE)
        with fresh_browser() as driver:
            p = open_page(driver, site, web, base, pid)
            end = p.run()
            assert end["kind"] == "end" and end["code"] == CODE, p.screens[-3:]
            assert f"Your completion code is {CODE}." in end["text"]
        out, err = proc.communicate(timeout=TIMEOUT)
    finally:
        if proc.poll() is None:  # only after a failure: xvfb-run, Xvfb and the session
            _kill_group(proc.pid)
            proc.communicate()
    assert proc.returncode == 0, err[-3000:]
    assert json.loads(out.strip().splitlines()[-1])["complete"]
    # the page: consent, the checks, welcome, practice, the four parts, in that order
    kinds = [k if k != "text" else f"text:{d}" for k, d in p.screens]
    assert kinds[:9] == ["consent", "fullscreen", "key", "key", "key", "key", "text:sound-check",
                         "audio-check", "text:welcome"]
    assert [d for k, d in p.screens if k == "key"] == [k.upper() for k in site["keys"].values()]
    assert kinds[9:12] == ["text:practice", "practice-response", "text:practice_over"]
    assert [k for k in kinds if k.startswith("text:part")] == [
        "text:part:visual-0", "text:part:audio-0", "text:part:bimodal-1", "text:part:bimodal-2"]
    plan = plan_of(web, pid)
    check_shown(site, plan, p.shown)
    assert [k for k, _ in p.shown] == list(range(N_TRIALS))
    # the two data files
    header = {s: data_path(s, pid).read_text().splitlines()[0] for s in (web, lab)}
    assert header[web] == header[lab]
    w, l_ = rows_of(web, pid), rows_of(lab, pid)
    assert len(w) == len(l_) == N_TRIALS
    for a, b in zip(w, l_):
        assert {c: a[c] for c in SHARED} == {c: b[c] for c in SHARED}
    assert [r["response"] for r in w] == [rule(t) for t in plan]
    assert {r["site"] for r in w} == {"web"} and {r["site"] for r in l_} == {"lab"}
    for r in w:
        assert r["browser"].lower().startswith("chrome"), r["browser"]
        assert float(r["refresh_hz"]) > 0
        t = [float(r[c]) for c in TIMES]
        assert t == sorted(t), dict(zip(TIMES, t))
        # in full screen (the page asked, the participant agreed) and focused all along
        assert (r["fullscreen"], r["focused"]) == ("true", "true")
        assert float(r["rt_s"]) == pytest.approx((t[3] - t[2]) / 1000, abs=0.01)
    for r in l_:
        assert all(r[c] == "" for c in (*TIMES, "browser", "refresh_hz"))
    # both took the first slot of the same seeded list
    slots = [[(r["slot"], r["sequence"]) for r in Allocation(s).rows()
              if r["participant_id"] == pid] for s in (web, lab)]
    assert slots[0] == slots[1] and len(slots[0]) == 1
    assert [r["sequence"] for r in Allocation(web).rows()] == \
        [r["sequence"] for r in Allocation(lab).rows()]
    sides = [json.loads(sidecar_path(s, pid).read_text()) for s in (web, lab)]
    assert sides[0]["allocation"]["sequence"] == sides[1]["allocation"]["sequence"]
    assert sides[0]["allocation"]["slot"] == sides[1]["allocation"]["slot"]
    assert [s["end_state"] for s in sides[0]["sessions"]] == ["complete"]


def received(study_dir, pid) -> list[dict]:
    """The judgments the server kept verbatim, in order."""
    path = data_path(study_dir, pid).parent / "web" / "received.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()]


# --- (2) a page closed mid-way continues at the next trial -----------------------------------
def test_a_closed_page_continues_at_the_next_trial_when_opened_again(fresh_browser, serve,
                                                                     site, tmp_path):
    """P02 answers 8 trials; once the 8th is saved the page is left (its localStorage kept)
    and opened again: no consent or practice, the checks, then trial 8's part text and trial 8;
    27 rows in order, none lost or twice, session 1 then 2."""
    study, pid = tmp_path / "study_data", "P02"
    base = serve(study, completion_code=CODE)
    with fresh_browser() as driver:
        first = open_page(driver, site, study, base, pid)
        assert first.run(until_answered=8) is None
        wait_rows(driver, study, pid, 8)  # the 8th judgment acknowledged ...
        driver.get("about:blank")  # ... and the page closed; its localStorage stays
        assert n_rows(study, pid) == 8
        again = open_page(driver, site, study, base, pid, start=8)
        end = again.run()
        assert end["kind"] == "end" and end["code"] == CODE, again.screens[-3:]
    kinds = [k if k != "text" else f"text:{d}" for k, d in again.screens]
    assert "consent" not in kinds and "text:practice" not in kinds
    assert "practice-response" not in kinds
    # the checks again, then trial 8's part (the audio-only part) before it
    assert kinds[:8] == ["fullscreen", "key", "key", "key", "key", "text:sound-check",
                         "audio-check", "text:welcome"]
    assert kinds[8:10] == ["text:part:audio-0", "response"]
    assert [k for k, _ in first.shown] == list(range(8))
    assert [k for k, _ in again.shown] == list(range(8, N_TRIALS))
    plan = plan_of(study, pid)
    check_shown(site, plan, first.shown + again.shown)
    rows = rows_of(study, pid)
    assert [int(r["trial_index"]) for r in rows] == list(range(N_TRIALS))  # none lost or twice
    assert [r["stimulus_id"] for r in rows] == [t.stimulus_id for t in plan]
    assert [r["response"] for r in rows] == [rule(t) for t in plan]
    assert [r["session"] for r in rows] == ["1"] * 8 + ["2"] * (N_TRIALS - 8)
    assert [b["trial_index"] for b in received(study, pid)] == list(range(N_TRIALS))
    side = json.loads(sidecar_path(study, pid).read_text())
    assert [s["end_state"] for s in side["sessions"]] == ["interrupted", "complete"]
    assert [s["rows_at_start"] for s in side["sessions"]] == [0, 8]


def test_a_page_closed_during_a_trial_asks_that_trial_again(fresh_browser, serve, site,
                                                            tmp_path):
    """Closed while trial 2's video plays (before its key): nothing of trial 2 reached the
    server, and the page opened again asks trial 2 first."""
    study, pid = tmp_path / "study_data", "P03"
    base = serve(study)
    with fresh_browser() as driver:
        first = open_page(driver, site, study, base, pid)
        assert first.run(until_playing=2) is None
        driver.get("about:blank")
        assert n_rows(study, pid) == 2 and len(received(study, pid)) == 2
        again = open_page(driver, site, study, base, pid, start=2)
        assert again.run(until_answered=4) is None
        wait_rows(driver, study, pid, 4)
    assert [k for k, _ in first.shown] == [0, 1] and [k for k, _ in again.shown] == [2, 3]
    kinds = [k if k != "text" else f"text:{d}" for k, d in again.screens]
    assert "consent" not in kinds and "text:practice" not in kinds
    assert kinds[8:10] == ["text:part:visual-0", "response"]  # its part's text again, first
    rows = rows_of(study, pid)
    assert [(int(r["trial_index"]), r["session"]) for r in rows] == \
        [(0, "1"), (1, "1"), (2, "2"), (3, "2")]
    assert [r["stimulus_id"] for r in rows] == [t.stimulus_id for t in plan_of(study, pid)[:4]]
    assert [b["trial_index"] for b in received(study, pid)] == [0, 1, 2, 3]
    side = json.loads(sidecar_path(study, pid).read_text())
    assert [s["end_state"] for s in side["sessions"]] == ["interrupted", "running"]


# --- (3) another browser cannot take a participant's session over ------------------------------
def test_another_browser_opening_the_same_link_is_refused_and_writes_nothing(
        fresh_browser, serve, site, tmp_path):
    """P04's session started in one browser; a browser with a fresh profile opening P04's
    link shows the server's refusal after the consent, and no file changes."""
    study, pid = tmp_path / "study_data", "P04"
    base = serve(study)
    with fresh_browser() as driver:
        first = open_page(driver, site, study, base, pid)
        assert first.run(until_answered=1) is None
        wait_rows(driver, study, pid, 1)
        before = snapshot(study)
        reset(driver, width=1600, height=1000)  # another browser: a profile with nothing kept
        other = open_page(driver, site, study, base, pid)
        end = other.run()
    assert [k for k, _ in other.screens] == ["consent", "error"]
    assert end["text"] == (f"The study could not start: participant {pid}'s session was "
                           "started in another browser (its token does not match); continue "
                           "it in that browser")
    assert snapshot(study) == before  # no session, no row, no token replaced
    assert n_rows(study, pid) == 1


def test_two_participants_in_one_browser_each_consent_and_keep_their_own_session(
        fresh_browser, serve, site, tmp_path):
    """A lab's shared computer: P05 answers 2 trials, then P06 opens their link in the same
    browser (consent asked of P06 too), answers 1; P05's link opened again continues P05's
    session at trial 2, without consent; P06's again at trial 1. Each kept their own token."""
    study = tmp_path / "study_data"
    base = serve(study)
    with fresh_browser() as driver:
        five = open_page(driver, site, study, base, "P05")
        assert five.run(until_answered=2) is None
        wait_rows(driver, study, "P05", 2)
        six = open_page(driver, site, study, base, "P06")
        assert six.run(until_answered=1) is None
        wait_rows(driver, study, "P06", 1)
        five_again = open_page(driver, site, study, base, "P05", start=2)
        assert five_again.run(until_answered=3) is None
        wait_rows(driver, study, "P05", 3)
        six_again = open_page(driver, site, study, base, "P06", start=1)
        assert six_again.run(until_answered=2) is None
        wait_rows(driver, study, "P06", 2)
    for page, consented in ((five, True), (six, True), (five_again, False),
                            (six_again, False)):
        assert ([k for k, _ in page.screens][:1] == ["consent"]) == consented, page.screens[:2]
    assert [k for k, _ in five_again.shown] == [2] and [k for k, _ in six_again.shown] == [1]
    for pid, n in (("P05", 3), ("P06", 2)):
        assert [r["session"] for r in rows_of(study, pid)] == ["1"] * (n - 1) + ["2"]


# --- (4) simulated observers answer through the page ------------------------------------------
def autoplay_chromium(width: int = 1600, height: int = 1000):
    """A headless Chromium that plays media without a user gesture (jsPsych's visual
    simulation presses no key before the first sound), quit on leaving with no process left."""
    return headless_chromium(width=width, height=height, extra_args=(
        "--autoplay-policy=no-user-gesture-required", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"))


def flmp_observer(site):
    """The FLMP observers of ``study serve --inject flmp`` (study.simulate), seeing each video
    through a fixed table of visual evidence (the tiny test videos carry no markers for the
    classifier of talkingface/cli/study_web.py: flmp_observers), and answering faster than
    the default population (median response time ``FLMP_RT_S``) to keep the test short."""
    from study.design import EXPRESSIONS, participant_seed
    from study.simulate import PopulationParams, make_observers, responder

    evidence = {}
    for i, sid in enumerate(sorted(s for s, e in site["stimuli"].items()
                                   if e["kind"] == "video")):
        p = np.full(len(EXPRESSIONS), 0.15)
        p[i % len(EXPRESSIONS)] = 0.7
        evidence[sid] = p / p.sum()

    quick = PopulationParams(rt_median_s=FLMP_RT_S)

    def observer(pid: str):
        return responder(make_observers(1, participant_seed(SEED, pid), quick)[0], evidence)
    return observer


def test_simulated_observers_answer_through_the_page(serve, site, tmp_path):
    """``?participant=P09&simulate=visual`` with the server's FLMP observers: jsPsych's
    visual simulation plays the page in the browser and posts the observer's 27 answers."""
    study, pid = tmp_path / "study_data", "P09"
    observer = flmp_observer(site)
    base = serve(study, observer=observer, responder_model="flmp-v1")
    with autoplay_chromium() as driver:
        driver.get(f"{base}/?participant={pid}&simulate=visual")
        wait_until(driver, lambda d: n_rows(study, pid) == N_TRIALS, "27 simulated judgments",
                   300)
        end = Participant(driver, site, [], rule).run()  # nothing left to answer
    assert end["kind"] == "end" and site["texts"]["end"] in end["text"]
    plan = plan_of(study, pid)
    answer = observer(pid)
    expected = [answer(t) for t in plan]
    rows = rows_of(study, pid)
    assert [int(r["trial_index"]) for r in rows] == list(range(N_TRIALS))
    assert [r["response"] for r in rows] == [r for r, _ in expected]
    assert [r["response_key"] for r in rows] == [site["keys"][r] for r, _ in expected]
    assert len({r for r, _ in expected}) > 1  # the answers differ between trials
    for r, (_, rt) in zip(rows, expected):  # the key pressed after the observer's time
        assert rt - 0.005 <= float(r["rt_s"]) <= rt + 1.0, (r["stimulus_id"], r["rt_s"], rt)
        assert float(r["rt_s"]) == pytest.approx(
            (float(r["response_ms"]) - float(r["response_onset_ms"])) / 1000, abs=0.01)
    assert {(r["simulated"], r["responder_model"], r["site"]) for r in rows} == \
        {("true", "flmp-v1", "web")}
