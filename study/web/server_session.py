"""The web study's sessions on the lab's own server: the rules of a lab session, request by
request (``study.web.app`` puts them behind HTTP).

A participant's browser calls :meth:`WebStudy.start` when the page opens and
:meth:`WebStudy.record` once per judgment. They keep the lab's rules (``study.session``,
``study.data``): the identifier is checked as ``study run`` checks it; a new participant takes
the next slot of the same allocation list, under the same lock, as a lab session; the trial
order is :func:`study.design.session_trials` of the participant and the study seed; each
judgment is appended and fsync'ed to the same psych-DS data file (``site`` = ``web``, with what
the browser measured) after its request is kept verbatim in ``sub-<id>/web/received.jsonl``
(the primary record, as PsychoPy's files are in the lab); a complete session is never run or
written again; a page closed mid-way continues, when opened again, at the next trial (a new
session number, as ``--resume`` in the lab).

A participant's data can be read or written only with the secret token their browser got at the
start (kept as a SHA-256 in their sidecar): another participant's id alone neither continues
that session nor writes to it. Every request for a participant holds that participant's lock
(the one a lab session holds), so two requests of one participant never interleave; requests of
different participants run at the same time.

Refusals raise :class:`WebError` (a ParameterError with the HTTP status to answer with) before
any file is changed.
"""
from __future__ import annotations

import hashlib
import hmac
import json
import math
import os
import platform
import secrets
from pathlib import Path

from filelock import FileLock, Timeout

from groundwork.errors import ParameterError
from study import data as sdata
from study.design import (N_TRIALS, RESPONSES, check_participant_id, group_of,
                          participant_seed, session_trials)
from study.session import LOCK_NAME, claim_slot, earlier_sessions
from study.columns import WEB_COLUMNS

# how long a request waits for the participant's lock (another request of theirs, or a lab
# session holding it) before it is refused
LOCK_WAIT_S = 10.0
# the recruitment parameters kept (at most this many, each at most this long)
MAX_PARAMS, MAX_PARAM_CHARS = 20, 200
MAX_RT_MS = 600_000.0  # a response screen shown for ten minutes is a broken session
# the participant id a recruitment site passes, in the order they are looked for
ID_PARAMS = ("PROLIFIC_PID", "participant")


class WebError(ParameterError):
    """A refused request: ``status`` is the HTTP status (400 malformed, 403 wrong token, 404
    unknown participant, 409 conflict with what is recorded, 413 too large); ``code`` names a
    case a page acts on (``duplicate``: that judgment is already saved)."""

    def __init__(self, status: int, message: str, code: str | None = None):
        super().__init__(message)
        self.status, self.code = int(status), code


def token_digest(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def _text(body: dict, name: str, *, required: bool = True) -> str | None:
    v = body.get(name)
    if v is None and not required:
        return None
    if not isinstance(v, str) or not v or len(v) > MAX_PARAM_CHARS:
        raise WebError(400, f"{name} {v!r}; allowed: a string of 1-{MAX_PARAM_CHARS} "
                            "characters")
    return v


def _params(body: dict) -> dict:
    p = body.get("params", {})
    if not isinstance(p, dict) or len(p) > MAX_PARAMS or not all(
            isinstance(k, str) and isinstance(v, str) and len(k) <= 64
            and len(v) <= MAX_PARAM_CHARS for k, v in p.items()):
        raise WebError(400, f"params: allowed at most {MAX_PARAMS} URL parameters, names of at "
                            f"most 64 and values of at most {MAX_PARAM_CHARS} characters")
    return dict(p)


def _number(body: dict, name: str, lo: float, hi: float) -> float:
    v = body.get(name)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
            or not lo <= v <= hi:
        raise WebError(400, f"{name} {v!r}; allowed: a number in [{lo:g}, {hi:g}]")
    return float(v)


def browser_measures(raw) -> dict:
    """The browser's measures of one trial (:data:`study.columns.WEB_COLUMNS`), checked:
    times and the refresh rate are finite non-negative numbers (or absent), ``fullscreen`` and
    ``focused`` booleans, ``browser`` a short text."""
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise WebError(400, f"browser {raw!r}; allowed: an object of the browser's measures")
    out = {}
    for c in WEB_COLUMNS:
        v = raw.get(c)
        if v is None:
            continue
        if c in ("fullscreen", "focused"):
            ok = isinstance(v, bool)
        elif c == "browser":
            ok = isinstance(v, str) and len(v) <= MAX_PARAM_CHARS and "\n" not in v
        else:
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and \
                math.isfinite(v) and v >= 0
        if not ok:
            raise WebError(400, f"browser.{c} {v!r}; allowed: "
                                + ("true or false" if c in ("fullscreen", "focused") else
                                   "a short text" if c == "browser" else
                                   "a finite number >= 0"))
        out[c] = v
    return out


class WebStudy:
    """The server's side of every participant's web session (see the module text).

    Parameters
    ----------
    study_dir : path
        The study data folder (the same as ``study run``'s; its allocation list is made with
        ``study_seed`` and ``n_slots`` when missing).
    site : dict
        The built experiment's ``study.json`` (keys, practice, the stimuli's manifest digest).
    study_seed, n_slots : int
        As ``study run`` takes them (the run seed; ``study.n_participants``).
    completion_code, completion_url : str
        What a participant who completed is given (``study.completion_*``).
    observer : callable, optional
        ``observer(pid) -> answer`` where ``answer(trial) -> (response, rt_s)``: simulated
        observers answer every participant (``study serve --inject flmp``); their answers
        reach the page, which plays them through jsPsych's simulation.
    responder_model : str
        What answers: ``human``, or the simulated observers' model.
    """

    def __init__(self, study_dir, site: dict, *, study_seed: int, n_slots: int,
                 completion_code: str = "", completion_url: str = "", observer=None,
                 responder_model: str = "human"):
        self.dir = Path(study_dir)
        self.site = site
        self.seed, self.n_slots = int(study_seed), int(n_slots)
        self.keys = {r: str(site["keys"][r]) for r in RESPONSES}
        self.response_of = {k: r for r, k in self.keys.items()}
        self.code, self.url = completion_code, completion_url
        self.observer, self.responder_model = observer, responder_model
        alloc = sdata.Allocation(self.dir)
        if alloc.path.is_file():  # refuses a list made with another seed, as study run does
            claim_check = alloc.meta_path.is_file() and json.loads(
                alloc.meta_path.read_text()).get("seed")
            if claim_check not in (False, None, self.seed):
                raise ParameterError(f"{alloc.path} was made with seed {claim_check}, but the "
                                     f"server's study seed is {self.seed}; serve with --seed "
                                     f"{claim_check} (one seed per study)")
        else:
            alloc.create(self.n_slots, self.seed)
        sdata.write_dataset_description(self.dir, name="talkingface emotion-perception study",
                                        simulated=observer is not None)

    # -- the participant's files and lock ------------------------------------------------
    def _lock(self, pid: str) -> FileLock:
        folder = sdata.subject_dir(self.dir, pid)
        folder.mkdir(parents=True, exist_ok=True)
        lock = FileLock(str(folder / LOCK_NAME))
        try:
            lock.acquire(timeout=LOCK_WAIT_S)
        except Timeout:
            raise WebError(409, f"participant {pid}'s session is busy (another request of "
                                "theirs, or a session in the lab, holds it); try again") \
                from None
        return lock

    def _sidecar(self, pid: str) -> dict:
        path = sdata.sidecar_path(self.dir, pid)
        return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}

    def _save_sidecar(self, pid: str, side: dict) -> None:
        sdata.write_atomic(sdata.sidecar_path(self.dir, pid), json.dumps(side, indent=1) + "\n")

    def _check_token(self, pid: str, side: dict, token) -> None:
        web = side.get("web")
        if not isinstance(web, dict):
            raise WebError(409, f"participant {pid}'s session ran in the lab, not in a browser; "
                                "continue it there (talkingface study run --resume)")
        if not isinstance(token, str) or not hmac.compare_digest(
                token_digest(token), str(web.get("token_sha256", ""))):
            raise WebError(403, f"participant {pid}'s session was started in another browser "
                                "(its token does not match); continue it in that browser")

    def _completion(self) -> dict:
        return {"code": self.code or None,
                "url": self.url.replace("{code}", self.code) if self.url else None}

    def _trials(self, pid: str, side: dict) -> list:
        return session_trials(pid, side["allocation"]["sequence"], self.seed)

    # -- the two requests ----------------------------------------------------------------
    def start(self, body) -> dict:
        """A page opened: the participant's plan (the /api/session reply of the contract),
        for a new participant (a slot claimed, a token made) or one continuing."""
        if not isinstance(body, dict):
            raise WebError(400, "the body must be a JSON object")
        params = _params(body)
        given = next((params[k] for k in ID_PARAMS if params.get(k)), None) or \
            body.get("participant_id")
        if given is None:
            given = "W" + secrets.token_hex(6).upper()  # a new participant with no id given
        try:
            pid = check_participant_id(given)
        except ParameterError as exc:
            raise WebError(400, str(exc)) from None
        browser = body.get("browser") or {}
        if not isinstance(browser, dict):
            raise WebError(400, f"browser {browser!r}; allowed: an object")
        lock = self._lock(pid)
        try:
            return self._start(pid, body.get("token"), params, browser)
        finally:
            lock.release()

    def _start(self, pid: str, token, params: dict, browser: dict) -> dict:
        side = self._sidecar(pid)
        data = sdata.data_path(self.dir, pid)
        if side or data.is_file():
            self._check_token(pid, side, token)
            rows = sdata.read_rows(data)[0] if data.is_file() else []
            if len(rows) >= N_TRIALS:  # never run again; shown the code again
                return {"participant_id": pid, "complete": True, "trials": [],
                        "completion": self._completion()}
        else:
            token = secrets.token_urlsafe(24)
            side = {}
        try:
            slot, resume = claim_slot(self.dir, pid, study_seed=self.seed,
                                      n_slots=self.n_slots, resume=data.is_file())
            trials = session_trials(pid, slot["sequence"], self.seed)
            sf = sdata.SessionFile(self.dir, pid, trials, resume=resume)
        except ParameterError as exc:
            raise WebError(409, str(exc)) from None
        earlier = earlier_sessions(side)
        record = {"session": len(earlier) + 1, "start": sdata.now_iso(), "resumed": resume,
                  "rows_at_start": len(sf.done), "dropped_partial_row": sf.dropped_partial,
                  "end": None, "end_state": "running", "rows_at_end": None,
                  "site": "web", "browser": {k: str(v)[:MAX_PARAM_CHARS]
                                             for k, v in list(browser.items())[:MAX_PARAMS]}}
        web = dict(side.get("web", {}), token_sha256=token_digest(token))
        web.setdefault("recruitment", params)
        side = {"participant_id": pid, "task": sdata.TASK,
                "group": group_of(slot["sequence"]),
                "versions": {"python": platform.python_version(),
                             "experiment": self.site.get("versions", {})},
                "study_seed": self.seed, "participant_seed": participant_seed(self.seed, pid),
                "allocation": {"file": str(sdata.Allocation(self.dir).path),
                               "slot": int(slot["slot"]), "sequence": slot["sequence"]},
                "stimuli": {"folder": self.site.get("source", ""),
                            "manifest_digest": self.site.get("manifest_digest", "")},
                "responder_model": self.responder_model,
                "simulated": self.responder_model != "human", "keys": dict(self.keys),
                "site": "web", "web": web, "sessions": [*earlier, record]}
        self._save_sidecar(pid, side)
        start, part, plan = len(sf.done), None, []
        for t in trials[len(sf.done):]:  # a part's instruction before its first trial, also
            opens = (t.block, t.period) != part  # when the session continues inside it
            part = (t.block, t.period)
            plan.append(dict(t.as_dict(), opens_part=f"{t.block}-{t.period}" if opens else None))
        return {"participant_id": pid, "token": token, "sequence": slot["sequence"],
                "session": record["session"], "start": start,
                "practice": bool(self.site.get("practice", True)) and start == 0
                and not earlier, "complete": False, "trials": plan,
                "answers": self._answers(pid, trials, start), "completion": None}

    def _answers(self, pid: str, trials: list, start: int) -> dict | None:
        """The simulated observer's answers to the trials from ``start`` on (it answers the
        earlier ones too, unseen, so its random stream continues where a closed page left it,
        as ``study run --inject flmp --resume`` does)."""
        if self.observer is None:
            return None
        answer, out = self.observer(pid), {}
        for t in trials:
            response, rt = answer(t)
            if t.trial_index >= start:
                out[str(t.trial_index)] = {"key": self.keys[response], "rt_s": float(rt)}
        return out

    def record(self, body) -> dict:
        """One judgment from the page (the /api/trial body of the contract), checked against
        the participant's plan, kept verbatim and appended to the data file."""
        if not isinstance(body, dict):
            raise WebError(400, "the body must be a JSON object")
        try:
            pid = check_participant_id(body.get("participant_id"))
        except ParameterError as exc:
            raise WebError(400, str(exc)) from None
        k = body.get("trial_index")
        if isinstance(k, bool) or not isinstance(k, int) or not 0 <= k < N_TRIALS:
            raise WebError(400, f"trial_index {k!r}; allowed: an integer in [0, {N_TRIALS - 1}]")
        sid = _text(body, "stimulus_id")
        key = _text(body, "response_key")
        if key not in self.response_of:
            raise WebError(400, f"response_key {key!r}; allowed: "
                                f"{', '.join(self.response_of)}")
        rt_ms = _number(body, "rt_ms", 0.0, MAX_RT_MS)
        web = browser_measures(body.get("browser"))
        if not sdata.sidecar_path(self.dir, pid).is_file():
            raise WebError(404, f"participant {pid} has no session on this server; open the "
                                "study's page first")
        lock = self._lock(pid)
        try:
            return self._record(pid, body, k, sid, key, rt_ms, web)
        finally:
            lock.release()

    def _record(self, pid, body, k, sid, key, rt_ms, web) -> dict:
        side = self._sidecar(pid)
        self._check_token(pid, side, body.get("token"))
        trials = self._trials(pid, side)
        data = sdata.data_path(self.dir, pid)
        done = len(sdata.read_rows(data)[0]) if data.is_file() else 0
        if k < done:
            raise WebError(409, f"trial {k} of participant {pid} is already recorded; nothing "
                                "was written", code="duplicate")
        if k > done:
            raise WebError(409, f"trial {k} of participant {pid} is out of order: trial {done} "
                                "comes next; nothing was written")
        if trials[k].stimulus_id != sid:
            raise WebError(400, f"trial {k} of participant {pid} plays {trials[k].stimulus_id}, "
                                f"not {sid}; nothing was written")
        sf = sdata.SessionFile(self.dir, pid, trials, resume=data.is_file())
        session = side["sessions"][-1]
        row = sdata.trial_row(trials[k], participant_id=pid,
                              sequence=side["allocation"]["sequence"],
                              response=self.response_of[key], response_key=key,
                              rt_s=rt_ms / 1000.0, simulated=side["simulated"],
                              responder_model=side["responder_model"],
                              session=int(session["session"]), site="web", web=web)
        received = sdata.subject_dir(self.dir, pid) / "web" / "received.jsonl"
        received.parent.mkdir(exist_ok=True)
        kept = {k_: v for k_, v in body.items() if k_ != "token"}
        with open(received, "a", encoding="utf-8") as f:  # the primary record, first
            f.write(json.dumps({"received": sdata.now_iso(), **kept}, sort_keys=True) + "\n")
            f.flush()
            os.fsync(f.fileno())
        sf.append(row)
        complete = sf.complete
        if complete:  # (a session closed mid-way is marked interrupted when it is reopened)
            session.update(end=sdata.now_iso(), rows_at_end=len(sf.done), end_state="complete")
            self._save_sidecar(pid, side)
            sdata.Allocation(self.dir).set_status(pid, "complete")
        return {"saved": k, "rows": len(sf.done), "complete": complete,
                "completion": self._completion() if complete else None}
