"""Work refused before it starts, or cut short, as a user meets it: a setting that names bad
data refused by name before any stage runs; Ctrl-C in a terminal during a command that runs worker
processes (one ``interrupted: ...`` line, no worker's traceback, no worker left running), and the
line that refuses a study simulation cut between participants (one line, bounded, however many
participants the simulation planned).

The Ctrl-C tests run the real command line in a process of its own, and send SIGINT to its whole
process group, as a terminal's Ctrl-C does: the command and every process it started get it. An
interrupt that lands where Python cannot raise it (an ``os.fork`` hook, a finaliser) is raised
again, without a word, in a script of its own (its fork hooks stay out of the test process).
"""
from __future__ import annotations

import csv
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import textwrap

import pytest

from groundwork.errors import TalkingFaceError

from talkingface.cli.errors import MAX_CHARS, error_line
from talkingface.cli.interrupts import INTERRUPTED
from talkingface.cli.main import main
from talkingface.config import DATA_SETTINGS, Config, flatten, load_config
from talkingface.experiments.processes import group_members

REPO = Path(__file__).resolve().parents[2]
SMALL = ["--set", "synth.n_sentences=4", "--set", "synth.workers=2",
         "--set", "mlflow.enabled=false", "--set", "real_speaker.corpus=''",
         "--set", "mapping.baselines=[linear]"]
HANG_GUARD_S = 600  # only so that a command that never gets there fails instead of hanging
# Dask's warning when another Dask cluster of this machine holds port 8787 (its scheduler's
# HTTP server then takes another port): a fact of the machine, not of the interrupt
OTHER_CLUSTER = ("UserWarning: Port 8787 is already in use", "Perhaps you already have a cluster",
                 "Hosting the HTTP server on port", "warnings.warn(")


def _workers(pgid: int) -> list[int]:
    """The worker processes of the command leading process group ``pgid``: the processes of
    its group but itself and multiprocessing's resource tracker."""
    out = []
    for pid in group_members(pgid):
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            continue
        if pid != pgid and b"resource_tracker" not in cmdline:
            out.append(pid)
    return out


def _ctrl_c_when(argv: list, cwd: Path, marker: str) -> tuple[int, str, list]:
    """Run ``talkingface argv`` in ``cwd``; once ``marker`` shows on its stderr (a progress
    bar's name: the work it names has started) and its worker processes are there (starting),
    send SIGINT to its process group. Returns the exit status, the stderr and the processes of
    its group still running once it has ended."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", "talkingface", *argv], cwd=cwd, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)  # its own group, as a terminal's job
    chunks: list[str] = []
    seen = threading.Event()

    def read() -> None:
        for chunk in iter(lambda: proc.stderr.read1(4096), b""):
            chunks.append(chunk.decode("utf-8", "replace"))
            if marker in "".join(chunks):
                seen.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        for _ in range(int(HANG_GUARD_S / 0.1)):
            if seen.wait(0.1) and _workers(proc.pid):
                break
            assert proc.poll() is None, f"{argv} ended before {marker!r}: {''.join(chunks)}"
        else:
            raise AssertionError(f"{argv}: {marker!r} and its workers never showed")
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C
        code = proc.wait(timeout=HANG_GUARD_S)
        reader.join(timeout=60)
        left = group_members(proc.pid)
        for _ in range(600):  # the workers a command ended may take a moment to go
            if not left:
                break
            time.sleep(0.1)
            left = group_members(proc.pid)
        return code, "".join(chunks), left
    finally:
        if proc.poll() is None or group_members(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _lines(stderr: str) -> list[str]:
    """The lines of ``stderr`` but progress bars (tqdm redraws them with carriage returns)."""
    out = []
    for line in stderr.replace("\r", "\n").splitlines():
        line = line.strip()
        if line and "%|" not in line and not any(w in line for w in OTHER_CLUSTER):
            out.append(line)
    return out


@pytest.mark.parametrize("command, marker", [
    (["train", "--name", "t", *SMALL], "speech:"),  # the speech synthesis pool
    (["train", "--name", "t", *SMALL], "training:"),  # a Dask cluster starting its workers
    (["ablate", "--grid", "grid.yaml", "--workers", "2", "--name", "t", *SMALL], "ablations:"),
], ids=["train, synthesising", "train, Dask starting", "ablate, Dask grid"])
def test_ctrl_c_prints_one_line_and_leaves_no_worker(tmp_path, command, marker):
    (tmp_path / "grid.yaml").write_text("children:\n  paper: {}\n  small:\n"
                                        "    mapping.hidden_max: 20\n")
    code, err, left = _ctrl_c_when(command, tmp_path, marker)
    assert "Traceback" not in err, err
    assert _lines(err) == [INTERRUPTED], err
    assert code == 130
    assert left == []  # no worker process outlives the command
    # the stage that was cut leaves no partial folder, but a grid's (it goes on from its tasks)
    run = tmp_path / "runs" / "t"
    assert sorted(p.name for p in run.glob(".*")) == (
        [".ablations.partial"] if command[0] == "ablate" else [])


# -- an interrupt Python would drop ----------------------------------------------------------
# The interrupt raised where Python reports it as "unraisable" and drops it: in a hook that
# os.fork runs in the parent (as logging's, when a pool forks a worker while a Ctrl-C is
# raised), or in a finaliser. LOOP bounds the ordinary code run after it: far more than it takes
# (the waiting thread raises it again as soon as it holds the GIL, within the switch interval).
LOOP = 10**9
LAND = {
    "fork hook": """
        def land():
            if not landed:
                landed.append(1)
                raise KeyboardInterrupt
        os.register_at_fork(after_in_parent=land)
        pid = os.fork()
        if pid == 0:
            os._exit(0)
        os.waitpid(pid, 0)
        assert landed
    """,
    "finaliser": """
        class Cut:
            def __del__(self):
                landed.append(1)
                raise KeyboardInterrupt
        Cut()
        assert landed
    """,
}
THEN = {
    "ordinary code": f"""
        total = 0
        for i in range({LOOP}):
            total += i
        print("loop finished")
    """,
    "block end": "",  # the block ends at once: raised as it ends, if not by then
}


def _script(body: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, "-c", textwrap.dedent(body)], env=env,
                          capture_output=True, text=True, timeout=HANG_GUARD_S, cwd=REPO)


@pytest.mark.parametrize("then", THEN)
@pytest.mark.parametrize("where", LAND)
def test_an_interrupt_python_drops_is_raised_again_without_a_word(where, then):
    body = ("import os\nimport sys\n"
            "from talkingface.cli.interrupts import interrupts_for_this_process\n"
            "landed = []\nbefore = sys.unraisablehook\ntry:\n"
            "    with interrupts_for_this_process():\n"
            + textwrap.indent(textwrap.dedent(LAND[where] + THEN[then]), " " * 8)
            + "    print('not interrupted')\n"
            "except KeyboardInterrupt:\n"
            "    print('interrupted', sys.unraisablehook is before)\n")
    done = _script(body)
    assert done.returncode == 0, done.stderr
    # once, where ordinary code runs next: not at the block's end, not never
    assert done.stdout.splitlines() == ["interrupted True"], done.stdout + done.stderr
    assert "Traceback" not in done.stderr and "Exception ignored" not in done.stderr, done.stderr


def test_other_unraisable_exceptions_reach_the_hook_there_was():
    done = _script("""
        import sys
        from talkingface.cli.interrupts import interrupts_for_this_process
        seen = []
        def before(unraisable):
            seen.append((unraisable.exc_type.__name__, str(unraisable.exc_value)))
        sys.unraisablehook = before
        class Broken:
            def __del__(self):
                raise ValueError("in a finaliser")
        with interrupts_for_this_process():
            assert sys.unraisablehook is not before
            Broken()
        assert sys.unraisablehook is before
        print(seen)
    """)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[('ValueError', 'in a finaliser')]", done.stdout + done.stderr
    assert done.stderr == ""


# -- a study simulation cut between participants --------------------------------------------

def _cut_simulation(run_dir: Path, out: Path, planned: int) -> Path:
    """The run's simulated study data as if its simulation had planned ``planned`` participants
    and been cut after the ones it has, save its last (its slot free again)."""
    shutil.copytree(run_dir / "runs" / "R" / "study_data", out)
    last = sorted(out.glob("sub-SIM*"))[-1]
    shutil.rmtree(last)
    with open(out / "allocation.csv", newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    fields = list(rows[0])
    for r in rows:
        if r["participant_id"] == last.name.removeprefix("sub-"):
            r.update(participant_id="", status="free", updated="")
    for slot in range(len(rows) + 1, planned + 1):
        rows.append({**{k: "" for k in fields}, "slot": str(slot),
                     "sequence": ("SR", "RS")[slot % 2], "status": "free"})
    with open(out / "allocation.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=fields, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    return out


@pytest.mark.parametrize("planned", [5, 1200])
def test_a_cut_simulation_is_refused_in_one_bounded_line(small_run_dir, tmp_path, monkeypatch,
                                                         capsys, planned):
    _cut_simulation(small_run_dir, tmp_path / "cut", planned)
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    assert main(["analyze", "cut", "--out", "an"]) == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: cut holds incomplete sessions"), lines
    assert len(lines[0]) <= MAX_CHARS
    assert "--allow-incomplete" in lines[0]  # what to do survives however long the list
    if planned > 100:  # the message names the first few and a count: nothing had to be cut
        assert " more" in lines[0] and "more characters" not in lines[0], lines[0]
    assert not (tmp_path / "an").exists()


@pytest.mark.parametrize("n", [0, 1, 100, MAX_CHARS - 8, MAX_CHARS - 7, MAX_CHARS, 10**6])
def test_an_error_line_is_whole_when_it_fits_and_keeps_both_ends_when_cut(n):
    message = "w" * max(0, n - 18) + "\n" + "use --flag"  # a line break: one space
    line = error_line(message)
    assert "\n" not in line and len(line) <= MAX_CHARS
    whole = "error: " + message.replace("\n", " ")
    if len(whole) <= MAX_CHARS:
        assert line == whole
    else:
        head, _, rest = line.partition(" … (")
        count, _, tail = rest.partition(" more characters) … ")
        assert whole.startswith(head) and whole.endswith(tail) and tail.endswith("use --flag")
        assert len(head) + int(count) + len(tail) == len(whole)  # what was left out, counted


# -- settings that name data -----------------------------------------------------------------
def test_every_setting_that_names_data_is_one_checked_before_a_run():
    """A setting whose name says it names a folder or a file is in DATA_SETTINGS, the list of
    those the stages check before any of them runs (the test below)."""
    named = {key for key, value in flatten(Config()).items() if isinstance(value, str)
             and re.fullmatch(r"(corpus|source|grid|file|dir|folder|path|videos)|"
                              r"\w+_(corpus|grid|file|files|dir|folder|path)",
                              key.rsplit(".", 1)[-1])}
    assert named == set(DATA_SETTINGS)


@pytest.mark.parametrize("setting", DATA_SETTINGS)
def test_a_setting_naming_missing_data_is_refused_by_name_before_any_stage(tmp_path,
                                                                         monkeypatch, setting):
    from talkingface.paths import RunPaths
    from talkingface.stages import REPLICATION, preflight

    monkeypatch.chdir(tmp_path)
    cfg = load_config(None, [f"{setting}=not_here", "mlflow.enabled=false"])
    with pytest.raises(TalkingFaceError, match=rf"{re.escape(setting)}\b.*not_here.*not found|"
                                               rf"not_here.*not found.*{re.escape(setting)}"):
        preflight(REPLICATION, RunPaths.create("r"), cfg)
    assert not any(tmp_path.iterdir())  # nothing written
