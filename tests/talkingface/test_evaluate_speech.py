"""``talkingface evaluate-speech`` and the ``speech_eval`` stage score a (tiny) trained mapping on
real recordings, write their files, log one MLflow run per model, and refuse bad input in one
line; a model trained on a speaker is never scored on that speaker as "unseen"."""
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
from talkingface.stages import speech_eval as stage
from talkingface.stages.speech_eval import evaluate_models, evaluate_speech, find_models
from talkingface.stages.training import train_and_evaluate

TINY = ["mapping.baselines=[]", "mapping.splits=[utterance]", "mapping.train.max_epochs=8",
        "mapping.min_class_frames=20", "mlflow.enabled=false"]


def tiny_trained_run(root: Path, corpus_dir: Path) -> RunPaths:
    """runs/t under ``root`` with the corpus ``corpus_dir``, its Motion Units and a mapping
    trained for a few epochs (:data:`TINY`)."""
    paths = RunPaths.create("t", runs_dir=root / "runs")
    cfg = load_config(None, TINY)
    shutil.copytree(corpus_dir, paths.corpus)
    fit_units_folder(paths.corpus, paths.units, cfg)
    res = train_and_evaluate(paths.corpus, paths.units_model, paths.mapping, cfg, progress=False)
    (paths.mapping / DONE).write_text(json.dumps({"fingerprint": "test",
                                                  "models": res["models"]}))
    return paths


@pytest.fixture(scope="module")
def run_dir(small_corpus_dir, tmp_path_factory):
    """runs/t with the small corpus, its Motion Units and a mapping trained for a few epochs."""
    root = tmp_path_factory.mktemp("speech_eval")
    tiny_trained_run(root, small_corpus_dir)
    return root


def set_of(tmp_path, keep) -> Path:
    """A copy of the shipped set's manifest cut to the rows ``keep`` accepts, its folders
    linked, two levels below a link to face_model/ (the GRID rows read their audio through
    ``../../face_model``)."""
    root = tmp_path / "a"
    (root / "b" / "set").mkdir(parents=True)
    (root / "face_model").symlink_to(SET_DIR.parents[1] / "face_model")
    out = root / "b" / "set"
    for sub in SET_DIR.iterdir():
        if sub.is_dir():
            (out / sub.name).symlink_to(sub)
    rows = [r for r in read_manifest(SET_DIR) if keep(r)]
    with open(out / "manifest.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return out


@pytest.fixture
def small_set(tmp_path):
    """The shipped set cut down to two recordings (one ARCTIC, one pocketsphinx)."""
    return set_of(tmp_path, lambda r: r["id"] in ("slt_a0009", "ps_goforward"))


@pytest.fixture
def mixed_set(tmp_path):
    """ARCTIC slt, praatio's bobby, a pocketsphinx test recording and two GRID s1 sentences:
    four speakers."""
    grid = iter(range(2))
    return set_of(tmp_path, lambda r: r["id"] in ("slt_a0009", "praatio_bobby",
                                                    "ps_goforward")
                   or (r["speaker"] == "grid-s1" and next(grid, None) is not None))


def _rows(path) -> list:
    with open(path) as f:
        return list(csv.DictReader(f))


def test_the_stage_follows_the_models_it_scores_in_a_replication():
    # the paper's mapping, then the voice-robust models, then their scores on real speech
    order = [REPLICATION.index(s) for s in ("mapping", "voices", "speech_eval")]
    assert order == sorted(order) and order[2] == order[1] + 1
    assert {"mapping", "voices"} <= set(STAGES["speech_eval"].upstream)


def test_the_stage_scores_the_runs_model_on_every_real_recording(run_dir, mixed_set,
                                                                 monkeypatch):
    monkeypatch.setattr(stage, "SET_DIR", mixed_set)
    paths = RunPaths.create("t", runs_dir=run_dir / "runs")
    done = evaluate_speech(paths, load_config(None, TINY))
    out = paths.speech_eval
    for name in ("results.csv", "per_file.csv", "results.json", "rates.csv", "per_speaker.csv",
                 "comparisons.csv", "opening_gated_mlp_utterance.png"):
        assert (out / name).is_file(), name
    per_file = _rows(out / "per_file.csv")
    ids = {r["id"] for r in read_manifest(mixed_set)}
    for system in ("gated_mlp_utterance", "pocketsphinx-5.1.1 allphone", "pylipsync"):
        assert {r["id"] for r in per_file if r["model"] == system} == ids, system
    # an espeak-only corpus: its one training speaker is espeak, none of the set's
    assert done["training_speakers"] == {"gated_mlp_utterance": ["espeak"]}
    assert done["seen_speakers"] == {"gated_mlp_utterance": []}
    rows = {(r["model"], r["split"]): r for r in done["summary"]}
    model = rows[("gated_mlp_utterance", "unseen-test")]
    assert model["files"] == 5 and model["speakers"] == 4
    assert model["speaker_ids"] == "arctic-slt;grid-s1;pocketsphinx-test;praatio-bobby"
    assert rows[("gated_mlp_utterance", "seen")]["files"] == 0
    assert 0 <= model["bilabial_closed_frac"] <= 1 and -1 <= model["r_reference"] <= 1
    assert model["r_reference_lo"] <= model["r_reference"] <= model["r_reference_hi"]
    for k in ("chance_viseme_acc", "chance_bilabial_closed_frac", "chance_r_reference"):
        assert k in model
    # the model streams: its live markers equal its offline markers on one recording
    info = json.loads((out / "results.json").read_text())
    check = info["stream"]["gated_mlp_utterance"]
    assert check["stream_equals_offline"] and check["max_marker_diff_px"] < 1e-3
    # the streaming column is the live output: the offline figure (NaN alike for a gate of one
    # group)
    assert model["viseme_acc_stream_100ms"] == model["viseme_acc"] or (
        model["viseme_acc"] != model["viseme_acc"]
        and model["viseme_acc_stream_100ms"] != model["viseme_acc_stream_100ms"])
    assert info["split_ids"]["gated_mlp_utterance"]["unseen-test"]["speakers"] == [
        "arctic-slt", "grid-s1", "pocketsphinx-test", "praatio-bobby"]
    # every rate; the 16 kHz files are scored once at 16 kHz and said so
    rates = [r for r in _rows(out / "rates.csv") if r["model"] == "gated_mlp_utterance"
             and r["split"] == "unseen-test"]
    assert [r["input_rate"] for r in rates] == ["native", "16000", "8000"]
    assert rates[1]["rate_note"].startswith("3 recordings scored as recorded")
    # the per-speaker table sums to the pooled counts
    table = [r for r in _rows(out / "per_speaker.csv") if r["model"] == "gated_mlp_utterance"]
    for rate in ("native", "16000"):  # each rate's rows, every test recording once
        assert sum(int(r["files"]) for r in table if r["input_rate"] == rate) == rows[
            ("gated_mlp_utterance", "test")]["files"]
    assert {r["input_rate"] for r in table} == {"native", "16000"}
    assert {r["kind"] for r in table} == {"sentences"}
    # comparisons pair the default model with the recognisers (streaming) and the peers
    comp = _rows(out / "comparisons.csv")
    has_stream = model["viseme_acc_stream_100ms"] == model["viseme_acc_stream_100ms"]
    assert ("pocketsphinx-5.1.1 allphone" in {r["model_b"] for r in comp}) == has_stream
    assert {r["model_b"] for r in comp} >= {"loudness", "pylipsync"}
    assert all(r["model_a"] == "gated_mlp_utterance" for r in comp)


def _copy_run(run_dir, dest) -> Path:
    shutil.copytree(run_dir / "runs" / "t", dest, ignore=shutil.ignore_patterns("speech_eval"))
    return dest


def test_a_model_trained_on_a_synthetic_voice_of_slt_is_seen_on_slt(run_dir, mixed_set,
                                                                    tmp_path):
    run = _copy_run(run_dir, tmp_path / "runs" / "v")
    manifest = run / "corpus" / "manifest.csv"
    rows = _rows(manifest)
    for r in rows:
        r["voice"] = "flite:slt"
    with open(manifest, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    res = evaluate_models(find_models(str(run)), tmp_path / "ev" / "results.csv",
                          set_dir=mixed_set, recogniser=False, peers=False, rates=("native",))
    assert res["training_speakers"]["gated_mlp_utterance"] == ["arctic-slt"]
    by_id = {r["id"]: r["split"] for r in res["per_file"]}
    assert by_id["slt_a0009"] == "seen"
    unseen = [r for r in res["summary"] if r["split"].startswith("unseen") and r["files"]]
    assert unseen and all("arctic-slt" not in r["speaker_ids"] for r in unseen)


def test_a_nested_real_run_on_grid_s1_is_seen_on_grid_s1(run_dir, mixed_set, tmp_path):
    # runs/o/real: a nested real-speaker run whose corpus is given (GRID s1 recordings)
    real = _copy_run(run_dir, tmp_path / "runs" / "o" / "real")
    corpus = real / "corpus"
    info = json.loads((corpus / "corpus.json").read_text())
    (corpus / "corpus.json").write_text(json.dumps({**info, "source": "GRID s1 video"}))
    text = (corpus / "manifest.csv").read_text().splitlines()
    head = text[0].split(",")
    col = head.index("speaker")
    (corpus / "manifest.csv").write_text("\n".join(
        [text[0]] + [",".join(v if i != col else "grid-s1" for i, v in enumerate(line.split(",")))
                     for line in text[1:]]) + "\n")
    for models in (find_models(str(real)),
                   find_models(str(real / "mapping" / "gated_mlp_utterance.tfmap"))):
        assert models["gated_mlp_utterance"][2] == corpus
        res = evaluate_models(models, tmp_path / "ev" / "results.csv", set_dir=mixed_set,
                              recogniser=False, peers=False, rates=("native",))
        assert res["seen_speakers"]["gated_mlp_utterance"] == ["grid-s1"]
        splits = {r["id"]: (r["speaker"], r["split"]) for r in res["per_file"]}
        assert {s for spk, s in splits.values() if spk == "grid-s1"} == {"seen"}
        unseen = [r for r in res["summary"] if r["split"].startswith("unseen") and r["files"]]
        assert all("grid-s1" not in r["speaker_ids"] for r in unseen)


def test_the_command_prints_the_table_and_logs_one_mlflow_run_per_model(run_dir, small_set,
                                                                        workdir, capsys):
    shutil.copytree(run_dir / "runs", workdir / "runs")
    code = main(["evaluate-speech", "--model", "t", "--set-dir", str(small_set), "--out",
                 "ev/t.csv"])
    assert code == 0
    out = capsys.readouterr().out
    assert "gated_mlp_utterance" in out and "pocketsphinx-5.1.1 allphone" in out
    assert "training speakers of gated_mlp_utterance: espeak (seen in the set: none)" in out
    for name in ("t.csv", "t_per_file.csv", "t.json", "t_opening_gated_mlp_utterance.png",
                 "t_per_speaker.csv", "t_rates.csv", "t_comparisons.csv"):
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
