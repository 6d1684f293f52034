"""The study data contract (DESIGN.md) and the rules that keep it safe.

::

    study_data/
      dataset_description.json            psych-DS metadata (written once)
      allocation.csv                      the pre-generated sequence list and who holds each slot
      allocation_log.csv                  every allocation event, append-only
      sub-<id>/
        sub-<id>_task-emotion_beh.csv     one row per judgment, appended and fsync'ed per trial
        sub-<id>_task-emotion_beh.json    sidecar: versions, seeds, allocation, sessions, QC
        psychopy/                         PsychoPy's own files (the primary record of a lab run)

The columns of a data file, the codes they may hold and its text are :mod:`study.columns`.
Rules (:class:`SessionFile`): a complete session (27 rows) is never opened for writing again; a
partial one is continued only with ``resume=True``, after its rows are checked against the
planned trial order; a row cut short by a crash (no final newline) is the trial that was in
progress and is dropped on resume. :class:`Allocation` hands out the sequences of the
pre-generated list under a file lock; an aborted session keeps its slot (so it can resume in the
same order) until a researcher releases it, and every change is logged.
"""
from __future__ import annotations

import csv
import io
import json
import os
import time
from pathlib import Path

from filelock import FileLock

from groundwork.atomic import atomic_file
from groundwork.errors import ParameterError
from study.columns import COLUMNS, SITES, WEB_COLUMNS, csv_text, read_data_file
from study.design import (
    N_TRIALS,
    RESPONSES,
    SEQUENCES,
    Trial,
    allocation_sequences,
    check_participant_id,
    group_of,
)

TASK = "emotion"
ALLOCATION_COLUMNS = ("slot", "sequence", "participant_id", "status", "updated")
ALLOCATION_STATUSES = ("free", "assigned", "complete")
LOG_COLUMNS = ("time", "event", "slot", "sequence", "participant_id", "note")


def now_iso() -> str:
    """The local wall-clock time, ``2024-05-01T14:03:59+0200``."""
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file of its own, fsync'ed, then renamed
    (:func:`groundwork.atomic.atomic_file`); the folder is created when missing."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path, fsync=True, unique=True) as tmp, open(tmp, "w", newline="") as f:
        f.write(text)


def subject_dir(study_dir, pid: str) -> Path:
    """``study_dir/sub-<pid>`` (the id checked: :func:`study.design.check_participant_id`)."""
    return Path(study_dir) / f"sub-{check_participant_id(pid)}"


def data_path(study_dir, pid: str) -> Path:
    """The participant's data file, ``sub-<pid>/sub-<pid>_task-emotion_beh.csv``."""
    return subject_dir(study_dir, pid) / f"sub-{pid}_task-{TASK}_beh.csv"


def sidecar_path(study_dir, pid: str) -> Path:
    """The participant's JSON sidecar, ``sub-<pid>/sub-<pid>_task-emotion_beh.json``."""
    return subject_dir(study_dir, pid) / f"sub-{pid}_task-{TASK}_beh.json"


def write_dataset_description(study_dir, *, name: str, simulated: bool) -> Path:
    """Write the psych-DS ``dataset_description.json`` of a study folder (kept if present).

    Parameters
    ----------
    study_dir : path
    name : str
        The data set's name.
    simulated : bool
        Whether the participants are simulated (said in the description).

    Returns
    -------
    pathlib.Path
        The file, new or as it was.
    """
    path = Path(study_dir) / "dataset_description.json"
    if path.is_file():
        return path
    desc = {
        "@context": "https://schema.org/",
        "@type": "Dataset",
        "name": name,
        "description": "Emotion judgments of a synthetic and a real talking face, visual-only, "
                       "audio-only and bimodal (Hong, Wen & Huang 2002, section VII-C), one row "
                       "per judgment." + (" Simulated participants." if simulated else ""),
        "variableMeasured": list(COLUMNS),
        "keywords": ["talking face", "emotion perception", "audio-visual", "psych-DS"],
    }
    write_atomic(path, json.dumps(desc, indent=1) + "\n")
    return path


def read_rows(path: Path) -> tuple[list[dict], bool]:
    """The complete rows of a data file and whether a cut-short last line was found
    (:func:`study.columns.read_data_file` without the header)."""
    _, rows, torn = read_data_file(path)
    return rows, torn


def check_session_file(study_dir, participant_id: str, trials: list[Trial], *,
                       resume: bool = False) -> tuple[list[dict], bool]:
    """The refusals of :class:`SessionFile`, without writing anything.

    Parameters
    ----------
    study_dir : path
    participant_id : str
    trials : list of Trial
        The planned order (27 trials, ``study.design.session_trials``).
    resume : bool
        Whether an interrupted session may be continued.

    Returns
    -------
    rows : list of dict
        The rows already in the participant's data file (none if it does not exist).
    torn : bool
        Whether its last line was cut short.

    Raises
    ------
    ParameterError
        Not 27 trials, a complete session, an interrupted one without ``resume``, rows that
        do not follow ``trials``, and ``resume`` without a data file.
    """
    pid = check_participant_id(participant_id)
    path = data_path(study_dir, pid)
    if len(trials) != N_TRIALS:
        raise ParameterError(f"a session has {N_TRIALS} trials, got {len(trials)}")
    if not path.is_file():
        if resume:
            raise ParameterError(f"--resume: participant {pid} has no session to resume "
                                 f"({path} not found)")
        return [], False
    rows, torn = read_rows(path)
    if len(rows) >= N_TRIALS:
        raise ParameterError(
            f"participant {pid} has a complete session ({len(rows)} judgments in {path}); it "
            "is never overwritten or extended. Use a new participant id.")
    if not resume:
        raise ParameterError(
            f"participant {pid} has an interrupted session ({len(rows)} of {N_TRIALS} "
            f"judgments in {path}); continue it with --resume, or use a new participant id")
    for i, row in enumerate(rows):
        t = trials[i]
        if (int(row["trial_index"]), row["stimulus_id"], row["block"]) != \
                (t.trial_index, t.stimulus_id, t.block):
            raise ParameterError(
                f"{path}, row {i + 2}: trial {row['trial_index']} ({row['stimulus_id']}) does "
                f"not match the planned order (trial {t.trial_index}, {t.stimulus_id}); was "
                "the study seed or the allocation changed? Nothing was written.")
    return rows, torn


class SessionFile:
    """The data file of one participant: opened for a new session or to resume one.

    Parameters
    ----------
    study_dir : path
    participant_id : str
    trials : list of Trial
        The planned order (``study.design.session_trials``).
    resume : bool
        Continue a partial session (refused otherwise); a complete one is always refused.
    """

    def __init__(self, study_dir, participant_id: str, trials: list[Trial], *,
                 resume: bool = False):
        self.pid = check_participant_id(participant_id)
        self.path = data_path(study_dir, self.pid)
        self.trials = list(trials)
        if len(self.trials) != N_TRIALS:
            raise ParameterError(f"a session has {N_TRIALS} trials, got {len(self.trials)}")
        rows, torn = check_session_file(study_dir, self.pid, self.trials, resume=resume)
        # a file begun by an older version keeps its own columns (appended rows match them)
        fields = read_data_file(self.path)[0] if rows else None
        self.fields = tuple(fields) if fields and set(fields) <= set(COLUMNS) else COLUMNS
        if torn:  # the trial in progress when the session died: it is asked again
            with open(self.path, "r+b") as f:
                data = f.read()
                f.seek(0)
                f.truncate(data.rfind(b"\n") + 1)
                f.flush()
                os.fsync(f.fileno())
        self.dropped_partial = torn
        self.done: list[dict] = rows

    @property
    def remaining(self) -> list[Trial]:
        """The planned trials not yet in the file, in order."""
        return self.trials[len(self.done):]

    @property
    def complete(self) -> bool:
        """Whether all 27 judgments are in the file."""
        return len(self.done) >= N_TRIALS

    def append(self, row: dict) -> None:
        """Append one judgment and fsync it before returning.

        Parameters
        ----------
        row : dict
            Every column of the contract (:func:`trial_row`), for the next planned trial.

        Raises
        ------
        ParameterError
            A missing column, an unknown response, another participant's row, or a trial out
            of the planned order.
        """
        missing = [c for c in COLUMNS if c not in row]
        if missing:
            raise ParameterError(f"a data row lacks {missing}")
        if row["response"] not in RESPONSES:
            raise ParameterError(f"response {row['response']!r}; allowed: "
                                 f"{', '.join(RESPONSES)}")
        if row["participant_id"] != self.pid:
            raise ParameterError(f"a row of participant {row['participant_id']!r} cannot go to "
                                 f"{self.path}")
        expected = self.trials[len(self.done)]
        if int(row["trial_index"]) != expected.trial_index:
            raise ParameterError(f"trial {row['trial_index']} written out of order (expected "
                                 f"{expected.trial_index})")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        new = not self.path.is_file() or self.path.stat().st_size == 0
        text = csv_text([row], header=new, fields=self.fields if not new else COLUMNS)
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, text.encode("utf-8"))
            os.fsync(fd)
        finally:
            os.close(fd)
        if new:
            self.fields = COLUMNS
        self.done.append({c: str(row[c]) for c in self.fields})


def trial_row(trial: Trial, *, participant_id: str, sequence: str, response: str,
              response_key: str, rt_s: float, simulated: bool, responder_model: str,
              session: int, site: str, qc: dict | None = None, web: dict | None = None,
              timestamp: str | None = None) -> dict:
    """A data row for one judgment, with every column of the contract.

    Parameters
    ----------
    trial : Trial
        The trial judged (block, period, trial index, face, expression, audio, stimulus id).
    participant_id, sequence : str
        The participant and their sequence (``SR`` or ``RS``; the group follows from it).
    response : str
        One of ``study.design.RESPONSES``.
    response_key : str
        The key pressed.
    rt_s : float
        Response time in seconds (written with 4 decimals).
    simulated : bool
    responder_model : str
        ``human``, or the model that answered.
    session : int
        1 for a first session, 2 … for a resumed one.
    site : str
        Where the session ran (:data:`study.columns.SITES`: ``lab``, ``web``, or ``none`` for
        files a simulation writes directly).
    qc : dict, optional
        The frame-timing columns (``n_frames``, ``frames_late``, ``frame_interval_ms_mean``,
        ``frame_interval_ms_max`` in ms, ``audio_onset_s`` in s); blank when absent.
    web : dict, optional
        What a browser measured (:data:`study.columns.WEB_COLUMNS`: times in ms, the browser,
        the refresh rate in Hz, ``fullscreen`` and ``focused`` as booleans); blank when absent.
    timestamp : str, optional
        The wall-clock time of the answer, now by default; simulated rows pass "".

    Returns
    -------
    dict
        Column → value (numbers formatted as the file holds them).
    """
    if site not in SITES:
        raise ParameterError(f"site {site!r}; allowed: {', '.join(SITES)}")
    qc, web = qc or {}, web or {}
    return {"participant_id": participant_id, "group": group_of(sequence), "sequence": sequence,
            **{k: v for k, v in trial.as_dict().items()},
            "response": response, "response_key": response_key, "rt_s": f"{rt_s:.4f}",
            "simulated": str(bool(simulated)).lower(), "responder_model": responder_model,
            "session": session,
            "n_frames": qc.get("n_frames", ""), "frames_late": qc.get("frames_late", ""),
            "frame_interval_ms_mean": _fmt(qc.get("frame_interval_ms_mean")),
            "frame_interval_ms_max": _fmt(qc.get("frame_interval_ms_max")),
            "audio_onset_s": _fmt(qc.get("audio_onset_s")),
            "timestamp": now_iso() if timestamp is None else timestamp, "site": site,
            **{c: _web_value(web.get(c)) for c in WEB_COLUMNS}}


def _fmt(v) -> str:
    return "" if v is None else f"{float(v):.4f}"


def _web_value(v) -> str:
    """A browser's measure as the file holds it: booleans ``true``/``false``, numbers with
    two decimals (times in ms, Hz), text as it is, blank when absent."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, (int, float)):
        return f"{float(v):.2f}"
    return str(v)


class Allocation:
    """The pre-generated allocation list of a study folder (see the module text)."""

    def __init__(self, study_dir):
        self.dir = Path(study_dir)
        self.path = self.dir / "allocation.csv"
        self.log_path = self.dir / "allocation_log.csv"
        self.meta_path = self.dir / "allocation.json"

    def _lock(self):
        self.dir.mkdir(parents=True, exist_ok=True)
        return FileLock(str(self.dir / ".allocation.lock"), timeout=30)

    def create(self, n: int, seed: int) -> list[dict]:
        """Write the list of ``n`` slots, or return the list already there if it is the same.

        Parameters
        ----------
        n : int
            Number of slots (participants).
        seed : int
            Seeds the permuted blocks of sequences (:func:`study.design.allocation_sequences`).

        Returns
        -------
        list of dict
            The rows of ``allocation.csv``.

        Raises
        ------
        ParameterError
            The folder already holds a list made with another ``(n, seed)``.
        """
        seqs = allocation_sequences(n, seed)
        with self._lock():
            if self.path.is_file():
                meta = json.loads(self.meta_path.read_text()) if self.meta_path.is_file() else {}
                if (meta.get("n"), meta.get("seed")) != (n, seed):
                    raise ParameterError(
                        f"{self.path} already holds an allocation list (n={meta.get('n')}, "
                        f"seed={meta.get('seed')}); it is never replaced. Use another study "
                        "folder for a different list.")
                return self.rows()
            rows = [{"slot": i + 1, "sequence": s, "participant_id": "", "status": "free",
                     "updated": ""} for i, s in enumerate(seqs)]
            write_atomic(self.meta_path, json.dumps({"n": n, "seed": seed,
                                                     "block_size": 4,
                                                     "created": now_iso()}, indent=1) + "\n")
            self._write(rows)
            self._log("created", "", "", "", f"n={n} seed={seed}")
            return rows

    def rows(self) -> list[dict]:
        """The rows of ``allocation.csv``, checked (a damaged list is refused)."""
        if not self.path.is_file():
            raise ParameterError(f"no allocation list in {self.dir} ({self.path.name} missing): "
                                 "create one with `talkingface study allocate`")
        with open(self.path, newline="", encoding="utf-8-sig") as f:  # as saved by Excel, too
            reader = csv.DictReader(f)
            rows = list(reader)
        missing = [c for c in ALLOCATION_COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise ParameterError(f"{self.path}: missing columns {missing}; the list is damaged "
                                 f"(its history is in {self.log_path.name})")
        for line, r in enumerate(rows, start=2):
            if r["sequence"] not in SEQUENCES or r["status"] not in ALLOCATION_STATUSES:
                raise ParameterError(
                    f"{self.path}, line {line}: sequence {r['sequence']!r}, status "
                    f"{r['status']!r}; allowed: sequence {' or '.join(SEQUENCES)}, status "
                    f"{', '.join(ALLOCATION_STATUSES)}; the list is damaged (its history is in "
                    f"{self.log_path.name})")
        return rows

    def _write(self, rows: list[dict]) -> None:
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=ALLOCATION_COLUMNS, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
        write_atomic(self.path, buf.getvalue())

    def _log(self, event, slot, sequence, pid, note="") -> None:
        new = not self.log_path.is_file()
        with open(self.log_path, "a", newline="") as f:
            w = csv.DictWriter(f, fieldnames=LOG_COLUMNS, lineterminator="\n")
            if new:
                w.writeheader()
            w.writerow({"time": now_iso(), "event": event, "slot": slot, "sequence": sequence,
                        "participant_id": pid, "note": note})
            f.flush()
            os.fsync(f.fileno())

    def slot_for(self, pid: str, rows: list[dict] | None = None) -> dict:
        """The slot ``pid`` holds, else the first free one, in ``rows`` (default: the list as
        it is); nothing is written. A full list is refused."""
        rows = self.rows() if rows is None else rows
        held = [r for r in rows if r["participant_id"] == pid]
        if held:
            return held[0]
        free = [r for r in rows if r["status"] == "free"]
        if not free:
            raise ParameterError(f"every slot of {self.path} is taken ({len(rows)} "
                                 "participants); extend the study with a new list in "
                                 "another folder, or release an aborted slot")
        return free[0]

    def assign(self, pid: str) -> dict:
        """The participant's slot: the one they hold, else the first free one (logged)."""
        check_participant_id(pid)
        with self._lock():
            rows = self.rows()
            slot = self.slot_for(pid, rows)
            if slot["participant_id"] == pid:
                return slot
            slot.update(participant_id=pid, status="assigned", updated=now_iso())
            self._write(rows)
            self._log("assigned", slot["slot"], slot["sequence"], pid)
            return slot

    def set_status(self, pid: str, status: str) -> None:
        """Mark the participant's slot ``assigned`` or ``complete`` (logged)."""
        if status not in ("assigned", "complete"):
            raise ParameterError(f"allocation status {status!r}; allowed: assigned, complete")
        with self._lock():
            rows = self.rows()
            for r in rows:
                if r["participant_id"] == pid:
                    r.update(status=status, updated=now_iso())
                    self._write(rows)
                    self._log(status, r["slot"], r["sequence"], pid)
                    return
            raise ParameterError(f"participant {pid} holds no slot in {self.path}")

    def release(self, pid: str, note: str = "") -> dict:
        """Give an aborted participant's slot back to the pool (their data stay; logged)."""
        check_participant_id(pid)
        if not self.path.is_file():  # checked before the lock, which would make the folder
            raise ParameterError(f"{self.path} not found: {self.dir} holds no allocation list, "
                                 "so there is no slot to release")
        with self._lock():
            rows = self.rows()
            for r in rows:
                if r["participant_id"] == pid:
                    if r["status"] == "complete":
                        raise ParameterError(f"participant {pid} completed their session; "
                                             "a complete slot is not released")
                    self._log("released", r["slot"], r["sequence"], pid, note)
                    r.update(participant_id="", status="free", updated=now_iso())
                    self._write(rows)
                    return r
            raise ParameterError(f"participant {pid} holds no slot in {self.path}")
