"""The files of simulated participants (:func:`study.simulate.simulate_study`), as an
uninterrupted run writes them, and the checks that let an interrupted run be resumed: a file
already in the study folder must be what the simulation writes (a data file may be cut short),
else it is refused before anything is written."""
from __future__ import annotations

import json
from pathlib import Path

from groundwork.errors import ParameterError
from study.columns import csv_text
from study.data import (
    Allocation,
    SessionFile,
    data_path,
    read_rows,
    sidecar_path,
    trial_row,
    write_atomic,
)
from study.design import N_TRIALS, group_of, participant_seed, session_trials

RESPONDER_MODEL = "flmp-v1"


class SimulatedParticipant:
    """One simulated participant's data rows and sidecar, computed once (``answer``, a
    ``trial -> (response, rt_s)`` function, draws from the observer's random stream).

    Parameters
    ----------
    pid : str
    slot : dict
        Their row of the allocation list (``slot``, ``sequence``, ``status``).
    answer : callable
    study_seed : int
    key_of : dict
        Response → key.
    sidecar : dict
        The participant's own sidecar fields (index, observer seed and parameters).
    common : dict
        The sidecar fields every participant shares.
    """

    def __init__(self, pid: str, slot: dict, answer, *, study_seed: int, key_of: dict,
                 sidecar: dict, common: dict):
        self.pid, self.slot, self.sequence = pid, slot, slot["sequence"]
        self.trials = session_trials(pid, self.sequence, study_seed)
        self.rows = []
        for trial in self.trials:
            response, rt = answer(trial)
            self.rows.append(trial_row(
                trial, participant_id=pid, sequence=self.sequence, response=response,
                response_key=key_of[response], rt_s=rt, simulated=True,
                responder_model=RESPONDER_MODEL, session=1, site="none", qc=None,
                timestamp=""))  # no session happened at any time: reproducible files
        side = {"participant_id": pid, "participant_index": sidecar["participant_index"],
                "sequence": self.sequence, "group": group_of(self.sequence),
                "slot": int(slot["slot"]),
                "participant_seed": participant_seed(study_seed, pid),
                "observer_seed": sidecar["observer_seed"], "observer": sidecar["observer"],
                "n_trials": N_TRIALS,
                "sessions": [{"session": 1, "n_trials": N_TRIALS, "complete": True}], **common}
        self.sidecar = json.dumps(side, indent=1) + "\n"

    def check_files(self, study_dir) -> bool:
        """Whether the participant's files are complete; refuses files that are not (the
        start of) what this simulation writes. Writes nothing."""
        data, side = data_path(study_dir, self.pid), sidecar_path(study_dir, self.pid)
        if data.is_file() and not csv_text(self.rows).encode("utf-8").startswith(data.read_bytes()):
            raise _not_ours(data)
        if side.is_file() and side.read_text() != self.sidecar:
            raise _not_ours(side)
        return data.is_file() and len(read_rows(data)[0]) == N_TRIALS and side.is_file()

    def write(self, study_dir, alloc: Allocation) -> None:
        """Complete the participant's files and slot (nothing written is rewritten; a row cut
        short by the interruption is dropped and written again)."""
        data, side = data_path(study_dir, self.pid), sidecar_path(study_dir, self.pid)
        if not (data.is_file() and len(read_rows(data)[0]) == N_TRIALS):
            session = SessionFile(study_dir, self.pid, self.trials, resume=data.is_file())
            for row in self.rows[len(session.done):]:
                session.append(row)
        if not side.is_file():
            write_atomic(side, self.sidecar)
        if self.slot["status"] != "complete":
            alloc.set_status(self.pid, "complete")


def _not_ours(path: Path) -> ParameterError:
    return ParameterError(
        f"{path} is not what this simulation writes (was it made with another seed, study "
        "seed, population, classifier, stimuli or package versions?); an interrupted "
        "simulation is resumed only with the settings it started with: use those, or a new "
        "study folder")


def check_allocation(alloc: Allocation, pids: list[str], *, n: int,
                      study_seed: int) -> list[dict]:
    """The rows of the folder's allocation list that hold a participant ([] if there is no
    list yet); refuses a list made for another ``(n, study_seed)`` or holding a participant
    who is not simulated. Writes nothing."""
    if not alloc.path.is_file():
        return []
    meta = json.loads(alloc.meta_path.read_text()) if alloc.meta_path.is_file() else {}
    if (meta.get("n"), meta.get("seed")) != (n, study_seed):
        raise ParameterError(f"{alloc.path} already holds an allocation list (n={meta.get('n')}, "
                             f"seed={meta.get('seed')}), not the one of this simulation (n={n}, "
                             f"study seed={study_seed}); it is never replaced. Use another "
                             "study folder, or the settings it was made with.")
    rows = [r for r in alloc.rows() if r["participant_id"]]
    foreign = sorted({r["participant_id"] for r in rows} - set(pids))
    if foreign:
        raise ParameterError(f"{alloc.path} holds slots of participants {foreign}, who are not "
                             "simulated; simulate into a separate study folder")
    return rows
