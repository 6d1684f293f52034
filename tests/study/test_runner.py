"""The PsychoPy session (study/runner.py), headless: real PsychoPy windows under Xvfb, the
keyboard fed by injected key presses, audio through the sounddevice backend on ALSA's null
device ($HOME/.asoundrc in a temporary home, so PsychoPy's prefs never touch the real one).

Sessions run the command line in subprocesses (``talkingface study run``), as a lab would, on a
small stimulus set made from the small synthetic corpus (no trained model): 0.2 s videos and
WAVs, so that the trials' real-time playback is short (decoding, frame choice by elapsed time and
audio on the onset flip are the same for any length). Frame timing is recorded but never
asserted: Xvfb has no vsync. Commands refused before any window or sound opens run the same
``main`` in the test's process (:func:`in_process`): a new Python process would only add the
command line's start-up; one refusal per kind of check still runs as its own process.
"""
from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from filelock import FileLock
from PIL import Image

from face_model.render import FaceRenderer
from groundwork.audio import write_wav
from groundwork.errors import ParameterError
from study.data import Allocation, data_path, read_rows, sidecar_path
from study.design import AUDIO, EXPRESSIONS, FACES, N_TRIALS, RESPONSES, Trial, \
    required_stimuli, session_trials, stimulus_id
from study.runner import scripted_responder
from study.stimuli import COLUMNS, FPS, MANIFEST, load_manifest, sha256, write_silent_mp4
from talkingface.config import Config

REPO = Path(__file__).resolve().parents[2]
ARTIFACTS = Path(__file__).resolve().parent / "artifacts"
SEED = Config().seed
KEYS = dict(zip(RESPONSES, Config().study.keys))
N_FRAMES = 6  # 0.2 s videos; the sentences' audio is cut to the same length
FAST = ["--set", "study.fixation_s=0.02", "--set", "study.iti_s=0.02"]
NO_PRACTICE = ["--set", "study.practice=false"]
XVFB = ["xvfb-run", "-a", "-s", "-screen 0 1024x768x24"]
TIMEOUT = 240


# --- fixtures -----------------------------------------------------------------------------
@pytest.fixture(scope="session")
def stimuli_dir(small_corpus, tmp_path_factory):
    """Every stimulus the design needs: short silent MP4s of corpus utterances (the two faces
    start at different frames, so they differ), WAVs of the same length, markers and a
    manifest."""
    out = tmp_path_factory.mktemp("stimuli")
    renderer = FaceRenderer(mesh=False)
    rows = []

    def row(sid, kind, face, expr, audio, **files):
        r = {"stimulus_id": sid, "kind": kind, "face": face, "expression": expr,
             "audio": audio, "n_frames": N_FRAMES, "fps": FPS,
             "duration_s": f"{N_FRAMES / FPS:.4f}"}
        for key in ("video", "wav", "markers"):
            p = files.get(key)
            r[key] = str(p.relative_to(out)) if p else ""
            r[f"sha256_{key}"] = sha256(p) if p else ""
        return r

    for i, a in enumerate(AUDIO):
        calm = small_corpus[f"s00_neutral_{i:03d}"]
        wav = out / "audio" / f"{stimulus_id('none', 'none', a)}.wav"
        wav.parent.mkdir(parents=True, exist_ok=True)
        write_wav(wav, np.asarray(calm.audio[:int(N_FRAMES / FPS * calm.sample_rate)],
                                  np.float64), calm.sample_rate)
        rows.append(row(stimulus_id("none", "none", a), "audio", "none", "none", a, wav=wav))
        for e in EXPRESSIONS:
            utt = small_corpus[f"s00_{e}_{i:03d}"]
            for j, face in enumerate(FACES):
                sid = stimulus_id(face, e, a)
                markers = np.asarray(utt.markers[10 * j:10 * j + N_FRAMES], np.float32)
                mk = out / "markers" / f"{sid}.npy"
                mk.parent.mkdir(parents=True, exist_ok=True)
                np.save(mk, markers, allow_pickle=False)
                video = write_silent_mp4(out / "video" / f"{sid}.mp4",
                                         [renderer.render(m) for m in markers], renderer.size)
                rows.append(row(sid, "video", face, e, a, video=video, wav=wav, markers=mk))
    with open(out / MANIFEST, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    assert sorted(load_manifest(out)) == sorted(required_stimuli())
    return out


@pytest.fixture(scope="session")
def env(tmp_path_factory):
    """A temporary home with ALSA's null device as the default sound card."""
    home = tmp_path_factory.mktemp("home")
    (home / ".asoundrc").write_text("pcm.!default { type null }\n")
    e = {k: v for k, v in os.environ.items() if not k.startswith("XDG_")}
    e.update(HOME=str(home), PYTHONPATH=os.pathsep.join(
        p for p in (str(REPO), os.environ.get("PYTHONPATH", "")) if p))
    return e


@pytest.fixture(scope="session")
def script(tmp_path_factory):
    """Seeded responses (all four used) and response times for every stimulus."""
    rng = np.random.default_rng(SEED)
    table = {sid: (RESPONSES[i % 4], round(float(rng.uniform(0.3, 1.5)), 3))
             for i, sid in enumerate(rng.permutation(required_stimuli()))}
    path = tmp_path_factory.mktemp("script") / "responses.csv"
    with open(path, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["stimulus_id", "response", "rt_s"])
        w.writerows([sid, r, rt] for sid, (r, rt) in table.items())
    return path, table


def study_run(study, stimuli, pid, *extra):
    """The arguments of ``talkingface study run``."""
    return ["study", "run", "--participant", pid, "--study-dir", str(study), "--stimuli",
            str(stimuli), *extra]


def command(study, stimuli, pid, *extra):
    return [sys.executable, "-m", "talkingface.cli.main", *study_run(study, stimuli, pid, *extra)]


def run_cli(args, env, cwd, *, xvfb=True):
    return subprocess.run([*XVFB, *args] if xvfb else args, env=env, cwd=cwd,
                          capture_output=True, text=True, timeout=TIMEOUT)


@pytest.fixture
def in_process(monkeypatch, capsys):
    """``in_process(args, cwd, unset=())``: the command line's ``main(args)`` run in this
    process in the folder ``cwd`` (and without the environment variables ``unset``), for a
    command refused before any window or sound opens; returns its exit status and what it
    printed, as :func:`run_cli` does."""
    from talkingface.cli.main import main

    def call(args, cwd, *, unset=()):
        capsys.readouterr()
        with monkeypatch.context() as mp:
            mp.chdir(cwd)
            for name in unset:
                mp.delenv(name, raising=False)
            code = main([str(a) for a in args])
        out = capsys.readouterr()
        return SimpleNamespace(returncode=code, stdout=out.out, stderr=out.err)

    return call


def snapshot(folder: Path) -> dict:
    """Every file under ``folder`` and its bytes."""
    if not folder.exists():
        return {}
    return {p: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def rows_of(study, pid) -> list[dict]:
    rows, torn = read_rows(data_path(study, pid))
    assert not torn
    return rows


def assert_session_data(rows, pid, sequence, table):
    """27 rows in the planned order (blocks in the design's order) with the injected answers."""
    planned = session_trials(pid, sequence, SEED)
    assert len(rows) == N_TRIALS
    assert [(int(r["trial_index"]), r["stimulus_id"]) for r in rows] == \
        [(t.trial_index, t.stimulus_id) for t in planned]
    first, second = ("synthetic", "real") if sequence == "SR" else ("real", "synthetic")
    blocks = [(r["block"], r["period"], r["face"]) for r in rows]
    assert [b[:2] for b in blocks] == [("visual", "0")] * 6 + [("audio", "0")] * 3 + \
        [("bimodal", "1")] * 9 + [("bimodal", "2")] * 9
    assert {b[2] for b in blocks[9:18]} == {first} and {b[2] for b in blocks[18:]} == {second}
    assert {b[2] for b in blocks[6:9]} == {"none"} and {r["audio"] for r in rows[:6]} == {"none"}
    for r in rows:
        response, rt = table[r["stimulus_id"]]
        assert (r["response"], r["response_key"]) == (response, KEYS[response])
        assert float(r["rt_s"]) == pytest.approx(rt, abs=1e-3)
        assert r["participant_id"] == pid and r["sequence"] == sequence
        assert r["simulated"] == "false" and r["responder_model"] == "script:responses.csv"
        assert int(r["n_frames"]) >= 1  # timing recorded, never judged (no vsync under Xvfb)
        assert (r["audio_onset_s"] != "") == (r["audio"] != "none")


def _kill_group(pgid):
    """SIGKILL xvfb-run, Xvfb and the session; remove the X server's stale lock file."""
    members = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid:
            members.append(int(stat.parent.name))
    os.killpg(pgid, signal.SIGKILL)
    for lock in Path("/tmp").glob(".X*-lock"):
        try:
            if int(lock.read_text().strip()) in members:
                lock.unlink()
                Path(f"/tmp/.X11-unix/X{lock.name[2:-5]}").unlink(missing_ok=True)
        except (OSError, ValueError):
            pass


def kill_after(study, pid, n_rows, stimuli_dir, env, script):
    """Start ``pid``'s session, SIGKILL it once ``n_rows`` judgments are on disk; returns the
    study folder, the data file's complete rows at that moment and their number."""
    study.parent.mkdir(parents=True, exist_ok=True)
    proc = subprocess.Popen([*XVFB, *command(study, stimuli_dir, pid, "--inject",
                                             str(script[0]), *FAST, *NO_PRACTICE)],
                            env=env, cwd=study.parent, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    path, deadline = data_path(study, pid), time.monotonic() + TIMEOUT
    try:
        while not (path.is_file() and path.read_bytes().count(b"\n") >= n_rows + 1):
            assert proc.poll() is None, "the session ended before it was killed"
            assert time.monotonic() < deadline, f"no {n_rows} judgments in time"
            time.sleep(0.05)
    finally:
        _kill_group(proc.pid)
        proc.wait()
    before = path.read_bytes()
    kept = before[:before.rfind(b"\n") + 1]  # complete rows; a cut-short one is the trial lost
    return study, pid, kept, kept.count(b"\n") - 1


def run_sessions(root, stimuli_dir, env, script):
    """Three sessions side by side: one participant of each group (P01 with the practice
    trial and the screenshot, the other without the practice), and P07 in another study
    folder, killed with SIGKILL once 10 judgments are on disk. Writes ``done.json`` last."""
    study = root / "study_data"
    alloc = Allocation(study)
    pids = {}
    for r in alloc.create(4, SEED):  # the seeded list, pre-assigned in slot order
        pid = f"P{int(r['slot']):02d}"
        alloc.assign(pid)
        pids.setdefault(r["sequence"], pid)
    assert set(pids) == {"SR", "RS"} and "P01" in pids.values()
    shot = ARTIFACTS / "bimodal_trial.png"
    shot.unlink(missing_ok=True)
    procs = {}
    try:
        for seq, pid in pids.items():
            extra = ["--screenshot", str(shot)] if pid == "P01" else NO_PRACTICE
            with open(root / f"{pid}.out", "w") as o, open(root / f"{pid}.err", "w") as e:
                procs[seq] = subprocess.Popen(
                    [*XVFB, *command(study, stimuli_dir, pid, "--inject", str(script[0]),
                                     *FAST, *extra)],
                    env=env, cwd=root, stdout=o, stderr=e, start_new_session=True)
        killed, pid, kept, n_kept = kill_after(root / "killed" / "study_data", "P07", 10,
                                               stimuli_dir, env, script)
        for p in procs.values():
            p.wait(timeout=TIMEOUT)
    finally:  # only after a failure: no session outlives the tests
        for p in procs.values():
            if p.poll() is None:
                _kill_group(p.pid)
                p.wait()
    (root / "kept.csv").write_bytes(kept)
    out = {seq: [pid, (root / f"{pid}.out").read_text(), (root / f"{pid}.err").read_text(),
                 procs[seq].returncode] for seq, pid in pids.items()}
    (root / "done.json").write_text(json.dumps({
        "study": str(study), "out": out, "shot": str(shot),
        "killed": [str(killed), "P07", n_kept]}))


@pytest.fixture(scope="module")
def sessions(stimuli_dir, env, script, tmp_path_factory):
    """The sessions of :func:`run_sessions`, run once per test run: pytest-xdist workers
    share them through a file lock (as the default corpus in tests/conftest.py)."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = tmp_path_factory.getbasetemp().parent
    else:
        shared = tmp_path_factory.mktemp("shared")
    root = shared / "runner_sessions"
    with FileLock(str(shared / "runner_sessions.lock")):
        if not (root / "done.json").is_file():
            shutil.rmtree(root, ignore_errors=True)
            root.mkdir(parents=True)
            run_sessions(root, stimuli_dir, env, script)
    done = json.loads((root / "done.json").read_text())
    killed, pid, n_kept = done["killed"]
    return SimpleNamespace(study=Path(done["study"]), shot=Path(done["shot"]),
                           out={k: tuple(v) for k, v in done["out"].items()},
                           killed=(Path(killed), pid, (root / "kept.csv").read_bytes(), n_kept))


# --- (1) one participant of each group --------------------------------------------------
@pytest.mark.parametrize("sequence", ["SR", "RS"])
def test_each_group_runs_headless_with_injected_responses(sessions, script, sequence):
    study, out = sessions.study, sessions.out
    pid, stdout, stderr, code = out[sequence]
    assert code == 0, stderr[-3000:]
    assert f"participant {pid} ({sequence}): 27 of 27 judgments, complete" in stdout
    assert_session_data(rows_of(study, pid), pid, sequence, script[1])
    side = json.loads(sidecar_path(study, pid).read_text())
    assert side["allocation"]["sequence"] == sequence and side["study_seed"] == SEED
    assert side["keys"] == KEYS and len(side["stimuli"]["manifest_digest"]) == 64
    assert set(side["versions"]) == {"python", "psychopy", "numpy"}
    (ses,) = side["sessions"]
    assert (ses["end_state"], ses["resumed"], ses["rows_at_start"], ses["rows_at_end"]) == \
        ("complete", False, 0, 27)
    assert ses["practice"] == (pid == "P01")
    slot = next(r for r in Allocation(study).rows() if r["participant_id"] == pid)
    assert slot["status"] == "complete"
    assert (study / "dataset_description.json").is_file()


def test_psychopy_files_are_saved_per_participant(sessions):
    study, out = sessions.study, sessions.out
    folder = study / "sub-P01" / "psychopy"
    (ses,) = json.loads(sidecar_path(study, "P01").read_text())["sessions"]
    assert sorted(folder.iterdir()) == sorted(Path(f) for f in ses["psychopy_files"])
    (csv_file,) = folder.glob("sub-P01_ses-1_*.csv")
    log = next(folder.glob("*.log")).read_text()  # PsychoPy's log: the practice, then 0-26
    assert "trial -1 audio-normal" in log and "trial 26 " in log
    text = csv_file.read_text(encoding="utf-8-sig")
    rows = list(csv.DictReader(text.splitlines()))
    assert [r["stimulus_id"] for r in rows] == [r["stimulus_id"] for r in rows_of(study, "P01")]
    assert {r["participant"] for r in rows} == {"P01"}


# --- (4) a screenshot for a person to look at -------------------------------------------
def test_screenshot_of_a_bimodal_trial(sessions):
    shot = sessions.shot
    assert shot.is_file(), "the P01 session did not save its screenshot"
    img = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    assert img.shape == (768, 1024, 3)
    assert img.std() > 20  # not blank
    skin = np.all(np.abs(img - np.array([238, 200, 170])) < 30, axis=2)
    assert skin[:500].sum() > 5000  # the face, above the prompt
    white = np.all(img > 230, axis=2)
    assert white[600:].sum() > 300  # the key prompt's text at the bottom


# --- (2) a session killed mid-block is resumed in the same order ------------------------
def test_killed_session_resumes_in_the_same_order(sessions, stimuli_dir, env, script, tmp_path,
                                                   in_process):
    study, pid, kept, n_kept = sessions.killed
    path = data_path(study, pid)
    assert 10 <= n_kept < N_TRIALS
    slot = next(r for r in Allocation(study).rows() if r["participant_id"] == pid)
    assert slot["status"] == "assigned"

    # (3) an interrupted session is not continued without --resume, and nothing changes
    files = snapshot(study)
    res = in_process(study_run(study, stimuli_dir, pid, "--inject", str(script[0]), *FAST),
                     tmp_path)
    assert res.returncode == 2 and "interrupted session" in res.stderr and "--resume" in \
        res.stderr, res.stderr
    assert snapshot(study) == files

    res = run_cli(command(study, stimuli_dir, pid, "--resume", "--inject", str(script[0]),
                          *FAST), env, tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    after = path.read_bytes()
    assert after.startswith(kept)  # nothing written before the kill was lost or rewritten
    rows = rows_of(study, pid)
    assert len({r["trial_index"] for r in rows}) == N_TRIALS
    assert_session_data(rows, pid, slot["sequence"], script[1])
    assert [r["session"] for r in rows] == ["1"] * n_kept + ["2"] * (N_TRIALS - n_kept)
    side = json.loads(sidecar_path(study, pid).read_text())
    assert [s["end_state"] for s in side["sessions"]] == ["interrupted", "complete"]
    assert side["sessions"][1]["resumed"] and side["sessions"][1]["rows_at_start"] == n_kept
    assert len(list((study / f"sub-{pid}" / "psychopy").glob("*_ses-2_*.csv"))) == 1


# --- (3) refusals: clear messages, exit 2, nothing written or changed ---------------------
@pytest.mark.parametrize("pid", ["../x", "", "P 01"])
def test_bad_participant_ids_are_refused(stimuli_dir, tmp_path, in_process, pid):
    study = tmp_path / "study_data"
    res = in_process(study_run(study, stimuli_dir, pid), tmp_path)
    assert res.returncode == 2
    assert f"error: participant id {pid!r} is not allowed" in res.stderr
    assert not study.exists()


def test_refusals_change_nothing(sessions, stimuli_dir, tmp_path, in_process):
    study, out = sessions.study, sessions.out
    pid = out["SR"][0]
    files = snapshot(study)
    for extra in ([], ["--resume"]):
        res = in_process(study_run(study, stimuli_dir, pid, *extra), tmp_path)
        assert res.returncode == 2 and "has a complete session" in res.stderr, res.stderr
    res = in_process(study_run(study, stimuli_dir, "P99", "--resume"), tmp_path)
    assert res.returncode == 2 and "no session to resume" in res.stderr, res.stderr
    res = in_process(study_run(study, tmp_path / "nowhere", "P99"), tmp_path)
    assert res.returncode == 2 and "manifest.csv: manifest not found" in res.stderr, res.stderr
    res = in_process(study_run(study, stimuli_dir, "P99", "--seed", str(SEED + 1)), tmp_path)
    assert res.returncode == 2 and f"was made with seed {SEED}" in res.stderr, res.stderr
    assert snapshot(study) == files


# --- a refused session takes no slot and leaves no lock, folder or traceback -----------------
@pytest.mark.parametrize("case", ["no display", "no audio device"])
def test_a_refused_session_takes_no_slot_and_leaves_nothing_behind(stimuli_dir, env, tmp_path,
                                                                   in_process, case):
    """No display (DISPLAY unset) and no audio device (the PTB backend cannot play on ALSA's
    null device, FIELD_NOTES.md) are found before the allocation slot is claimed: the list,
    its log and the folder stay byte for byte as they were, and the error is one line (the
    whole stderr of the command's own process, for no display)."""
    study = tmp_path / "study_data"
    alloc = Allocation(study)
    alloc.create(4, SEED)
    alloc.assign("P01")
    alloc.assign("P02")
    files = snapshot(study)
    if case == "no display":
        headless = {k: v for k, v in env.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
        res = run_cli(command(study, stimuli_dir, "P03", *FAST), headless, tmp_path,
                      xvfb=False)
        expected = "error: no display: DISPLAY is not set, so no window can open"
        assert res.stderr.strip().splitlines() == [res.stderr.strip()]  # nothing else
    else:
        res = run_cli(command(study, stimuli_dir, "P03", *FAST, "--set",
                              "study.audio_backend=ptb"), env, tmp_path)
        expected = "error: audio backend 'ptb' cannot play"
    assert res.returncode == 2, res.stderr[-3000:]
    assert "Traceback" not in res.stderr, res.stderr[-3000:]
    (line,) = [x for x in res.stderr.splitlines() if x.startswith("error:")]
    assert line.startswith(expected), res.stderr[-3000:]
    assert snapshot(study) == files  # allocation.csv, allocation.json, the log: unchanged
    assert not (study / "sub-P03").exists()
    assert not list(study.rglob("*.lock")) or \
        [q.name for q in study.rglob("*.lock")] == [".allocation.lock"]
    if case == "no display":  # a study folder that is not there yet is not created either
        res = in_process(study_run(tmp_path / "fresh", stimuli_dir, "P03"), tmp_path,
                         unset=("DISPLAY", "WAYLAND_DISPLAY"))
        assert res.returncode == 2 and "no display" in res.stderr
        assert not (tmp_path / "fresh").exists()


# --- Escape ends a session safely ---------------------------------------------------------
ESCAPE = """
import json, sys
from study.runner import run_session
def responder(trial):
    return ("escape", 0.3) if trial.trial_index == 4 else ("sad", 0.5)
res = run_session(sys.argv[1], sys.argv[2], "P05", study_seed=%d, practice=False,
                  fixation_s=0.02, iti_s=0.02, audio_backend="none", responder=responder,
                  responder_model="test")
print(json.dumps(res))
""" % SEED


def test_escape_aborts_and_keeps_what_was_written(stimuli_dir, env, tmp_path):
    study = tmp_path / "study_data"
    res = run_cli([sys.executable, "-c", ESCAPE, str(study), str(stimuli_dir)], env, tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert (out["aborted"], out["complete"], out["rows"]) == (True, False, 4)
    rows = rows_of(study, "P05")
    assert [int(r["trial_index"]) for r in rows] == [0, 1, 2, 3]
    assert {r["response"] for r in rows} == {"sad"}
    slot = next(r for r in Allocation(study).rows() if r["participant_id"] == "P05")
    assert slot["status"] == "assigned"  # the slot stays with P05, for --resume
    (ses,) = json.loads(sidecar_path(study, "P05").read_text())["sessions"]
    assert (ses["end_state"], ses["rows_at_end"]) == ("aborted", 4)
    (csv_file,) = (study / "sub-P05" / "psychopy").glob("*.csv")
    assert len(list(csv.DictReader(csv_file.read_text(encoding="utf-8-sig").splitlines()))) == 4


def test_importing_the_runner_does_not_import_psychopy(env):
    code = "import sys, study.runner; assert 'psychopy' not in sys.modules"
    assert subprocess.run([sys.executable, "-c", code], env=env).returncode == 0


# --- (5) scripted responses ----------------------------------------------------------------
def _write(path, rows, header=("stimulus_id", "response", "rt_s")):
    with open(path, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(header)
        w.writerows(rows)
    return path


def test_scripted_responder(tmp_path):
    good = [[sid, "happy", ""] for sid in required_stimuli()]
    good[0][2] = "1.25"
    f = scripted_responder(_write(tmp_path / "ok.csv", good))
    trial = Trial("audio", 0, 6, "none", "none", "good", "audio-good")
    assert f(trial) == ("happy", 0.8)
    assert f(Trial("visual", 0, 0, "synthetic", "neutral", "none", good[0][0])) == \
        ("happy", 1.25)


@pytest.mark.parametrize("change, message", [
    (lambda rows: rows.__setitem__(2, [rows[2][0], "angry", ""]),
     "row 4: response 'angry'; allowed: neutral, happy, sad, not_sure"),
    (lambda rows: rows.append(["synthetic-angry-good", "happy", ""]),
     "row 23: stimulus_id 'synthetic-angry-good' is not a stimulus of the design"),
    (lambda rows: rows.__setitem__(0, [rows[0][0], "sad", "-1"]),
     "row 2: rt_s '-1'; allowed"),
    (lambda rows: rows.append(list(rows[0])), "row 23: stimulus_id"),
    (lambda rows: rows.pop(), "no response for stimuli ['audio-bad']"),
])
def test_scripted_responder_refuses_bad_rows(tmp_path, change, message):
    rows = [[sid, "neutral", ""] for sid in required_stimuli()]
    change(rows)
    path = _write(tmp_path / "bad.csv", rows)
    with pytest.raises(ParameterError) as err:
        scripted_responder(path)
    assert str(path) in str(err.value) and message in str(err.value)


def test_a_response_script_saved_by_excel_is_read(tmp_path):
    rows = [[sid, "sad", "0.5"] for sid in required_stimuli()]
    path = _write(tmp_path / "excel.csv", rows)
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes().replace(b"\n", b"\r\n"))
    f = scripted_responder(path)
    assert f(Trial("audio", 0, 6, "none", "none", "good", "audio-good")) == ("sad", 0.5)


def test_scripted_responder_refuses_bad_files(tmp_path):
    with pytest.raises(ParameterError, match="not found"):
        scripted_responder(tmp_path / "missing.csv")
    path = _write(tmp_path / "cols.csv", [["audio-good", "sad"]], header=("stimulus", "resp"))
    with pytest.raises(ParameterError, match=r"cols\.csv: missing columns"):
        scripted_responder(path)


def test_a_simulated_observer_answers_inside_the_runner(stimuli_dir, small_corpus_dir, env,
                                                        tmp_path):
    """``--inject flmp``: the FLMP observer of study/simulate.py answers every trial through the
    PsychoPy keyboard; its answers equal the same observer's answers computed offline."""
    from face_model.corpus import load_corpus
    from study.design import participant_seed
    from study.simulate import ExpressionClassifier, make_observers, responder, visual_evidence

    stim = tmp_path / "stimuli"
    shutil.copytree(stimuli_dir, stim)
    (stim / "source").symlink_to(small_corpus_dir)  # the observers' classifier learns from it
    study = tmp_path / "study_data"
    res = run_cli(command(study, stim, "P02", "--inject", "flmp", *FAST, *NO_PRACTICE), env,
                  tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    rows = rows_of(study, "P02")
    assert len(rows) == N_TRIALS
    assert {(r["simulated"], r["responder_model"]) for r in rows} == {("true", "flmp-v1")}
    sequence = rows[0]["sequence"]
    clf = ExpressionClassifier().fit(load_corpus(small_corpus_dir), seed=SEED)
    answer = responder(make_observers(1, participant_seed(SEED, "P02"))[0],
                       visual_evidence(clf, load_manifest(stim)))
    expected = [answer(t) for t in session_trials("P02", sequence, SEED)]
    assert [r["response"] for r in rows] == [r for r, _ in expected]
    assert [r["response_key"] for r in rows] == [KEYS[r] for r, _ in expected]
