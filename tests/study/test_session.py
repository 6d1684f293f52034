"""The session plan (study/session.py), without a window or PsychoPy: the trials and their
order for both sequences, where a session resumes, the parts' instructions and the screenshot,
the files and the sidecar's metadata, and the refusals (which change nothing)."""
from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

from groundwork.errors import ParameterError
from study.data import Allocation, data_path, read_rows, sidecar_path, trial_row, write_atomic
from study.design import N_TRIALS, RESPONSES, required_stimuli, session_trials
from study.session import (PRACTICE, check_disk_space, check_options, check_session,
                           earlier_sessions, open_session, plan_session, plan_steps)
from study.stimuli import COLUMNS, MANIFEST, load_manifest
from talkingface.config import Config

SEED = Config().seed
PARTS = [("visual", 0)] * 6 + [("audio", 0)] * 3 + [("bimodal", 1)] * 9 + [("bimodal", 2)] * 9
VERSIONS = {"python": "3", "psychopy": "x", "numpy": "2"}


@pytest.fixture(scope="module")
def stimuli_dir(tmp_path_factory):
    """A manifest of every stimulus the design plays, over small stand-in files (the plan
    checks that they exist and records their checksums; it never decodes them)."""
    out = tmp_path_factory.mktemp("stimuli")
    rows = []
    for sid in required_stimuli():
        face, expr, audio = sid.split("-") if sid.count("-") == 2 else ("none", "none",
                                                                        sid.split("-")[1])
        files = {"wav": f"audio/audio-{audio}.wav"}
        if face != "none":
            files.update(video=f"video/{sid}.mp4", markers=f"markers/{sid}.npy")
        for rel in files.values():
            (out / rel).parent.mkdir(parents=True, exist_ok=True)
            (out / rel).write_bytes(rel.encode())
        rows.append({"stimulus_id": sid, "kind": "video" if face != "none" else "audio",
                     "face": face, "expression": expr, "audio": audio, "video": "", "markers": "",
                     **files, "n_frames": 20, "fps": 30, "duration_s": "0.6667",
                     "sha256_video": "", "sha256_wav": "", "sha256_markers": ""})
    with open(out / MANIFEST, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    return out


@pytest.fixture
def study(tmp_path):
    """A study folder whose allocation list (4 slots, the default seed) is held by P01–P04."""
    study = tmp_path / "study_data"
    alloc = Allocation(study)
    alloc.create(4, SEED)
    for i in range(1, 5):
        alloc.assign(f"P{i:02d}")
    return study


def pid_of(study, sequence) -> str:
    return next(r["participant_id"] for r in Allocation(study).rows()
                if r["sequence"] == sequence)


def plan(study, stimuli_dir, pid, **kw):
    kw.setdefault("study_seed", SEED)
    return plan_session(study, stimuli_dir, pid, **kw)


def judge(p, k):
    """Write the first ``k`` judgments of plan ``p`` to its data file."""
    for trial in p.trials[:k]:
        p.file.append(trial_row(trial, participant_id=p.participant_id, sequence=p.sequence,
                                response="sad", response_key="s", rt_s=0.5, simulated=False,
                                responder_model="test", session=p.session, site="lab"))


def crash(p):
    """Leave the sidecar as a session that died while running (the runner's first save)."""
    write_atomic(p.sidecar_path, json.dumps(p.metadata(VERSIONS, p.record(
        start="t0", versions=VERSIONS, audio_device=""))) + "\n")


def snapshot(folder: Path) -> dict:
    return {q: q.read_bytes() for q in sorted(folder.rglob("*")) if q.is_file()}


# --- a fresh session ------------------------------------------------------------------------
@pytest.mark.parametrize("sequence", ["SR", "RS"])
def test_fresh_session_plays_the_design_in_order(study, stimuli_dir, sequence):
    pid = pid_of(study, sequence)
    p = plan(study, stimuli_dir, pid, screenshot="shot.png", keys=("a", "b", "c", "d"))
    try:
        trials = session_trials(pid, sequence, SEED)
        assert (p.participant_id, p.sequence, p.resume, p.practice, p.session, p.start) == \
            (pid, sequence, False, True, 1, 0)
        assert p.trials == tuple(trials) and len(p.steps) == N_TRIALS
        assert [s.trial for s in p.steps] == trials
        assert all(s.stimulus.stimulus_id == s.trial.stimulus_id for s in p.steps)
        assert [(s.trial.block, s.trial.period) for s in p.steps] == PARTS
        opens = {i: s.part for i, s in enumerate(p.steps) if s.part is not None}
        assert opens == {0: ("visual", 0), 6: ("audio", 0), 9: ("bimodal", 1),
                         18: ("bimodal", 2)}
        first, second = ("synthetic", "real") if sequence == "SR" else ("real", "synthetic")
        assert {s.trial.face for s in p.steps[9:18]} == {first}
        assert {s.trial.face for s in p.steps[18:]} == {second}
        assert [i for i, s in enumerate(p.steps) if s.screenshot] == [9]  # first bimodal
        assert p.stimuli[PRACTICE.stimulus_id].wav.is_file()
        assert p.keys == dict(zip(RESPONSES, "abcd"))
        assert (p.data_path, p.sidecar_path) == (data_path(study, pid), sidecar_path(study, pid))
        assert p.file.path == p.data_path and not p.data_path.exists()  # nothing written yet
        assert p.psychopy_base("20260101T000000") == \
            study / f"sub-{pid}" / "psychopy" / f"sub-{pid}_ses-1_20260101T000000"
        assert p.result("aborted") == {
            "participant_id": pid, "sequence": sequence, "rows": 0, "complete": False,
            "aborted": True, "data": str(data_path(study, pid)), "session": 1,
            "sidecar": str(sidecar_path(study, pid))}
    finally:
        p.release()


def test_the_sidecar_metadata(study, stimuli_dir):
    pid = pid_of(study, "RS")
    p = plan(study, stimuli_dir, pid, responder_model="flmp-v1", fullscreen=1,
             window_size=(800, 600), audio_backend="none")
    p.release()
    this = p.record(start="t0", versions=VERSIONS, audio_device="null")
    assert list(this) == ["session", "start", "resumed", "rows_at_start", "dropped_partial_row",
                          "end", "end_state", "rows_at_end", "pid", "versions", "responder_model",
                          "audio_backend", "audio_device", "fullscreen", "window_size",
                          "practice"]
    assert (this["end_state"], this["audio_backend"], this["fullscreen"],
            this["window_size"]) == ("running", "none", True, [800, 600])
    meta = p.metadata(VERSIONS, this)
    slot = next(r for r in Allocation(study).rows() if r["participant_id"] == pid)
    assert list(meta) == ["participant_id", "task", "group", "versions", "study_seed",
                          "participant_seed", "allocation", "stimuli", "responder_model",
                          "simulated", "keys", "sessions"]
    assert meta["group"] == "real_first" and meta["simulated"] is True
    assert meta["allocation"] == {"file": str(study / "allocation.csv"),
                                  "slot": int(slot["slot"]), "sequence": "RS"}
    assert meta["stimuli"] == {"folder": str(stimuli_dir.resolve()),
                               "manifest_digest": p.manifest_digest}
    assert meta["sessions"] == [this] and meta["keys"] == dict(zip(RESPONSES, "nhsu"))


def test_a_new_participant_gets_the_first_free_slot(tmp_path, stimuli_dir):
    study = tmp_path / "study_data"
    p = plan(study, stimuli_dir, "P01", n_slots=8)  # the list is created with the study seed
    p.release()
    rows = Allocation(study).rows()
    assert len(rows) == 8 and rows[0]["participant_id"] == "P01"
    assert (p.slot, p.sequence) == (1, rows[0]["sequence"])


# --- resuming -------------------------------------------------------------------------------
@pytest.mark.parametrize("sequence, k", [("SR", 4), ("RS", 10), ("SR", 20)])
def test_resume_after_k_judgments(study, stimuli_dir, sequence, k):
    pid = pid_of(study, sequence)
    first = plan(study, stimuli_dir, pid, screenshot="shot.png")
    crash(first)
    judge(first, k)
    first.release()
    p = plan(study, stimuli_dir, pid, resume=True, screenshot="shot.png")
    try:
        assert (p.resume, p.practice, p.start, p.session) == (True, False, k, 2)
        assert p.trials == first.trials
        assert [s.trial for s in p.steps] == list(first.trials[k:])
        assert p.steps[0].part == PARTS[k]  # the instruction of the part it resumes in
        assert [i for i, s in enumerate(p.steps, start=k) if s.screenshot] == [max(k, 9)]
        assert [s["end_state"] for s in p.earlier_sessions] == ["interrupted"]
        assert p.record(start="t1", versions=VERSIONS, audio_device="")["rows_at_start"] == k
    finally:
        p.release()


def test_a_row_cut_short_is_asked_again(study, stimuli_dir):
    pid = pid_of(study, "SR")
    first = plan(study, stimuli_dir, pid)
    judge(first, 5)
    first.release()
    with open(data_path(study, pid), "ab") as f:
        f.write(b"P01,synthetic_first,SR,vis")  # the trial in progress when the power failed
    p = plan(study, stimuli_dir, pid, resume=True)
    p.release()
    assert p.start == 5 and p.steps[0].trial == p.trials[5] and p.file.dropped_partial
    assert len(read_rows(data_path(study, pid))[0]) == 5


def test_stopped_before_the_first_judgment_starts_afresh(study, stimuli_dir):
    pid = pid_of(study, "RS")
    p = plan(study, stimuli_dir, pid, resume=True)  # the slot is held, the data file absent
    p.release()
    assert (p.resume, p.practice, p.start, len(p.steps)) == (False, True, 0, N_TRIALS)


def test_earlier_sessions():
    side = {"sessions": [{"session": 1, "end_state": "aborted"},
                         {"session": 2, "end_state": "running"}]}
    assert [s["end_state"] for s in earlier_sessions(side)] == ["aborted", "interrupted"]
    assert earlier_sessions({}) == []


def test_plan_steps_without_screenshot(stimuli_dir):
    trials = session_trials("P01", "SR", SEED)
    steps = plan_steps(trials[7:], load_manifest(stimuli_dir), screenshot=False)
    assert not any(s.screenshot for s in steps)
    assert [s.part for s in steps if s.part] == [("audio", 0), ("bimodal", 1), ("bimodal", 2)]


# --- refusals -------------------------------------------------------------------------------
def test_refusals_change_nothing(study, stimuli_dir, tmp_path):
    done, partial = pid_of(study, "SR"), pid_of(study, "RS")
    p = plan(study, stimuli_dir, done)
    judge(p, N_TRIALS)
    p.release()
    p = plan(study, stimuli_dir, partial)
    crash(p)
    judge(p, 3)
    p.release()
    files = snapshot(study)
    refusals = [
        (dict(pid=done), "has a complete session"),
        (dict(pid=done, resume=True), "has a complete session"),
        (dict(pid=partial), "has an interrupted session"),
        (dict(pid="P99", resume=True), "no session to resume"),
        (dict(pid=partial, study_seed=SEED + 1), f"was made with seed {SEED}"),
        (dict(pid=partial, resume=True, stimuli=tmp_path / "nowhere"),
         "manifest.csv: manifest not found"),
        (dict(pid="../x"), "participant id '../x' is not allowed"),
        (dict(pid=partial, keys=("n", "h", "s", "escape")), "different keys"),
        (dict(pid=partial, keys=("n", "n", "s", "u")), "different keys"),
        (dict(pid=partial, audio_backend="pulse"), "audio backend 'pulse'"),
        (dict(pid=partial, iti_s=11), "study.iti_s = 11"),
        (dict(pid=partial, window_size=(200, 100)), "window size"),
    ]
    for kw, message in refusals:
        pid, stim = kw.pop("pid"), kw.pop("stimuli", stimuli_dir)
        with pytest.raises(ParameterError, match=message.replace("(", r"\(")):
            plan(study, stim, pid, **kw)
    assert snapshot(study) == files
    p = plan(study, stimuli_dir, partial, resume=True)  # no refusal kept the lock
    p.release()


def test_a_released_participants_file_is_refused(study, stimuli_dir):
    pid = pid_of(study, "SR")
    p = plan(study, stimuli_dir, pid)
    judge(p, 2)
    p.release()
    Allocation(study).release(pid)
    with pytest.raises(ParameterError, match="holds no slot"):
        plan(study, stimuli_dir, pid, resume=True)


def test_resuming_with_other_stimuli_is_refused(study, stimuli_dir, tmp_path):
    pid = pid_of(study, "RS")
    p = plan(study, stimuli_dir, pid)
    crash(p)
    judge(p, 2)
    p.release()
    other = tmp_path / "other"
    other.mkdir()
    for q in stimuli_dir.rglob("*"):
        if q.is_file():
            (other / q.relative_to(stimuli_dir)).parent.mkdir(parents=True, exist_ok=True)
            (other / q.relative_to(stimuli_dir)).write_bytes(q.read_bytes())
    (other / "audio" / "audio-good.wav").write_bytes(b"another reading")
    rows = list(csv.DictReader(open(other / MANIFEST, newline="")))
    for r in rows:
        r["sha256_wav"] = ""
    with open(other / MANIFEST, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    with pytest.raises(ParameterError, match="differ from those of"):
        plan(study, other, pid, resume=True)


def test_a_second_session_at_the_same_time_is_refused(study, stimuli_dir):
    pid = pid_of(study, "SR")
    p = plan(study, stimuli_dir, pid)
    try:
        with pytest.raises(ParameterError, match="is already running"):
            plan(study, stimuli_dir, pid)
    finally:
        p.release()


def test_check_options():
    assert check_options(("n", "h", "s", 1), "none", 0, 10, (320, 320)) == ["n", "h", "s", "1"]
    with pytest.raises(ParameterError, match=r"study\.fixation_s = nan"):
        check_options("nhsu", "none", float("nan"), 0, (320, 320))


def test_planning_needs_no_psychopy(tmp_path, stimuli_dir):
    code = ("import sys; from study.session import plan_session; "
            "p = plan_session(sys.argv[1], sys.argv[2], 'P01', study_seed=1); p.release(); "
            "assert not {'psychopy', 'pyglet'} & set(sys.modules), sorted(sys.modules)")
    res = subprocess.run([sys.executable, "-c", code, str(tmp_path / "s"), str(stimuli_dir)],
                         capture_output=True, text=True, cwd=Path(__file__).parents[2])
    assert res.returncode == 0, res.stderr[-2000:]


# --- nothing lost, nothing executed: refusals leave no slot, lock or folder -------------------
def test_a_trailing_newline_is_not_part_of_a_participant_id(study, stimuli_dir):
    files = snapshot(study)
    with pytest.raises(ParameterError, match=r"participant id 'P01\\n' is not allowed"):
        plan(study, stimuli_dir, "P01\n")  # re.match(r"^...$") would have let it through
    assert snapshot(study) == files
    assert sorted(q.name for q in study.iterdir() if q.is_dir()) == []


def _manifest_rows(stimuli_dir):
    with open(stimuli_dir / MANIFEST, newline="") as f:
        return list(csv.DictReader(f))


def _copy_stimuli(stimuli_dir, dst, rows, *, encoding="utf-8"):
    for q in stimuli_dir.rglob("*"):
        if q.is_file() and q.name != MANIFEST:
            (dst / q.relative_to(stimuli_dir)).parent.mkdir(parents=True, exist_ok=True)
            (dst / q.relative_to(stimuli_dir)).write_bytes(q.read_bytes())
    with open(dst / MANIFEST, "w", newline="", encoding=encoding) as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\r\n")
        w.writeheader()
        w.writerows(rows)
    return dst


def test_a_stimulus_id_with_a_trailing_newline_is_refused(stimuli_dir, tmp_path):
    rows = _manifest_rows(stimuli_dir)
    rows[3]["stimulus_id"] += "\n"
    other = _copy_stimuli(stimuli_dir, tmp_path / "stimuli", rows)
    with pytest.raises(ParameterError, match=r"manifest\.csv, line 5: stimulus id "
                                             r"'[a-z-]+\\n' is not allowed"):
        load_manifest(other)


def test_a_manifest_saved_by_excel_is_read(stimuli_dir, tmp_path):
    """Excel writes a byte-order mark (and CRLF line ends): the first column is still
    ``stimulus_id``."""
    other = _copy_stimuli(stimuli_dir, tmp_path / "stimuli", _manifest_rows(stimuli_dir),
                          encoding="utf-8-sig")
    assert (other / MANIFEST).read_bytes().startswith(b"\xef\xbb\xbf")
    assert sorted(load_manifest(other)) == sorted(required_stimuli())


def test_an_allocation_list_and_data_file_saved_by_excel_are_read(study, stimuli_dir):
    pid = pid_of(study, "SR")
    p = plan(study, stimuli_dir, pid)
    crash(p)
    judge(p, 3)
    p.release()
    for path in (study / "allocation.csv", data_path(study, pid)):
        path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    assert [r["participant_id"] for r in Allocation(study).rows()] == \
        ["P01", "P02", "P03", "P04"]
    p = plan(study, stimuli_dir, pid, resume=True)
    p.release()
    assert (p.start, p.sequence) == (3, "SR") and p.file.done[0]["participant_id"] == pid


def test_checking_a_session_writes_nothing(tmp_path, stimuli_dir):
    study = tmp_path / "new" / "study_data"  # not there yet
    check = check_session(study, stimuli_dir, "P01", study_seed=SEED, n_slots=8)
    assert (check.participant_id, check.resume, check.n_slots) == ("P01", False, 8)
    assert check.probe_wav == load_manifest(stimuli_dir)["audio-normal"].wav
    assert not (tmp_path / "new").exists()
    p = open_session(check)  # now the folder, the list, the slot and the lock
    p.release()
    assert (study / "sub-P01" / ".session.lock").is_file()
    assert Allocation(study).rows()[0]["participant_id"] == "P01"


def test_too_little_disk_space_is_refused_before_anything_is_written(study, stimuli_dir,
                                                                     monkeypatch):
    files = snapshot(study)
    with pytest.raises(ParameterError, match=r"MB free on the disk of .*study_data; a session "
                                             r"needs at least 1000000 MB"):
        plan(study, stimuli_dir, "P01", min_free_bytes=10**6 * 2**20)
    free = type("Usage", (), {"free": 2**20})()
    monkeypatch.setattr("study.session.shutil.disk_usage", lambda path: free)
    with pytest.raises(ParameterError, match=r"only 1 MB free"):
        plan(study, stimuli_dir, "P01")
    assert snapshot(study) == files and not (study / "sub-P01").exists()
    assert check_disk_space(study, need=2**20) == 2**20


def test_a_session_refused_after_the_lock_removes_the_lock_and_its_folder(tmp_path, stimuli_dir):
    """Between the check and the claim, another terminal took the last slot: the refusal
    leaves no lock file, no participant folder and no slot behind."""
    study = tmp_path / "study_data"
    Allocation(study).create(2, SEED)
    Allocation(study).assign("P01")
    check = check_session(study, stimuli_dir, "P03", study_seed=SEED, n_slots=2)
    Allocation(study).assign("P02")  # the other terminal
    files = snapshot(study)
    with pytest.raises(ParameterError, match="every slot of .* is taken"):
        open_session(check)
    assert snapshot(study) == files and not (study / "sub-P03").exists()


def test_a_running_session_is_refused_by_the_check(study, stimuli_dir):
    pid = pid_of(study, "RS")
    p = plan(study, stimuli_dir, pid)
    try:
        files = snapshot(study)
        with pytest.raises(ParameterError, match="is already running"):
            check_session(study, stimuli_dir, pid, study_seed=SEED)
        assert snapshot(study) == files
    finally:
        p.release()
    check_session(study, stimuli_dir, pid, study_seed=SEED)  # free again
