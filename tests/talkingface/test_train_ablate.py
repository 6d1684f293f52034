"""The train and ablate commands, the logged pyfunc model, and the paper's mapping against the
linear and VQ baselines on held-out sentences. (``talkingface ui`` as a user starts it, its
front page and its stop: tests/talkingface/test_ui_landing.py, on one server for all the UI
tests.)"""
import csv
from pathlib import Path

import numpy as np
import pytest

from talkingface.cli.main import main

TINY = ["--set", "synth.n_sentences=4", "--set", "synth.workers=2", "--set", "real_speaker.corpus=''"]


def test_gated_mlp_beats_linear_and_vq_on_held_out_sentences(default_corpus):
    from analysis.evaluation import evaluate_experiment, ranking
    from face_model.motion_units import fit_corpus_units
    from mapping import build_dataset, run_experiment
    from talkingface.config import Config

    cfg = Config()
    units, _ = fit_corpus_units(default_corpus)
    data = build_dataset(default_corpus, units)
    trained = run_experiment(data, cfg.mapping, n_utterance=units.n_utterance, seed=cfg.seed,
                             methods=["gated_mlp", "linear", "vq"], splits=["utterance"])
    results = evaluate_experiment(trained, data, units)
    by = {x["method"]: x for x in ranking(results, "utterance")}
    for baseline in ("linear", "vq"):
        assert by["gated_mlp"]["R"] > by[baseline]["R"], by
        assert by["gated_mlp"]["MSE"] < by[baseline]["MSE"], by
    # every expression, not only the mean
    gated = next(r for r in results if r.method == "gated_mlp").tables
    linear = next(r for r in results if r.method == "linear").tables
    for e in ("neutral", "smile", "sad"):
        assert gated[e]["test"].R > linear[e]["test"].R
    # the lips beside R: the corpus's own mouths close on /p b m/; the gated MLP's lips err
    # less than the linear map's at their worst marker, and are ranked with LVE and closure
    lips = next(r for r in results if r.method == "gated_mlp").lips
    for e in ("neutral", "smile", "sad"):
        m = lips[e]["test"]
        assert m.bilabial_segments > 20 and m.closure_true >= 0.9, m
        assert 0 <= m.closure <= 1 and m.LVE > 0
    assert by["gated_mlp"]["LVE"] < by["linear"]["LVE"], by
    assert 0 <= by["gated_mlp"]["closure"] <= 1


def test_train_logs_a_pyfunc_model_that_predicts_from_a_wav(workdir, capsys):
    import mlflow
    import mlflow.pyfunc

    from groundwork.audio import read_wav, write_wav
    from mapping.checkpoint import AudioMapping
    from talkingface.stages.models import load_animator

    assert main(["train", "--name", "t", *TINY,
                 "--set", "mapping.baselines=[linear]"]) == 0
    out = capsys.readouterr().out
    assert "utterance split" in out and "gated_mlp" in out and "linear" in out
    model = mlflow.last_logged_model()
    run = mlflow.get_run(model.source_run_id)
    # every metric: expression x split x part, gate accuracy, training time
    for split in ("random_frames", "utterance"):
        for e in ("neutral", "smile", "sad"):
            for part in ("train", "test"):
                for k in ("R", "nu_d", "nu_d_est", "MSE", "LVE", "FDD", "R_lips", "closure"):
                    assert f"{split}.{e}.{part}.{k}" in run.data.metrics
        assert f"gate.{split}.neutral_test" in run.data.metrics
        assert f"fit_seconds.gated_mlp.{split}" in run.data.metrics
    assert run.data.params["mapping.n_classes"] == "44"
    artifacts = {a.path for a in mlflow.MlflowClient().list_artifacts(run.info.run_id, "mapping")}
    assert {"mapping/tables.csv", "mapping/trajectories.png",
            "mapping/gated_mlp_utterance.tfmap"} <= artifacts

    # models are data: the logged model is source code plus the .tfmap, no pickled object
    local = Path(mlflow.artifacts.download_artifacts(model.model_uri, dst_path=str(workdir / "m")))
    assert not [p for p in local.rglob("*") if p.suffix in (".pkl", ".pickle", ".cloudpickle")]
    assert "pyfunc_model.py" in (local / "MLmodel").read_text()

    wav = sorted((workdir / "runs" / "t" / "corpus" / "audio").glob("*.wav"))[0]
    loaded = mlflow.pyfunc.load_model(model.model_uri)
    mups = loaded.predict(str(wav))
    direct = AudioMapping.load(workdir / "runs" / "t" / "mapping" / "gated_mlp_utterance.tfmap")
    np.testing.assert_array_equal(mups, direct.predict_wav(wav))
    n_frames = np.load(workdir / "runs" / "t" / "corpus" / "markers" /
                       (wav.stem + ".npy")).shape[0]
    assert mups.shape == (n_frames, 9)
    assert np.all(mups[:, 7:] == 0)  # neutral by default: no expression MUPs
    # one audio -> MUP entry point: the pyfunc model applies the silence rule as animate does
    y, sr = read_wav(wav)
    padded = workdir / "padded.wav"
    write_wav(padded, np.concatenate([np.zeros(sr // 2), y, np.zeros(sr // 2)]), sr)
    animator, _ = load_animator("t")
    drawn = animator.mups(*read_wav(padded), "neutral")
    np.testing.assert_array_equal(loaded.predict(str(padded)), drawn)
    assert np.all(drawn[:5, :7] == animator.rest_.astype(np.float32))  # closed, neutral mouth
    smile = loaded.predict(str(wav), params={"expression": "smile"})
    assert np.abs(smile[:, 7:]).max() > 0
    from groundwork.audio import read_wav
    y, sr = read_wav(wav)
    np.testing.assert_allclose(loaded.predict({"audio": y, "sr": sr}), mups, rtol=0, atol=1e-5)


def test_ablate_leaves_a_parent_run_with_one_child_per_setting(workdir, capsys):
    import mlflow

    grid = workdir / "grid.yaml"
    grid.write_text("base:\n  mapping.splits: [utterance]\n  mapping.train.max_epochs: 20\n"
                    "children:\n  paper: {}\n"
                    "  classes-1: {mapping.n_classes: 1}\n"
                    "  baseline-linear: {mapping.method: linear}\n"
                    "  lookahead-gated-0: {mapping.context_forward: 0, "
                    "mapping.window_align: right}\n")
    assert main(["ablate", "--grid", str(grid), "--name", "a", *TINY, "--workers", "2",
                 "--seeds", "2"]) == 0
    runs = mlflow.search_runs(experiment_names=["talkingface"], output_format="list")
    parents = [r for r in runs if r.data.tags.get("stage") == "ablate"]
    assert len(parents) == 1
    children = [r for r in runs if r.data.tags.get("mlflow.parentRunId") ==
                parents[0].info.run_id]
    # one child run per setting and seed: replicate k trains with the run seed + 1000 k
    assert sorted((r.data.tags["ablation.setting"], r.data.tags["ablation.seed"])
                  for r in children) == sorted(
        (s, str(seed)) for s in ("baseline-linear", "classes-1", "lookahead-gated-0", "paper")
        for seed in (2002, 3002))
    for r in children:
        assert r.info.status == "FINISHED" and r.data.params["seed"] == \
            r.data.tags["ablation.seed"]
        assert "test.utterance.R" in r.data.metrics
        assert "test.utterance.LVE" in r.data.metrics
        assert "train.utterance.neutral.R" in r.data.metrics
        # a short name, the setting as a param (a chart axis) and the kind of grid as a tag
        assert r.info.run_name == f"{r.data.tags['ablation.setting']}/{r.data.params['seed']}"
        assert r.data.params["setting"] == r.data.tags["ablation.setting"]
        assert r.data.tags["grid"] == "ablations"
        # the test figures come first in MLflow's alphabetical lists of metrics
        assert sorted(r.data.metrics)[0].startswith("test.")
    by = {(r.data.tags["ablation.setting"], int(r.data.tags["ablation.seed"])): r
          for r in children}
    assert by["classes-1", 2002].data.params["mapping.n_classes"] == "1"
    assert by["baseline-linear", 3002].data.params["mapping.method"] == "linear"
    ab = workdir / "runs" / "a" / "ablations"
    with open(ab / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["setting"] for r in rows] == ["paper", "classes-1", "baseline-linear",
                                            "lookahead-gated-0"]
    from analysis.replicates import interval

    for r in rows:
        seeds = [by[r["setting"], s].data.metrics["test.utterance.R"] for s in (2002, 3002)]
        mean, half = interval(seeds)
        assert r["n_seeds"] == "2"
        assert float(r["utterance_R"]) == pytest.approx(mean)
        assert float(r["utterance_R_ci95"]) == pytest.approx(half)
    assert rows[0]["utterance_R_differs"] == "reference"
    # the paired tests of results.csv are those of the logged figures, paired by seed
    from analysis.replicates import paired_tests

    tests = paired_tests({n: {s: by[n, s].data.metrics["test.utterance.R"]
                              for s in (2002, 3002)} for n in (r["setting"] for r in rows)},
                         "paper")
    for r in rows[1:]:
        t = tests[r["setting"]]
        assert float(r["utterance_R_diff"]) == pytest.approx(t["diff"])
        assert float(r["utterance_R_p_holm"]) == pytest.approx(t["p_holm"])
        assert r["utterance_R_differs"] == str(t["differs"])
    # the seeds' own folders, and their figures row by row
    assert (ab / "replicates" / "seed-3002" / "paper" / "summary.json").is_file()
    with open(ab / "replicates.csv", newline="") as f:
        reps = list(csv.DictReader(f))
    assert len(reps) == 8
    for r in reps:
        assert float(r["utterance_R"]) == pytest.approx(
            by[r["setting"], int(r["seed"])].data.metrics["test.utterance.R"])
    # one class means one MLP, so the gate is always right
    assert float(rows[1]["utterance_gate_acc"]) == 1.0
    # the look-ahead curve: the paper's 3 frames + the centred window's 275 samples at 22050 Hz,
    # and 0 ms for no look-ahead with the window ending at the frame instant
    assert float(rows[0]["latency_ms"]) == pytest.approx(100 + 1000 * 275 / 22050)
    assert float(rows[3]["latency_ms"]) == 0.0 and rows[3]["window_align"] == "right"
    assert (workdir / "runs" / "a" / "ablations" / "lookahead.png").is_file()
    # the parent answers: its description, summary table and forest plot, the reference's
    # figures as its metrics, each equal to results.csv's
    parent = mlflow.get_run(parents[0].info.run_id)
    assert parent.data.tags["grid"] == "ablations"
    assert parent.data.metrics["reference.test.utterance.R"] == pytest.approx(
        float(rows[0]["utterance_R"]), abs=1e-12)
    assert parent.data.params["reference"] == "paper"
    best = max(rows, key=lambda r: float(r["utterance_R"]))["setting"]
    assert parent.data.params["best.utterance"] == best
    note = parent.data.tags["mlflow.note.content"]
    assert f"best: `{best}`" in note or best == "paper"
    for r in rows:
        assert f"| {r['setting']} | 2 | {float(r['utterance_R']):.3f} ± " in note
    top = {a.path for a in mlflow.MlflowClient().list_artifacts(parents[0].info.run_id)}
    assert {"summary.csv", "forest.png", "lookahead.png"} <= top
    with open(mlflow.artifacts.download_artifacts(run_id=parents[0].info.run_id,
                                                  artifact_path="summary.csv",
                                                  dst_path=str(workdir / "dl")),
              newline="") as f:
        summary = {r["setting"]: r for r in csv.DictReader(f)}
    for r in rows:
        assert float(summary[r["setting"]]["R"]) == pytest.approx(float(r["utterance_R"]))
        if r["setting"] != "paper":
            assert float(summary[r["setting"]]["p_holm"]) == pytest.approx(
                float(r["utterance_R_p_holm"]))


@pytest.mark.parametrize("grid_text, message", [
    ("children: {}\n", "needs a non-empty 'children' mapping"),
    ("children:\n  x: {mapping.nope: 1}\n", "child 'x': unknown config key mapping.nope"),
    ("children:\n  x: {}\nextra: 1\n", "unknown top-level keys"),
])
def test_bad_grids_are_refused_with_the_file_and_the_problem(workdir, capsys, grid_text,
                                                             message):
    from talkingface.stages.grid_files import load_grid
    from talkingface.config import Config
    from groundwork.errors import ParameterError

    grid = workdir / "g.yaml"
    grid.write_text(grid_text)
    with pytest.raises(ParameterError, match=message) as err:
        load_grid(grid, Config())
    assert str(grid) in str(err.value)
    assert main(["ablate", "--grid", str(workdir / "missing.yaml"), "--name", "m", *TINY]) == 2
    assert "ablation grid" in capsys.readouterr().err
