"""``talkingface evaluate-speech`` and the ``speech_eval`` stage score a (tiny) trained mapping on
real recordings, write their files, log one MLflow run per model, and refuse bad input in one
line."""
from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import pytest

from analysis.speech_set import SET_DIR, read_manifest
from talkingface.cli.main import main
from talkingface.config import load_config
from talkingface.paths import RunPaths
from talkingface.stages import REPLICATION, STAGES
from talkingface.stages.base import DONE
from talkingface.stages.foundation import fit_units_folder
from talkingface.stages.speech_eval import evaluate_speech
from talkingface.stages.training import train_and_evaluate

TINY = ["mapping.baselines=[]", "mapping.splits=[utterance]", "mapping.train.max_epochs=8",
        "mapping.min_class_frames=20", "mlflow.enabled=false"]


@pytest.fixture(scope="module")
def run_dir(small_corpus_dir, tmp_path_factory):
    """runs/t with the small corpus, its Motion Units and a mapping trained for a few epochs."""
    root = tmp_path_factory.mktemp("speech_eval")
    paths = RunPaths.create("t", runs_dir=root / "runs")
    cfg = load_config(None, TINY)
    shutil.copytree(small_corpus_dir, paths.corpus)
    fit_units_folder(paths.corpus, paths.units, cfg)
    res = train_and_evaluate(paths.corpus, paths.units_model, paths.mapping, cfg, progress=False)
    (paths.mapping / DONE).write_text(json.dumps({"fingerprint": "test",
                                                  "models": res["models"]}))
    return root


@pytest.fixture
def small_set(tmp_path):
    """The shipped set cut down to two recordings (one ARCTIC, one pocketsphinx)."""
    out = Path(shutil.copytree(SET_DIR, tmp_path / "set"))
    rows = [r for r in read_manifest(out) if r["id"] in ("slt_a0009", "ps_goforward")]
    with open(out / "manifest.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return out


def test_the_stage_follows_the_models_it_scores_in_a_replication():
    # the paper's mapping, then the voice-robust models, then their scores on real speech
    order = [REPLICATION.index(s) for s in ("mapping", "voices", "speech_eval")]
    assert order == sorted(order) and order[2] == order[1] + 1
    assert {"mapping", "voices"} <= set(STAGES["speech_eval"].upstream)


def test_the_stage_scores_the_runs_model_on_every_real_recording(run_dir):
    paths = RunPaths.create("t", runs_dir=run_dir / "runs")
    done = evaluate_speech(paths, load_config(None, TINY))
    out = paths.speech_eval
    for name in ("results.csv", "per_file.csv", "results.json",
                 "opening_gated_mlp_utterance.png"):
        assert (out / name).is_file(), name
    with open(out / "per_file.csv") as f:
        per_file = list(csv.DictReader(f))
    ids = {r["id"] for r in read_manifest()}
    assert {r["id"] for r in per_file if r["model"] == "gated_mlp_utterance"} == ids
    assert {r["id"] for r in per_file if r["model"].startswith("pocketsphinx")} == ids
    # an espeak-only corpus: no real speaker was heard in training
    assert done["seen_speakers"] == {"gated_mlp_utterance": []}
    rows = {(r["model"], r["split"]): r for r in done["summary"]}
    model = rows[("gated_mlp_utterance", "unseen")]
    assert model["files"] == len(ids) and rows[("gated_mlp_utterance", "seen")]["files"] == 0
    assert 0 <= model["bilabial_closed_frac"] <= 1 and -1 <= model["r_reference"] <= 1
    assert model["bilabial_segments"] >= 25
    assert rows[("pocketsphinx-5.1.1 allphone", "unseen")]["viseme_acc"] > 0.7


def test_the_command_prints_the_table_and_logs_one_mlflow_run_per_model(run_dir, small_set,
                                                                        workdir, capsys):
    shutil.copytree(run_dir / "runs", workdir / "runs")
    code = main(["evaluate-speech", "--model", "t", "--set-dir", str(small_set), "--out",
                 "ev/t.csv"])
    assert code == 0
    out = capsys.readouterr().out
    assert "gated_mlp_utterance" in out and "pocketsphinx-5.1.1 allphone" in out
    assert "seen speakers: gated_mlp_utterance: none" in out
    for name in ("t.csv", "t_per_file.csv", "t.json", "t_opening_gated_mlp_utterance.png"):
        assert (workdir / "ev" / name).is_file(), name
    import mlflow

    runs = mlflow.search_runs(experiment_names=["talkingface"],
                              filter_string="tags.stage = 'speech_eval'")
    assert list(runs["tags.speech_eval.model"]) == ["gated_mlp_utterance"]
    assert "metrics.unseen.bilabial_closed_frac" in runs.columns
    assert "metrics.bar.unseen.viseme_acc" in runs.columns


@pytest.mark.parametrize("args, message", [
    (["--model", "nothing"], "error: --model nothing: not a run under runs/, a run folder or "
                             "a .tfmap file"),
    (["--model", "x.tfmap"], "error: --model x.tfmap: file not found"),
    (["--model", "t", "--set-dir", "."], "error: manifest.csv: manifest not found"),
    (["--model", "t", "--out", "taken.csv"], "error: --out taken.csv already exists; pass "
                                             "--overwrite to replace it"),
])
def test_bad_input_is_one_line_and_exit_2(run_dir, workdir, capsys, args, message):
    shutil.copytree(run_dir / "runs", workdir / "runs")
    (workdir / "taken.csv").write_text("x\n")
    assert main(["evaluate-speech", *args, "--set", "mlflow.enabled=false"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(message), err
