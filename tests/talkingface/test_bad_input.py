"""Bad input over the real command line: for every case, exit status 2, exactly one line on
stderr that names the offending file or value, no traceback, and every file that existed before
is byte-identical afterwards (hashes of the whole working folder: the run, its study data, the
corpus, the model files).

The cases are a table (:mod:`tests.talkingface.bad_input_cases`, with the folder they run in);
Hypothesis adds out-of-range config values and random file contents. Inputs the project promises
to take (stereo, six-channel and float WAVs, another sample rate, study CSVs saved with a UTF-8
byte-order mark) are a small table of their own, which must exit 0.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.study_data import read_study
from groundwork.audio import read_wav, write_wav
from study.data import Allocation
from talkingface.cli.main import main
from tests.talkingface.bad_input_cases import ACCEPTED, CASES, QUICK, RUN, TINY, \
    add_bad_inputs
# tools/ship_default_model.py is not a talkingface command: its table and its test (the same
# contract) live in their own part and run here
from tests.talkingface.bad_input_ship import (  # noqa: F401
    ship_world, test_ship_default_model_refuses_bad_input_in_one_line)

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def world(small_run_dir, tmp_path_factory):
    """A working folder with a finished small run ``R`` (corpus, units, mapping, study data,
    report), a corpus ``c`` and the bad inputs of the cases (:mod:`bad_input_cases`), for all
    cases of a worker: a copy of the run and corpus made once per test run by
    :func:`bad_input_cases.build_run` (``small_run_dir``), then the bad inputs beside them."""
    root = tmp_path_factory.mktemp("bad_input")
    shutil.copytree(small_run_dir, root, dirs_exist_ok=True)
    add_bad_inputs(root)
    return root


def _hashes(root: Path) -> dict:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and p.name != "mlflow.db"}


def refused(world, monkeypatch, capsys, argv: list, *names: str) -> str:
    """Run ``argv`` in ``world``; check the contract; return the error line."""
    monkeypatch.chdir(world)
    before = _hashes(world)
    capsys.readouterr()
    code = main(argv)
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip() and "%|" not in ln]
    assert code == 2, (argv, err)
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    for n in names:
        assert n in lines[0], (n, lines[0])
    after = _hashes(world)
    assert {k: after.get(k) for k in before} == before, "a file that existed was changed"
    assert not set(after) - set(before), f"files were made: {sorted(set(after) - set(before))}"
    return lines[0]


def _case_id(argv: list) -> str:
    """The argv without the run's shared settings, as a test id."""
    shared = " ".join(QUICK)
    text = " ".join(argv).replace(shared, "").replace(" ".join(RUN), "")
    return " ".join(text.replace(" ".join(TINY), "").split())[:80]


@pytest.mark.parametrize("argv, names", CASES, ids=[_case_id(c[0]) for c in CASES])
def test_bad_input_gets_one_clear_line_and_changes_nothing(world, monkeypatch, capsys, argv,
                                                           names):
    refused(world, monkeypatch, capsys, argv, *names)


def test_a_pickled_model_is_refused_without_running_it(world, monkeypatch, capsys):
    for model in ("evil.tfmap", "member.tfmap"):  # a pickle for a model, or in one of its arrays
        refused(world, monkeypatch, capsys,
                ["animate", "speech.wav", "-o", "o.mp4", "--model", f"runs/R/mapping/{model}"],
                model)
    refused(world, monkeypatch, capsys, ["units", "--corpus", "obj_corpus", "--out", "u"], ".npy")
    assert not [p.name for p in world.glob("pwned*")]


@pytest.mark.parametrize("argv, what", ACCEPTED, ids=[w for _, w in ACCEPTED])
def test_inputs_the_project_promises_to_take_are_taken(world, monkeypatch, capsys, argv, what):
    monkeypatch.chdir(world)
    before = _hashes(world)
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 0, (what, err)
    assert "Traceback" not in err and "error:" not in err
    after = _hashes(world)
    assert {k: after.get(k) for k in before} == before, "a file that existed was changed"


def test_study_csvs_saved_with_a_byte_order_mark_read_as_without(world):
    """Excel saves CSVs with a UTF-8 byte-order mark: the same judgments and allocation."""
    plain, bom = (read_study(world / d) for d in ("runs/R/study_data", "sd_bom"))
    assert bom.trials.drop(columns="file").equals(plain.trials.drop(columns="file"))
    assert Allocation(world / "sd_bom").rows() == Allocation(world / "runs/R/study_data").rows()


@settings(max_examples=25)
@given(key=st.sampled_from(["synth.rate_wpm", "synth.marker_noise_px", "synth.head_scale",
                            "mapping.train_fraction", "mapping.train.learning_rate",
                            "tracker.corpus_noise_sd", "study.fixation_s"]),
       value=st.sampled_from([-1e9, -100, -1, -0.5, float("nan"), float("inf"), float("-inf")]))
def test_out_of_range_config_values_are_refused_before_any_work(world, key, value):
    with pytest.MonkeyPatch.context() as mp:
        capture = _Capture()
        mp.setattr("sys.stderr", capture)
        mp.chdir(world)
        before = _hashes(world)
        code = main(["train", "--name", "R", *QUICK[:-2], "--overwrite", "--set",
                     f"{key}={value}"])
        assert code == 2 and key in capture.text and "Traceback" not in capture.text
        assert _hashes(world) == before


@settings(max_examples=25)
@given(data=st.binary(min_size=0, max_size=400))
def test_any_bytes_as_a_wav_file_give_one_line(world, data):
    with pytest.MonkeyPatch.context() as mp:
        capture = _Capture()
        mp.setattr("sys.stderr", capture)
        mp.chdir(world)
        (world / "random.wav").write_bytes(data)
        before = _hashes(world)
        code = main(["animate", "random.wav", "-o", "o_random.mp4", "--model", "R"])
        assert code == 2 and "random.wav" in capture.text and "Traceback" not in capture.text
        assert _hashes(world) == before


class _Capture:
    def __init__(self):
        self.text = ""

    def write(self, s):
        self.text += s

    def flush(self):
        pass


# -- killed mid-way ---------------------------------------------------------------------------

def _final_files(root: Path) -> dict:
    """Hashes of every file under a final name (not a dot-named temporary one)."""
    return {k: v for k, v in _hashes(root).items()
            if not any(part.startswith(".") for part in Path(k).parts)}


def _kill_when(cmd: list, cwd: Path, ready, timeout_s: float = 300) -> None:
    """Start ``cmd``, SIGKILL it as soon as ``ready()`` is true, and wait for it."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", "talkingface", *cmd], cwd=cwd, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for _ in range(int(timeout_s / 0.05)):
            if ready():
                break
            if proc.poll() is not None:
                raise AssertionError(f"{cmd} ended (exit {proc.returncode}) before it was killed")
            time.sleep(0.05)
        else:
            raise AssertionError(f"{cmd}: never reached the point to kill it")
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)


def test_a_killed_animate_leaves_the_previous_mp4_as_it_was(world):
    long = world / "long.wav"
    y, sr = read_wav(world / "speech.wav")
    write_wav(long, np.tile(y, 25), sr)  # over a minute of speech: a long render
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(world)
        assert main(["animate", "speech.wav", "-o", "kept.mp4", "--model", "R"]) == 0
    before = _final_files(world)
    _kill_when(["animate", "long.wav", "-o", "kept.mp4", "--model", "R", "--overwrite"], world,
               lambda: (world / ".kept.partial.mp4").exists()
               and (world / ".kept.partial.mp4").stat().st_size > 50_000)
    assert _final_files(world) == before  # the old MP4 intact, no short one under its name


def test_a_killed_replicate_leaves_every_finished_stage_as_it_was(world):
    run = world / "runs" / "R"
    before = {k: v for k, v in _final_files(run).items() if k != "config.yaml"}
    _kill_when(["replicate", "--name", "R", *QUICK, "--overwrite", "--set",
                "mapping.hidden_max=30"], world,
               lambda: (run / ".mapping.partial").exists())
    after = {k: v for k, v in _final_files(run).items() if k != "config.yaml"}
    assert after == before
    # the next run clears the leftover build and finishes
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(world)
        assert main(["replicate", "--name", "R", *QUICK, "--overwrite", "--set",
                     "mapping.hidden_max=30"]) == 0
    assert not list(run.glob(".*"))
    assert json.loads((run / "mapping" / "done.json").read_text())["key"]["config"][
        "mapping"]["hidden_max"] == 30


def test_a_killed_simulation_resumes_to_the_uninterrupted_result(world):
    stim = ["--stimuli", "runs/R/stimuli", *TINY[-2:]]
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(world)
        assert main(["study", "simulate", "--n", "60", "--study-dir", "sim_ref", *stim]) == 0
    run_before = _final_files(world / "runs" / "R")
    # sixty participants, so the kill lands while many are still to come
    _kill_when(["study", "simulate", "--n", "60", "--study-dir", "sim_cut", *stim], world,
               lambda: (world / "sim_cut" / "sub-SIM03").exists())
    assert _final_files(world / "runs" / "R") == run_before
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(world)
        assert main(["study", "simulate", "--n", "60", "--study-dir", "sim_cut", *stim]) == 0

    def files(folder):  # the allocation list's timestamps are the wall clock: left out
        return {k: v for k, v in _final_files(world / folder).items()
                if not k.startswith("allocation")}

    assert files("sim_cut") == files("sim_ref")


# -- outputs that cannot be written, inputs that cannot be read ---------------------------

def _as_a_user(cmd: list) -> list:
    """``cmd`` without root's power to ignore file permissions (root keeps it otherwise)."""
    if os.geteuid() == 0:
        return ["setpriv", "--bounding-set=-dac_override,-dac_read_search", *cmd]
    return cmd


@pytest.mark.parametrize("argv, names", [
    (["animate", "speech.wav", "-o", "ro/o.mp4"], ["ro/o.mp4", "not writable"]),
    (["animate", "speech.wav", "-o", "o.mp4", "--markers", "ro/m.npy"],
     ["ro/m.npy", "not writable"]),
    (["animate", "locked.wav", "-o", "o.mp4"], ["locked.wav", "Permission denied"]),
    (["synth", "--out", "ro/c2", *TINY], ["ro", "Permission denied"]),
], ids=["animate -o read-only", "--markers read-only", "unreadable WAV", "synth --out read-only"])
def test_permissions_are_one_line_naming_the_path(world, tmp_path, argv, names):
    """In a subprocess, as an ordinary user would run it (exit status, stderr, files)."""
    ro = tmp_path / "ro"
    ro.mkdir()
    shutil.copy(world / "speech.wav", tmp_path / "speech.wav")
    shutil.copy(world / "speech.wav", tmp_path / "locked.wav")
    (tmp_path / "locked.wav").chmod(0)
    ro.chmod(0o555)
    state = lambda: (_hashes(ro), sorted(p.name for p in tmp_path.iterdir()),  # noqa: E731
                     (tmp_path / "locked.wav").stat().st_mtime_ns)
    before = state()
    if argv[0] == "animate":
        argv = [*argv, "--model", str(world / "runs" / "R")]
    proc = subprocess.run(_as_a_user([sys.executable, "-m", "talkingface", *argv]),
                          cwd=tmp_path, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and "%|" not in ln]
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in proc.stderr
    for n in names:
        assert n in lines[0], (n, lines[0])
    assert state() == before  # nothing written, nothing changed


# -- a full disk --------------------------------------------------------------------------------
# The disk is a real one: a small tmpfs mounted for the command, in a mount namespace of its
# own (`unshare`: as root, or as a user where user namespaces are allowed), so the test needs no
# privilege over the machine and leaves no mount behind. The command sees the disk fill up as it
# writes; after it, the shell lists and hashes what is on the disk, for the test to read.
FULL_DISK = r"""
set -e
mount -t tmpfs -o size={size_k}k tmpfs "$DISK"
{prepare}
# fill the disk, then free all but {free_k} KB of it
dd if=/dev/zero of="$DISK/.fill" bs=4k 2>/dev/null || true
truncate -s -{free_k}K "$DISK/.fill"
set +e
"$PY" -m talkingface "$@" 2> "$OUT/stderr" > /dev/null
echo $? > "$OUT/status"
cd "$DISK" && find . -type f ! -name .fill -exec sha256sum {{}} + | sort > "$OUT/files"
find . -mindepth 1 ! -name .fill | sort > "$OUT/names"
"""


def _on_a_full_disk(tmp_path, cwd, argv, *, prepare="", size_k=4096, free_k=8):
    """Run ``talkingface argv`` in ``cwd`` with a tmpfs of ``size_k`` KB at ``tmp_path/disk``
    (``prepare``: shell lines run first, e.g. copying files to it), filled up to ``free_k`` KB;
    returns (exit status, error lines, {name: sha256} of the disk before and after, names)."""
    disk, out = tmp_path / "disk", tmp_path / "out"
    disk.mkdir()
    out.mkdir()
    script = tmp_path / "full_disk.sh"
    script.write_text(FULL_DISK.format(size_k=size_k, free_k=free_k, prepare=prepare))
    env = {**os.environ, "PYTHONPATH": str(REPO), "DISK": str(disk), "OUT": str(out),
           "PY": sys.executable}
    proc = subprocess.run(["unshare", "--mount", "--map-root-user", "sh", str(script), *argv],
                          cwd=cwd, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr  # the shell itself (mount) worked
    err = (out / "stderr").read_text()
    lines = [ln for ln in err.splitlines() if ln.strip() and "%|" not in ln]
    files = dict(ln.split()[::-1] for ln in (out / "files").read_text().splitlines())
    names = (out / "names").read_text().split()
    return int((out / "status").read_text()), lines, err, files, names


def _one_line_about_room(status, lines, err):
    assert status == 2, err
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in err, err
    assert "No space left on device" in lines[0] or "ffmpeg" in lines[0], lines[0]


def test_animate_on_a_full_disk_keeps_the_previous_mp4(world, tmp_path):
    """ffmpeg runs out of room: exit 2, one line; the MP4 there before is byte-identical and no
    partial file is left (ffmpeg's exit status and the MP4's boxes are checked)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(world)
        assert main(["animate", "speech.wav", "-o", str(tmp_path / "keep.mp4"), "--model", "R",
                     "--overwrite"]) == 0
    keep = hashlib.sha256((tmp_path / "keep.mp4").read_bytes()).hexdigest()
    status, lines, err, files, names = _on_a_full_disk(
        tmp_path, world, ["animate", "speech.wav", "-o", str(tmp_path / "disk" / "keep.mp4"),
                          "--model", "R", "--overwrite"],
        prepare=f'cp "{tmp_path / "keep.mp4"}" "$DISK/keep.mp4"',
        size_k=4096, free_k=8)
    _one_line_about_room(status, lines, err)
    assert "keep.mp4" in lines[0]
    assert files == {"./keep.mp4": keep}  # the old video as it was
    assert names == ["./keep.mp4"]  # and nothing half-written beside it


def test_synth_on_a_full_disk_leaves_no_partial_corpus(world, tmp_path):
    status, lines, err, files, names = _on_a_full_disk(
        tmp_path, world, ["synth", "--out", str(tmp_path / "disk" / "c2"), *TINY],
        size_k=2048, free_k=64)
    _one_line_about_room(status, lines, err)
    assert files == {} and names == []  # the partial corpus was removed


# -- two commands on one run -----------------------------------------------------------------

def test_a_second_command_on_a_run_being_built_is_refused_naming_the_first(world, monkeypatch,
                                                                         capsys):
    """One builds (``replicate`` in another process), the other (``train``, here) is refused in
    one line naming the first process, which goes on as the owner (the first writes its run
    meanwhile, so the files are not compared here: the second is refused before it writes)."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    first = subprocess.Popen([sys.executable, "-m", "talkingface", "replicate", "--name", "Two",
                              *QUICK], cwd=world, env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    owner = world / "runs" / ".Two.owner"
    try:
        for _ in range(1200):
            if owner.is_file() or first.poll() is not None:
                break
            time.sleep(0.05)
        assert owner.is_file(), f"the first command never took the run (exit {first.poll()})"
        monkeypatch.chdir(world)
        capsys.readouterr()
        code = main(["train", "--name", "Two", *RUN])
        err = capsys.readouterr().err
        lines = [ln for ln in err.splitlines() if ln.strip() and "%|" not in ln]
        assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
        for part in ("error: run runs/Two is in use by process", f"process {first.pid} (",
                     "replicate --name Two", "wait for it to end"):
            assert part in lines[0], (part, lines[0])
        assert first.poll() is None  # the first goes on, still the owner
        assert f'"pid": {first.pid}' in owner.read_text()
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=60)


# -- waits, displays, settings that change nothing, names that are another study's ---------------

def test_a_scheduler_address_where_no_dask_scheduler_listens_is_one_line(world, monkeypatch,
                                                                      capsys):
    """Something accepts connections there (a web server, ssh) but speaks another protocol: a
    Dask client would wait on it forever. Refused before any work, in one line."""
    import socket
    import threading
    from contextlib import suppress

    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def banner():  # what an ssh server says first; a silent one is refused after 10 s
        with suppress(OSError):
            while True:
                conn, _ = server.accept()
                conn.sendall(b"SSH-2.0-OpenSSH_9.6\r\n")
                conn.close()

    threading.Thread(target=banner, daemon=True).start()
    try:
        line = refused(world, monkeypatch, capsys,
                       ["replicate", "--name", "R", *QUICK, "--scheduler",
                        f"tcp://127.0.0.1:{port}"], f"tcp://127.0.0.1:{port}",
                       "not a Dask scheduler", "SSH-2.0")
        assert "check the address and port" in line
    finally:
        server.close()


def test_show_without_a_display_is_refused(world, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    refused(world, monkeypatch, capsys, ["stream", "speech.wav", "--fast", "--model", "R",
                                         "--show"], "--show", "DISPLAY")


def test_sentences_zero_means_every_sentence_and_help_says_so(capsys):
    assert main(["synth", "--help"]) == 0
    assert "0: every sentence" in " ".join(capsys.readouterr().out.split())


def test_settings_that_change_nothing_refuse_nothing_and_rerun_nothing(world, monkeypatch,
                                                                      capsys):
    """Another scheduler, other worker counts, another tracking setting: the same run (no
    "different config"), and no stage runs again."""
    monkeypatch.chdir(world)
    run = world / "runs" / "Same"  # a copy of R, whatever other tests of this folder made of R
    shutil.copytree(world / "runs" / "R", run)
    done = {p.parent.name: p.read_bytes() for p in run.glob("*/done.json")}
    assert main(["train", "--name", "Same", "--config", str(run / "config.yaml"),
                 "--set", "cluster.scheduler=processes",
                 "--set", "synth.workers=1", "--set", "tracker.workers=1",
                 "--set", "mapping.workers=1", "--set", "voices.workers=1",
                 "--set", "ceiling.workers=1", "--set", "mlflow.experiment=other"]) == 0
    err = capsys.readouterr().err
    assert "error:" not in err
    after = {p.parent.name: p.read_bytes() for p in run.glob("*/done.json")}
    assert after == done


def test_a_study_report_never_takes_another_studys_name(world, monkeypatch, capsys):
    """``report --study-data B/study_data`` where reports/study/study_data.pdf is the report of
    runs/R/study_data: a name of its own (the folder's name and 8 hex digits of its path); the
    other study's report and analysis are as they were. Asked again, it is refused."""
    monkeypatch.chdir(world)
    other = world / "B" / "study_data"
    shutil.copytree(world / "runs" / "R" / "study_data", other)
    before = _hashes(world / "reports")
    assert main(["report", "--study-data", str(other)]) == 0
    out = capsys.readouterr().out
    made = sorted((world / "reports" / "study").glob("study_data-*.pdf"))
    assert len(made) == 1 and len(made[0].stem) == len("study_data-") + 8, out
    assert f"report: {Path('reports') / 'study' / made[0].name}" in out
    after = _hashes(world / "reports")
    assert {k: after[k] for k in before} == before  # runs/R/study_data's report untouched
    summary = json.loads((made[0].parent / f"{made[0].stem}_analysis" /
                          "analysis.json").read_text())
    assert summary["study_path"] == str(other.resolve())
    refused(world, monkeypatch, capsys, ["report", "--study-data", str(other)],
            made[0].name, "already exists", "--overwrite")


def test_a_tracking_server_that_never_answers_is_one_line(world, monkeypatch, capsys):
    """It accepts the connection and then says nothing: refused after the health check's
    timeout, before the run is touched (MLflow's own client would retry for minutes)."""
    import socket
    import threading
    from contextlib import suppress

    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    held = []

    def silent():
        with suppress(OSError):
            while True:
                held.append(server.accept()[0])  # kept open, never answered

    threading.Thread(target=silent, daemon=True).start()
    try:
        refused(world, monkeypatch, capsys,
                ["train", "--name", "R", *RUN, "--set", "mlflow.enabled=true", "--set",
                 f"mlflow.uri=http://127.0.0.1:{port}"], f"http://127.0.0.1:{port}",
                "no tracking server answers there", "timed out")
    finally:
        server.close()
        for conn in held:
            conn.close()


def test_a_second_session_of_a_participant_whose_session_runs_is_refused(world, monkeypatch,
                                                                        capsys):
    """Not told that the running session "was interrupted" (and to use --resume): told that
    it runs, and in which process; nothing changes."""
    from filelock import FileLock

    from study.data import sidecar_path, subject_dir
    from study.session import LOCK_NAME

    study = world / "sd_running"
    if not study.exists():
        shutil.copytree(world / "runs" / "R" / "study_data", study)
    side_path = sidecar_path(study, "SIM01")
    side = json.loads(side_path.read_text())
    side["sessions"] = [{"session": 2, "start": "2026-11-25T10:00:00", "end_state": "running",
                         "pid": os.getpid()}]  # as a session that runs now records itself
    side_path.write_text(json.dumps(side))
    lock = FileLock(str(subject_dir(study, "SIM01") / LOCK_NAME))
    lock.acquire(timeout=0)  # held by the running session
    try:
        for extra in ([], ["--resume"]):
            line = refused(world, monkeypatch, capsys,
                           ["study", "run", "--participant", "SIM01", "--study-dir",
                            "sd_running", "--stimuli", "runs/R/stimuli", *extra],
                           "participant SIM01 is already running in process "
                           f"{os.getpid()} (session 2, started 2026-11-25T10:00:00)")
            assert "interrupted" not in line and "wait for it to end" in line
    finally:
        lock.release()


# -- model files of another kind, or edited by hand (groundwork.modelfile) ------------------------

def _hand_edited_model(world: Path) -> str:
    """The run's model with one setting of its JSON record changed by hand, the zip itself
    consistent: its checksum (of the arrays and the record) no longer fits."""
    good = world / "runs" / "R" / "mapping" / "gated_mlp_utterance.tfmap"
    with np.load(good, allow_pickle=False) as z:
        members = {name: z[name] for name in z.files}
    record = json.loads(str(members["metadata"]))
    record["silence_dbfs"] = -10.0
    edited = good.parent / "edited.tfmap"
    with open(edited, "wb") as f:
        np.savez(f, **{**members, "metadata": np.array(json.dumps(record))})
    return str(edited.relative_to(world))


def _units_as_a_mapping(world: Path) -> str:
    """The run's Motion Units file (a model file of kind motion_units) named as a mapping."""
    units = world / "runs" / "R" / "mapping" / "units_renamed.tfmap"
    shutil.copy(world / "runs" / "R" / "units" / "motion_units.npz", units)
    return str(units.relative_to(world))


@pytest.mark.parametrize("make, names", [
    (_hand_edited_model, ["edited.tfmap", "checksum mismatch"]),
    (_units_as_a_mapping, ["units_renamed.tfmap", "its kind is 'motion_units', expected "
                                                  "'audio_mapping'"]),
], ids=["edited record", "another kind"])
def test_a_model_file_edited_or_of_another_kind_is_one_line(world, monkeypatch, capsys, make,
                                                            names):
    model = make(world)
    refused(world, monkeypatch, capsys,
            ["animate", "speech.wav", "-o", "o.mp4", "--model", model], *names)


def test_side_by_side_into_a_folder_that_holds_files_is_one_line(world, monkeypatch, capsys):
    """``evaluate-face --side-by-side DIR`` never writes into a folder of the user's files."""
    refused(world, monkeypatch, capsys,
            ["evaluate-face", "--model", "runs/R/mapping/gated_mlp_utterance.tfmap", "s9/video",
             "--out", "eval_new", "--side-by-side", "eval_mine"],
            "--side-by-side eval_mine", "already holds files", "--overwrite")
