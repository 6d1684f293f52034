"""The plan of one participant's session (paper §VII-C), made before any window opens.

Two steps, so that a session that is refused leaves nothing behind:

1. :func:`check_session` makes every refusal that needs no PsychoPy, and writes nothing: the
   participant id and the session's options, the stimulus set and its checksums, the
   allocation list (one made with another seed is refused; so is a full one), the data file (a
   complete session is never reopened, an interrupted one only with ``resume``, in the planned
   order; a resumed session must use the same stimuli), another session of this participant
   running (its lock), and the free disk space. :mod:`study.runner` then checks the display and
   the audio device (which need PsychoPy).
2. :func:`open_session` takes the participant's session lock, claims the allocation slot (the
   one they hold, else the first free one; the list is created with the study seed if the
   folder has none) and opens the data file (``study.data.SessionFile``: a row cut short by a
   crash is dropped there). If it is refused after all (another terminal was quicker), the
   lock file and the folders it made are removed again.

:func:`plan_session` is the two in one. The :class:`SessionPlan` it returns says what the
session will do: the 27 trials in their order, where it resumes, the trials still to run
(:class:`Step`: which stimulus, whether it opens a part of the study and so follows that
part's instruction, whether its response screen is captured), whether the practice trial is
shown, the files it writes and the metadata of the sidecar. :mod:`study.runner` executes it in
a PsychoPy window.
"""
from __future__ import annotations

import json
import math
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from filelock import FileLock, Timeout

from groundwork.errors import ParameterError
from study import data as sdata
from study.design import (RESPONSES, Trial, allocation_sequences, check_participant_id, group_of,
                          participant_seed, session_trials)
from study.stimuli import Stimulus, load_manifest, manifest_digest

AUDIO_BACKENDS = ("sounddevice", "ptb", "none")
# the practice trial: the neutral sentence's audio-only track, so neither face is seen before
# its block; never written
PRACTICE = Trial("audio", 0, -1, "none", "none", "normal", "audio-normal")
LOCK_NAME = ".session.lock"
# the data file, the sidecar, PsychoPy's files and a screenshot take well under 10 MB; the
# margin keeps a session from starting on a disk that is about to be full
MIN_FREE_BYTES = 100 * 2**20


@dataclass(frozen=True)
class Step:
    """One trial still to run: ``part`` is its ``(block, period)`` when it opens that part of
    the study (its instruction is shown first), else None; ``screenshot`` whether its response
    screen is saved (the first bimodal trial of the session, when a screenshot was asked for)."""

    trial: Trial
    stimulus: Stimulus
    part: tuple | None
    screenshot: bool


@dataclass(frozen=True)
class SessionPlan:
    """What one session will do (see the module text); made by :func:`plan_session`.

    ``trials`` are the participant's 27 trials in presentation order; ``start`` the number of
    judgments already in the data file (the resume point) and ``steps`` the trials from there
    on. ``session`` is this session's number and ``earlier_sessions`` the sidecar's records of
    the earlier ones (one left ``running`` by a crash is marked ``interrupted``). ``file`` is the
    open data file and ``lock`` the participant's session lock (:class:`SessionLock`), held
    until :meth:`release`.
    """

    participant_id: str
    sequence: str
    slot: int
    study_dir: Path
    stimuli_dir: Path
    study_seed: int
    stimuli: dict
    manifest_digest: str
    keys: dict
    resume: bool
    practice: bool
    fullscreen: bool
    window_size: tuple
    fixation_s: float
    iti_s: float
    audio_backend: str
    responder_model: str
    screenshot: Path | str | None
    trials: tuple
    start: int
    steps: tuple
    session: int
    earlier_sessions: tuple
    file: sdata.SessionFile
    lock: SessionLock

    @property
    def simulated(self) -> bool:
        """Whether a simulated observer (``flmp…``) answers."""
        return self.responder_model.startswith("flmp")

    @property
    def allocation_path(self) -> Path:
        return sdata.Allocation(self.study_dir).path

    @property
    def data_path(self) -> Path:
        return sdata.data_path(self.study_dir, self.participant_id)

    @property
    def sidecar_path(self) -> Path:
        return sdata.sidecar_path(self.study_dir, self.participant_id)

    def psychopy_base(self, stamp: str) -> Path:
        """PsychoPy's file names without extension, for a session started at ``stamp``."""
        return sdata.subject_dir(self.study_dir, self.participant_id) / "psychopy" / \
            f"sub-{self.participant_id}_ses-{self.session}_{stamp}"

    def record(self, *, start: str, versions: dict, audio_device: str) -> dict:
        """This session's entry of the sidecar's ``sessions`` list, as it starts."""
        return {"session": self.session, "start": start, "resumed": self.resume,
                "rows_at_start": self.start, "dropped_partial_row": self.file.dropped_partial,
                "end": None, "end_state": "running", "rows_at_end": None, "pid": os.getpid(),
                "versions": versions, "responder_model": self.responder_model,
                "audio_backend": self.audio_backend, "audio_device": audio_device,
                "fullscreen": self.fullscreen,
                "window_size": [int(s) for s in self.window_size],
                "practice": self.practice}

    def metadata(self, versions: dict, record: dict) -> dict:
        """The participant's sidecar, with ``record`` as the last session."""
        return {"participant_id": self.participant_id, "task": sdata.TASK,
                "group": group_of(self.sequence), "versions": versions,
                "study_seed": self.study_seed,
                "participant_seed": participant_seed(self.study_seed, self.participant_id),
                "allocation": {"file": str(self.allocation_path), "slot": self.slot,
                               "sequence": self.sequence},
                "stimuli": {"folder": str(Path(self.stimuli_dir).resolve()),
                            "manifest_digest": self.manifest_digest},
                "responder_model": self.responder_model, "simulated": self.simulated,
                "keys": dict(self.keys), "sessions": [*self.earlier_sessions, record]}

    def result(self, end_state: str) -> dict:
        """What :func:`study.runner.run_session` returns once the session has ended."""
        return {"participant_id": self.participant_id, "sequence": self.sequence,
                "rows": len(self.file.done), "complete": self.file.complete,
                "aborted": end_state == "aborted", "data": str(self.file.path),
                "session": self.session, "sidecar": str(self.sidecar_path)}

    def release(self) -> None:
        """Let another session of this participant start."""
        self.lock.release()


def check_options(keys, audio_backend, fixation_s, iti_s, window_size) -> list[str]:
    """The response keys as strings, after checking the session's options."""
    keys = [str(k) for k in keys]
    if len(keys) != len(RESPONSES) or len(set(keys)) != len(keys) or \
            any(not k or k in ("escape", "space") for k in keys):
        raise ParameterError(f"keys {keys}: give {len(RESPONSES)} different keys for "
                             f"{', '.join(RESPONSES)} (not escape or space)")
    if audio_backend not in AUDIO_BACKENDS:
        raise ParameterError(f"audio backend {audio_backend!r}; allowed: "
                             f"{', '.join(AUDIO_BACKENDS)}")
    for name, v in (("fixation_s", fixation_s), ("iti_s", iti_s)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 <= v <= 10):
            raise ParameterError(f"study.{name} = {v!r}; allowed: seconds in [0, 10]")
    if not (len(window_size) == 2 and all(isinstance(s, (int, np.integer)) and s >= 320
                                          for s in window_size)):
        raise ParameterError(f"window size {window_size!r}; allowed: (width, height) >= 320 px")
    return keys


def _missing_folders(folder: Path) -> list[Path]:
    """``folder`` and those of its parents that do not exist yet, deepest first."""
    out, p = [], Path(folder).absolute()
    while not p.exists():
        out.append(p)
        p = p.parent
    return out


def check_disk_space(study_dir, need: int | None = None) -> int:
    """The free bytes on the disk the study folder is (or will be) on; refused below ``need``
    (default :data:`MIN_FREE_BYTES`)."""
    need = MIN_FREE_BYTES if need is None else int(need)
    missing = _missing_folders(study_dir)
    where = missing[-1].parent if missing else Path(study_dir).absolute()
    free = shutil.disk_usage(where).free
    if free < need:
        raise ParameterError(f"only {free / 2**20:.0f} MB free on the disk of {study_dir}; a "
                             f"session needs at least {need / 2**20:.0f} MB: free some space or "
                             "use a study folder on another disk")
    return free


def _running(study_dir, pid: str) -> ParameterError:
    path = sdata.subject_dir(study_dir, pid) / LOCK_NAME
    who = "another process"
    try:  # the running session's own record says which process runs it
        side = json.loads(sdata.sidecar_path(study_dir, pid).read_text(encoding="utf-8"))
        run = [s for s in side.get("sessions", []) if s.get("end_state") == "running"]
        if run and run[-1].get("pid"):
            who = f"process {run[-1]['pid']} (session {run[-1]['session']}, started " \
                  f"{run[-1]['start']})"
    except (OSError, ValueError, AttributeError, KeyError):
        pass
    return ParameterError(f"a session of participant {pid} is already running in {who} "
                          f"(lock {path}); wait for it to end")


def check_not_running(study_dir, pid: str) -> None:
    """Refuse if another session of this participant holds its lock (creates nothing: a lock
    file that does not exist is held by nobody)."""
    path = sdata.subject_dir(study_dir, pid) / LOCK_NAME
    if not path.is_file():
        return
    probe = FileLock(str(path))
    try:
        probe.acquire(timeout=0)
    except Timeout:
        raise _running(study_dir, pid) from None
    probe.release()


@dataclass
class SessionLock:
    """The participant's session lock and what taking it created (the lock file, folders)."""

    lock: FileLock
    made_file: bool
    made_folders: list = field(default_factory=list)  # deepest first

    def release(self) -> None:
        self.lock.release()

    def discard(self) -> None:
        """Release it and remove what taking it created (a session refused after all)."""
        try:
            if self.made_file:  # removed while held: a waiting FileLock sees the unlinked file
                Path(self.lock.lock_file).unlink(missing_ok=True)
        finally:
            self.lock.release()
        for folder in self.made_folders:
            try:
                folder.rmdir()  # only if empty: the allocation list may have been made since
            except OSError:
                break


def session_lock(study_dir, pid: str) -> SessionLock:
    """One session per participant at a time (a second terminal is refused, not interleaved)."""
    folder = sdata.subject_dir(study_dir, pid)
    made = _missing_folders(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_NAME
    made_file = not path.exists()
    lock = FileLock(str(path))
    try:
        lock.acquire(timeout=0)
    except Timeout:
        raise _running(study_dir, pid) from None
    return SessionLock(lock, made_file, made)


def check_slot(study_dir, pid: str, *, study_seed: int, n_slots: int,
               resume: bool) -> tuple[dict | None, bool]:
    """The slot the participant holds (None for a new participant, who will get the first free
    one) and whether the session resumes: a participant who stopped before the first judgment
    starts afresh. Writes nothing; refuses a data file without a slot, a list made with another
    seed, and a full list."""
    alloc = sdata.Allocation(study_dir)
    data_file = sdata.data_path(study_dir, pid)
    rows = alloc.rows() if alloc.path.is_file() else None
    held = next((r for r in rows or [] if r["participant_id"] == pid), None)
    if resume and not data_file.is_file():
        if held is None:
            raise ParameterError(f"--resume: participant {pid} has no session to resume "
                                 f"({data_file} not found)")
        resume = False  # stopped before the first judgment: nothing to resume, start afresh
    if data_file.is_file() and held is None:
        raise ParameterError(f"{data_file} exists but participant {pid} holds no slot in "
                             f"{alloc.path} (was it released?); use a new participant id")
    if rows is None:
        allocation_sequences(n_slots, study_seed)  # checks n_slots; the list is made later
        return None, resume
    made = json.loads(alloc.meta_path.read_text()).get("seed") if alloc.meta_path.is_file() \
        else study_seed
    if made != study_seed:
        raise ParameterError(f"{alloc.path} was made with seed {made}, but this session's study "
                             f"seed is {study_seed}; run with --seed {made} (one seed per study)")
    if held is None:
        alloc.slot_for(pid, rows)  # refuses a full list
    return held, resume


def claim_slot(study_dir, pid: str, *, study_seed: int, n_slots: int,
               resume: bool) -> tuple[dict, bool]:
    """:func:`check_slot`, then the participant's slot: the one they hold, else the first free
    one (the list is created if the folder has none). Refusals change nothing."""
    _, resume = check_slot(study_dir, pid, study_seed=study_seed, n_slots=n_slots,
                           resume=resume)
    alloc = sdata.Allocation(study_dir)
    if not alloc.path.is_file():
        alloc.create(n_slots, study_seed)
    return alloc.assign(pid), resume


def plan_steps(trials, stimuli: dict, *, screenshot: bool) -> tuple[Step, ...]:
    """The trials still to run as :class:`Step`\\ s: a part's instruction before its first
    trial (also when a resumed session starts inside it), and the screenshot on the first
    bimodal trial."""
    steps, part, shot = [], None, bool(screenshot)
    for trial in trials:
        opens = (trial.block, trial.period) != part
        part = (trial.block, trial.period)
        take = shot and trial.block == "bimodal"
        shot = shot and not take
        steps.append(Step(trial, stimuli[trial.stimulus_id], part if opens else None, take))
    return tuple(steps)


def earlier_sessions(sidecar: dict) -> list[dict]:
    """The sidecar's sessions, one left ``running`` (the process died) marked interrupted."""
    return [dict(s, end_state="interrupted") if s.get("end_state") == "running" else s
            for s in sidecar.get("sessions", [])]


@dataclass(frozen=True)
class SessionCheck:
    """A session that passed :func:`check_session` (nothing written yet): its participant,
    study folder, stimuli and the options :func:`open_session` puts into the plan."""

    participant_id: str
    study_dir: Path
    stimuli_dir: Path
    study_seed: int
    n_slots: int
    resume: bool
    stimuli: dict
    manifest_digest: str
    sidecar: dict
    options: dict  # keys, practice, fullscreen, window_size, fixation_s, iti_s, audio_backend,
    #                responder_model, screenshot

    @property
    def probe_wav(self) -> Path:
        """A sound of the study, for the audio device's check (the practice trial's)."""
        return self.stimuli[PRACTICE.stimulus_id].wav


def check_session(study_dir, stimuli_dir, participant_id: str, *, study_seed: int,
                  n_slots: int = 20, resume: bool = False, fullscreen: bool = False,
                  keys=("n", "h", "s", "u"), practice: bool = True, fixation_s: float = 0.5,
                  iti_s: float = 0.5, audio_backend: str = "sounddevice",
                  responder_model: str = "human", screenshot=None,
                  window_size=(1024, 768), min_free_bytes: int | None = None) -> SessionCheck:
    """Every refusal that needs no PsychoPy, writing nothing (see the module text); the
    arguments are :func:`study.runner.run_session`'s. Refusals raise ParameterError."""
    pid = check_participant_id(participant_id)
    keys = check_options(keys, audio_backend, fixation_s, iti_s, window_size)
    study_dir = Path(study_dir)
    if study_dir.exists() and not study_dir.is_dir():
        raise ParameterError(f"--study-dir {study_dir} is a file; give a study folder")
    if screenshot is not None and Path(screenshot).is_dir():
        raise ParameterError(f"--screenshot {screenshot} is a folder; give a .png file name")
    check_not_running(study_dir, pid)  # before the data: a running session is not interrupted
    stimuli = load_manifest(stimuli_dir)  # checksums verified
    held, resume = check_slot(study_dir, pid, study_seed=study_seed, n_slots=n_slots,
                              resume=resume)
    if held is not None:
        sdata.check_session_file(study_dir, pid,
                                 session_trials(pid, held["sequence"], study_seed),
                                 resume=resume)
    side_path = sdata.sidecar_path(study_dir, pid)
    side = json.loads(side_path.read_text()) if side_path.is_file() else {}
    digest = manifest_digest(stimuli)
    if resume and side.get("stimuli", {}).get("manifest_digest", digest) != digest:
        raise ParameterError(f"the stimuli in {stimuli_dir} differ from those of {pid}'s earlier "
                             f"session (manifest digest, see {side_path}); resume with the same "
                             "stimulus set")
    check_disk_space(study_dir, min_free_bytes)
    return SessionCheck(
        participant_id=pid, study_dir=study_dir, stimuli_dir=Path(stimuli_dir),
        study_seed=int(study_seed), n_slots=int(n_slots), resume=bool(resume), stimuli=stimuli,
        manifest_digest=digest, sidecar=side,
        options=dict(keys=dict(zip(RESPONSES, keys)), practice=bool(practice),
                     fullscreen=bool(fullscreen), window_size=tuple(window_size),
                     fixation_s=fixation_s, iti_s=iti_s, audio_backend=audio_backend,
                     responder_model=responder_model, screenshot=screenshot or None))


def open_session(check: SessionCheck) -> SessionPlan:
    """Lock, claim the slot and open the data file of a checked session (see the module
    text). A refusal here (a race with another terminal) removes the lock file and the folders
    the lock made."""
    pid, study_dir = check.participant_id, check.study_dir
    lock = session_lock(study_dir, pid)
    try:
        slot, resume = claim_slot(study_dir, pid, study_seed=check.study_seed,
                                  n_slots=check.n_slots, resume=check.resume)
        trials = session_trials(pid, slot["sequence"], check.study_seed)
        sf = sdata.SessionFile(study_dir, pid, trials, resume=resume)
    except BaseException:
        lock.discard()
        raise
    opts = check.options
    earlier = earlier_sessions(check.sidecar)
    return SessionPlan(
        participant_id=pid, sequence=slot["sequence"], slot=int(slot["slot"]),
        study_dir=study_dir, stimuli_dir=check.stimuli_dir, study_seed=check.study_seed,
        stimuli=check.stimuli, manifest_digest=check.manifest_digest, keys=dict(opts["keys"]),
        resume=bool(resume), practice=opts["practice"] and not resume,
        fullscreen=opts["fullscreen"], window_size=opts["window_size"],
        fixation_s=opts["fixation_s"], iti_s=opts["iti_s"], audio_backend=opts["audio_backend"],
        responder_model=opts["responder_model"], screenshot=opts["screenshot"],
        trials=tuple(trials), start=len(sf.done),
        steps=plan_steps(sf.remaining, check.stimuli, screenshot=bool(opts["screenshot"])),
        session=len(earlier) + 1, earlier_sessions=tuple(earlier), file=sf, lock=lock)


def plan_session(study_dir, stimuli_dir, participant_id: str, **options) -> SessionPlan:
    """:func:`check_session` then :func:`open_session` (keyword arguments: those of
    :func:`check_session`, e.g. ``study_seed``). Refusals raise ParameterError."""
    return open_session(check_session(study_dir, stimuli_dir, participant_id, **options))
