"""Bad input over the real command line: for every case, exit status 2, exactly one line on
stderr that names the offending file or value, no traceback, and every file that existed before
is byte-identical afterwards (hashes of the whole working folder: the run, its study data, the
corpus, the model files).

The cases are a table; Hypothesis adds out-of-range config values and random file contents.
"""
from __future__ import annotations

import hashlib
import json
import os
import pickle
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

from face_model.audio import read_wav, write_wav
from talkingface.cli import main

REPO = Path(__file__).resolve().parents[2]

TINY = ["--set", "synth.n_sentences=3", "--set", "synth.workers=2", "--set", "mlflow.enabled=false"]
QUICK = [*TINY, "--set", "mapping.baselines=[linear]", "--set", "mapping.train.max_epochs=20",
         "--set", "study.n_participants=4", "--ablations", "none"]


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A working folder with a finished small run ``R`` (corpus, units, mapping, study data,
    report), a corpus ``c`` and some input files, made once for all cases of a worker."""
    root = tmp_path_factory.mktemp("bad_input")
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(root)
        assert main(["replicate", "--name", "R", *QUICK]) == 0
        assert main(["synth", "--out", "c", *TINY]) == 0
    wav = sorted((root / "runs" / "R" / "corpus" / "audio").glob("*.wav"))[0]
    shutil.copy(wav, root / "speech.wav")
    (root / "empty.wav").write_bytes(b"")
    (root / "corrupt.wav").write_bytes(b"RIFF\x10\x00\x00\x00WAVEfmt nonsense")
    (root / "bad.yaml").write_text("synth: [unclosed\n")
    (root / "utf16.yaml").write_bytes("synth:\n  speakers: 2\n".encode("utf-16"))
    (root / "list.yaml").write_text("- synth\n")
    (root / "a_folder").mkdir()
    bad_info = root / "bad_info_corpus"
    shutil.copytree(root / "c", bad_info)
    (bad_info / "corpus.json").write_text("{ damaged")
    damaged = root / "runs" / "D"  # a run whose records were damaged by hand
    shutil.copytree(root / "runs" / "R", damaged)
    for done in damaged.glob("*/done.json"):
        done.write_text('{"fingerprint": ')
    nan = root / "nan_corpus"
    shutil.copytree(root / "c", nan)
    m = next((nan / "markers").glob("*.npy"))
    arr = np.load(m)
    arr[3, 5, 0] = np.nan
    np.save(m, arr)
    # model files beside the run's own, so that --model reaches the loader (its Motion Units
    # are found next to it)
    models = root / "runs" / "R" / "mapping"
    tfmap = next(models.glob("*.tfmap"))
    (models / "truncated.tfmap").write_bytes(tfmap.read_bytes()[:200])
    marker = root / "pwned"
    (models / "evil.tfmap").write_bytes(
        b'{"format": "talkingface.mapping/2"}\n'
        + pickle.dumps(_Touch(str(marker))))
    return root


class _Touch:
    """A pickle payload that would create a file when unpickled (a model file must be data)."""

    def __init__(self, path):
        self.path = path

    def __reduce__(self):
        return (Path.touch, (Path(self.path),))


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
    return lines[0]


CASES = [
    # config values and files (every command reads them the same way)
    (["synth", "--out", "new1", "--set", "synth.bogus=1"], ["synth.bogus"]),
    (["synth", "--out", "new1", "--set", "nosection.x=1"], ["nosection"]),
    (["synth", "--out", "new1", "--set", "synth.speakers=two"], ["synth.speakers", "two"]),
    (["synth", "--out", "new1", "--config", "bad.yaml"], ["bad.yaml"]),
    (["synth", "--out", "new1", "--config", "utf16.yaml"], ["utf16.yaml"]),
    (["synth", "--out", "new1", "--config", "list.yaml"], ["list.yaml"]),
    (["synth", "--out", "new1", "--config", "missing.yaml"], ["missing.yaml"]),
    (["synth", "--out", "new1", "--set", "tracker.init=magic"], ["tracker.init", "magic"]),
    # corpus folders and files
    (["synth", "--out", "c", *TINY], ["c", "--overwrite"]),
    (["synth", "--out", "speech.wav", *TINY], ["speech.wav"]),
    (["synth", "--out", "a_folder_x", "--text", "nope.txt"], ["nope.txt"]),
    (["units", "--corpus", "missing", "--out", "u"], ["missing"]),
    (["units", "--corpus", "nan_corpus", "--out", "u"], ["NaN"]),
    (["units", "--corpus", "c", "--out", "runs/R/units"], ["motion_units.npz", "--overwrite"]),
    # runs: a different config is refused before anything is touched
    (["replicate", "--name", "R", *QUICK, "--seed", "5"], ["different config"]),
    (["replicate", "--name", "../x"], ["../x"]),
    (["train", "--name", "R", *QUICK[:-2], "--seed", "9"], ["different config"]),
    (["ablate", "--grid", "missing.yaml", "--name", "R", *QUICK[:-2]], ["missing.yaml"]),
    (["report", "--name", "never"], ["never"]),
    (["report", "--study-data", "missing_study"], ["missing_study"]),
    # WAV files and outputs
    (["animate", "missing.wav", "-o", "o.mp4", "--model", "R"], ["missing.wav"]),
    (["animate", "empty.wav", "-o", "o.mp4", "--model", "R"], ["empty.wav"]),
    (["animate", "corrupt.wav", "-o", "o.mp4", "--model", "R"], ["corrupt.wav"]),
    (["animate", "speech.wav", "-o", "a_folder", "--model", "R"], ["a_folder"]),
    (["animate", "speech.wav", "-o", "speech.wav", "--model", "R"], ["speech.wav", "--overwrite"]),
    (["animate", "speech.wav", "-o", "o.mp4", "--model", "R", "--expression", "angry"],
     ["angry"]),
    (["animate", "speech.wav", "-o", "o.mp4", "--model", "R", "--keyframes", "k.txt"],
     ["k.txt"]),
    (["animate", "speech.wav", "-o", "o.mp4", "--model", "nope"], ["nope"]),
    (["stream", "--fast"], ["WAV file or --mic"]),
    (["stream", "missing.wav", "--fast", "--model", "R"], ["missing.wav"]),
    # model files
    (["animate", "speech.wav", "-o", "o.mp4", "--model", "runs/R/mapping/truncated.tfmap"],
     ["truncated.tfmap"]),
    (["animate", "speech.wav", "-o", "o.mp4", "--model", "runs/R/mapping/evil.tfmap"],
     ["evil.tfmap"]),
    # study ids and study data
    (["study", "run", "--participant", "P03\n", "--study-dir", "runs/R/study_data",
      "--stimuli", "runs/R/stimuli"], ["P03"]),
    (["study", "run", "--participant", "../P03", "--study-dir", "sd",
      "--stimuli", "runs/R/stimuli"], ["../P03"]),
    (["study", "release", "--participant", "NOBODY", "--study-dir", "runs/R/study_data"],
     ["NOBODY"]),
    (["analyze", "missing_study"], ["missing_study"]),
    (["study", "allocate", "--study-dir", "runs/R/study_data", "--n", "8"], ["allocation"]),
    (["study", "simulate", "--n", "4", "--study-dir", "sd2", "--stimuli", "missing_stim"],
     ["missing_stim"]),
    (["study", "stimuli", "--name", "R\n", *TINY], ["'R\\n'"]),
    (["track", "--name", "R", *QUICK[:-2], "--set", "tracker.corpus_noise_sd=-3"],
     ["tracker.corpus_noise_sd"]),
    (["ui", "--config", "bad.yaml"], ["bad.yaml"]),
    # damaged records
    (["units", "--corpus", "bad_info_corpus", "--out", "u"], ["corpus.json"]),
    (["report", "--name", "D"], ["done.json"]),
    (["animate", "speech.wav", "-o", "o.mp4", "--model", "D"], ["done.json"]),
]


@pytest.mark.parametrize("argv, names", CASES, ids=[" ".join(c[0])[:60] for c in CASES])
def test_bad_input_gets_one_clear_line_and_changes_nothing(world, monkeypatch, capsys, argv,
                                                           names):
    refused(world, monkeypatch, capsys, argv, *names)


def test_a_pickled_model_is_refused_without_running_it(world, monkeypatch, capsys):
    refused(world, monkeypatch, capsys,
            ["animate", "speech.wav", "-o", "o.mp4", "--model", "runs/R/mapping/evil.tfmap"],
            "evil.tfmap")
    assert not (world / "pwned").exists()


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
        assert main(["study", "simulate", "--n", "6", "--study-dir", "sim_ref", *stim]) == 0
    run_before = _final_files(world / "runs" / "R")
    _kill_when(["study", "simulate", "--n", "6", "--study-dir", "sim_cut", *stim], world,
               lambda: (world / "sim_cut" / "sub-SIM03").exists())
    assert _final_files(world / "runs" / "R") == run_before
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(world)
        assert main(["study", "simulate", "--n", "6", "--study-dir", "sim_cut", *stim]) == 0

    def files(folder):  # the allocation list's timestamps are the wall clock: left out
        return {k: v for k, v in _final_files(world / folder).items()
                if not k.startswith("allocation")}

    assert files("sim_cut") == files("sim_ref")
