"""The command line and the replicate pipeline on a tiny corpus, with a throw-away MLflow store."""
import csv
import json
import shutil

import pytest
from pypdf import PdfReader

from talkingface.cli.main import main
# for the tests of the pipeline's bookkeeping, not of its figures: 3 sentences, less training
# (the linear baseline only, 20 epochs), 4 simulated participants, no MLflow, and no ablations,
# no voice-robust models, no ceiling decomposition. The suite shares one finished run made with
# these settings (small_run_dir in tests/conftest.py).
from tests.talkingface.bad_input_cases import QUICK as SMALL_RUN

from tests.talkingface.full_run import TINY


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    return tmp_path


def pdf_text(path) -> str:
    return "\n".join(page.extract_text() for page in PdfReader(path).pages)


def test_replicate_writes_runs_report_and_mlflow(full_run_dir, monkeypatch):
    """The whole replication, small (``full_run_dir``, tests/conftest.py: every stage, a real
    speaker (a quarter of GRID s1's sentences), three voice-robust models (one on the real
    speaker's training sentences), four ceiling steps,
    MLflow): what needs a real run is that the stages hand each other real files and the
    report cites them."""
    workdir = full_run_dir
    monkeypatch.chdir(workdir)  # read only: find_model looks for runs/ here
    run = workdir / "runs" / "tiny"
    for p in ("config.yaml", "corpus/manifest.csv", "corpus/done.json", "units/motion_units.npz",
              "units/variance.csv", "report/summary.json", "report/mu_variance.png",
              "front_end/causal_front.npz", "speech_eval/latency.json",
              "voices/causal/gated_mlp_utterance.front.npz"):
        assert (run / p).is_file(), p
    text = pdf_text(workdir / "reports" / "tiny.pdf")
    # the causal child read the run's own front end, and keeps a copy of it beside its model
    from mapping.checkpoint import AudioMapping
    from mapping.recogniser import recogniser_name

    causal = AudioMapping.load(run / "voices" / "causal" / "gated_mlp_utterance.tfmap")
    assert recogniser_name(causal.mapper.recogniser) == \
        recogniser_name(f"causal:{run / 'front_end' / 'causal_front.npz'}")
    assert "The causal front end's training" in text
    latency = json.loads((run / "speech_eval" / "latency.json").read_text())
    assert set(latency["models"]) >= {"voices-one", "voices-many", "voices-causal"}
    # the first page says what the run found, each figure as on the page it cites
    from tests.analysis.findings_check import findings_of, mismatches, page_texts

    leads = [f.split(".")[0] for f in findings_of(page_texts(workdir / "reports" / "tiny.pdf")[0])]
    assert leads == ["Table II", "The gap to the paper", "Real speech",
                     "Real faces never trained on", "A real face",
                     "Where the real speaker's R goes", "Perception study"]
    assert mismatches(workdir / "reports" / "tiny.pdf") == []
    assert "MU variance explained: ours vs the paper's" in text
    assert "Utterance MUs (neutral speech)" in text and "97.56 %" in text
    # the paper's pipeline on the built-in real speaker, scored against the real lips
    real = json.loads((run / "real_speaker" / "summary.json").read_text())
    assert real["corpus"]["utterances"] == 49 and real["test_utterances"]
    assert (run / "real" / "mapping" / "tables.csv").is_file()
    assert "A real speaker (GRID s1)" in text and "Cooke" in text
    speaker_r = real["face_scores"]["speaker_model"]["pooled"]["r_speech"]
    assert f"{speaker_r:.3f}" in text
    # the one held-out sentence of the quarter with a shipped video, drawn side by side
    assert real["side_by_side"] == {"videos": ["side_by_side_bgbh7a.mp4"], "clips": ["bgbh7a"],
                                    "without_video": len(real["test_utterances"]) - 1}
    from groundwork.movie import check_mp4

    check_mp4(run / "real_speaker" / "side_by_side_bgbh7a.mp4")
    assert "A held-out clip's video: left of each pair the tracked markers" in text
    # the articulation fitted on the real mouth against the hand table, on held-out lips
    art = json.loads((run / "articulation" / "summary.json").read_text())
    assert [r["model"] for r in art["rows"]] == ["articulatory space", "hand table",
                                                 "fitted (grid-s1)"]
    assert art["held_out_clips"] == len(real["test_utterances"])
    assert "The articulation fitted on the real mouth" in text
    assert f"{art['rows'][2]['r_opening']:.2f}" in text
    # every candidate's lips on the development face (s26) and the test faces (s31, s1)
    with open(run / "real_faces" / "results.csv", newline="") as f:
        faces = list(csv.DictReader(f))
    models = {r["model"] for r in faces}
    assert {"voices-one", "voices-many", "voices-real", "voices-causal", "paper",
            "speaker-trained", "loudness", "openfacefx-text", "openfacefx-energy",
            "pylipsync"} == models
    assert {(r["part"], r["speaker"]) for r in faces} == {
        ("dev", "all"), ("dev", "grid-s26"), ("test", "all"), ("test", "grid-s31"),
        ("test", "grid-s1")}
    rates = {m: {r["rate"] for r in faces if r["model"] == m} for m in models}
    assert rates["voices-many"] == {"native", "16000", "8000"}  # the default: every rate
    assert rates["speaker-trained"] == rates["pylipsync"] == {"native", "16000", "8000"}
    assert rates["voices-one"] == {"native"}
    seen = {(r["model"], r["speaker"]): r["seen"] for r in faces}
    assert seen[("voices-real", "grid-s1")] == "True" and \
        seen[("voices-real", "grid-s31")] == "False"
    assert seen[("speaker-trained", "grid-s1")] == "True"
    assert seen[("voices-one", "grid-s1")] == "False"
    # where its R goes, measured on the same training sentences the nested run trained on
    steps = json.loads((run / "real_steps" / "steps.json").read_text())
    assert steps["training_sentences"] == 49 - len(real["test_utterances"])
    assert "Where the real speaker's R goes" in text
    assert f"{steps['reconstruction_r']:.3f}" in text
    # the trained steps: each child with two seeds, on the training sentences' own split
    with open(run / "real_steps" / "results.csv", newline="") as f:
        trained = {r["step"]: r for r in csv.DictReader(f)}
    assert set(trained) == {"ours", "oracle"} and trained["oracle"]["n_seeds"] == "2"
    assert "the trained pipeline, training sentences" in text
    assert f"{float(trained['ours']['utterance_R']):.3f}" in text
    summary = json.loads((run / "report" / "summary.json").read_text())
    ours = f"{100 * summary['units']['explained']['neutral']:.2f} %"
    assert ours in text  # our figure, as text, in the table
    # the mapping: Tables I and II with our figures beside the paper's, and the ranking
    assert "TABLE I:" in text and "TABLE II:" in text
    assert "Lips and face beside Table II" in text and "LVE (px)" in text
    with open(run / "mapping" / "tables.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    for part, paper_r in (("train", "0.980"), ("test", "0.968")):
        ours = next(r for r in rows if r["method"] == "gated_mlp" and r["split"] == "utterance"
                    and r["expression"] == "neutral" and r["part"] == part)
        assert f"{float(ours['R']):.3f}" in text and paper_r in text
    assert "Methods ranked by mean test R (utterance split)" in text
    for method in ("gated_mlp", "vq", "linear", "gmm_regression", "mlp_large", "tdnn", "gru"):
        assert method in text

    import mlflow

    mlflow.set_tracking_uri(f"sqlite:///{workdir / 'mlflow.db'}")
    runs = mlflow.search_runs(experiment_names=["talkingface"], output_format="list")
    top = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    assert len(top) == 1
    r = top[0]
    # one child run per model scored on real speech, so they compare in the UI
    scored = {c.data.tags.get("speech_eval.model") for c in runs
              if c.data.tags.get("mlflow.parentRunId") == r.info.run_id}
    assert {"gated_mlp_utterance", "voices-one", "voices-many"} <= scored
    # the UI opens the experiment on its training runs, not on its GenAI pages
    tags = mlflow.get_experiment_by_name("talkingface").tags
    assert tags["mlflow.experimentKind"] == "custom_model_development"
    # the ceiling steps: a parent run with one child per step; a step that changes synth has
    # its own corpus; the report's section has every step and the paper's value
    parent = next(c for c in runs if c.data.tags.get("stage") == "ceiling")
    steps = {c.data.tags.get("ceiling.setting") for c in runs
             if c.data.tags.get("mlflow.parentRunId") == parent.info.run_id}
    assert steps == {"ours", "no-brow-motion", "tracked", "oracle"}
    assert parent.data.tags["grid"] == "ceiling" and parent.data.params["reference"] == "ours"
    assert "best: " in parent.data.tags["mlflow.note.content"]
    parent = next(c for c in runs if c.data.tags.get("stage") == "real_steps")
    assert {c.data.tags.get("real_steps.setting") for c in runs
            if c.data.tags.get("mlflow.parentRunId") == parent.info.run_id} == {"ours", "oracle"}
    # the voice-robust models: a parent with one child per model and the models side by side
    voices = next(c for c in runs if c.data.tags.get("stage") == "voices")
    kids = [c for c in runs if c.data.tags.get("mlflow.parentRunId") == voices.info.run_id]
    assert sorted(c.info.run_name for c in kids) == ["causal/2002", "many/2002", "one/2002",
                                                     "real/2002"]
    assert {c.data.tags["grid"] for c in kids} == {"voices"}
    assert voices.data.params["default"] == "many"
    note = voices.data.tags["mlflow.note.content"]
    assert "default model: `many`" in note and "| one |" in note
    with open(run / "ceiling" / "results.csv", newline="") as f:
        ceiling = {row["step"]: row for row in csv.DictReader(f)}
    assert ceiling["ours"]["corpus"] == ceiling["oracle"]["corpus"] == "the run's"
    own = run / "ceiling" / ceiling["no-brow-motion"]["corpus"]
    assert json.loads((own / "corpus.json").read_text())["settings"]["brow_px"] == 0
    assert "synth.brow_px=0" in ceiling["no-brow-motion"]["changes"]
    tracked = run / "ceiling" / ceiling["tracked"]["corpus"]
    assert tracked.name == "tracked" and "mapping.visual_source=tracked" in \
        ceiling["tracked"]["changes"]
    assert json.loads((tracked / "corpus.json").read_text())["source"] == "tracked"
    with open(tracked / "tracking.csv", newline="") as f:
        assert len(list(csv.DictReader(f))) == 9  # every utterance of the run's corpus tracked
    assert "Where Table II stands" in text and "no-brow-motion" in text and "0.968" in text
    assert r.data.params["synth.n_sentences"] == "3"
    assert r.data.metrics["corpus.n_utterances"] == 9
    assert abs(r.data.metrics["units.explained.neutral"]
               - summary["units"]["explained"]["neutral"]) < 1e-12
    assert len(r.data.tags["corpus_hash"]) == 64 and "git_commit" in r.data.tags
    assert (workdir / "mlartifacts").is_dir()
    # the perception study: the stimuli and twenty simulated participants, ten per sequence
    from study.stimuli import load_manifest

    assert len(load_manifest(run / "stimuli")) == 21
    subjects = sorted((run / "study_data").glob("sub-*/sub-*_task-emotion_beh.csv"))
    assert len(subjects) == 20
    with open(run / "study_data" / "allocation.csv", newline="") as f:
        slots = list(csv.DictReader(f))
    assert sorted(s["sequence"] for s in slots) == ["RS"] * 10 + ["SR"] * 10
    assert all(s["status"] == "complete" for s in slots)
    assert "Perception study" in text and "simulated FLMP observers" in text
    for table in ("TABLE III", "TABLE IV", "TABLE V", "TABLE VI", "TABLE VII"):
        assert f"{table}:" in text  # ours beside the paper's, all seven tables in one PDF
    assert "Model comparison" in text and "Synthetic vs real face: paired tests" in text
    _check_voices_and_real_speech(run, rows, text)


def _check_voices_and_real_speech(run, table_rows, text):
    """The voice-robust models and their scores on real recordings (stages voices and
    speech_eval), the default model of animate and the study, and the report's section."""
    from talkingface.stages.models import find_model

    with open(run / "voices" / "results.csv", newline="") as f:
        voices = {r["model"]: r for r in csv.DictReader(f)}
    assert set(voices) == {"one", "many", "real", "causal"} and voices["many"]["default"] == "True"
    # the child with the run's own settings is the run's mapping again: its in-domain R is
    # Table II's mean test R (utterance split), recomputed from its predictions
    ours = [float(r["R"]) for r in table_rows if r["method"] == "gated_mlp"
            and r["split"] == "utterance" and r["part"] == "test"]
    assert abs(float(voices["one"]["in_domain_R"]) - sum(ours) / len(ours)) < 1e-9
    manifest = (run / "voices" / "corpora" / "0" / "manifest.csv").read_text()
    assert all(v in manifest for v in ("espeak:en-us+f3", "flite:awb", "festival:kal_diphone"))
    # every model scored on the real recordings; flite's awb is the ARCTIC speaker awb
    with open(run / "speech_eval" / "results.csv", newline="") as f:
        scores = list(csv.DictReader(f))
    models = {r["model"] for r in scores}
    assert {"gated_mlp_utterance", "voices-one", "voices-many", "voices-real",
            "voices-causal"} <= models
    # the real-face child: the real speaker's training sentences only, its own Motion Units
    real_part = {r.split(",")[0] for r in
                 (run / "voices" / "corpora" / "real" / "manifest.csv").read_text().split()[1:]}
    held = json.loads((run / "real_speaker" / "summary.json").read_text())["test_utterances"]
    assert real_part and not real_part & set(held)
    assert (run / "voices" / "real" / "motion_units.npz").is_file()
    assert voices["real"]["real_face"] == "alone"
    seen = {r["model"]: int(r["files"]) for r in scores if r["split"] == "seen"}
    assert seen["voices-many"] == 1 and seen["voices-one"] == 0
    assert seen["voices-real"] >= 1  # the real speaker's own recordings are not unseen
    assert any(m.startswith("pocketsphinx") for m in models)
    assert any(m.startswith("hama") for m in models)
    # the run's own causal front end is scored beside them, its training speakers seen: the
    # run's espeak voice and the front end's voices (front_end.voices: espeak only here)
    front = next(m for m in models if m.startswith("causal-front"))
    from mapping.recogniser import recogniser_name

    assert front == recogniser_name(f"causal:{run / 'front_end' / 'causal_front.npz'}")
    assert {r["split"] for r in scores if r["model"] == front} >= {"unseen-test-independent"}
    # the test part apart by where its labels came from, and the front ends' look-ahead curve
    splits = {r["split"] for r in scores if r["model"].startswith("hama")}
    assert {"unseen-test-independent", "unseen-test-aligned"} <= splits
    with open(run / "speech_eval" / "lookahead.csv", newline="") as f:
        curve = list(csv.DictReader(f))
    assert {float(r["lookahead_ms"]) for r in curve} == {0, 33.3, 66.7, 100, 133.3, 166.7, 200}
    assert (run / "speech_eval" / "lookahead.png").is_file()
    assert "The front ends alone" in text and "labels independent of both recognisers" in text
    # animate, stream and the study use the voice-robust model by default
    tfmap, _ = find_model(None)
    assert tfmap.resolve() == run / "voices" / "many" / "gated_mlp_utterance.tfmap"
    assert "Real speech, unseen speakers" in text and "voices-many is the one" in text


def test_replicate_refuses_a_different_config_under_the_same_name(workdir, capsys,
                                                                  small_run_dir):
    # the run replicate made with these settings (once per test run, under the name R:
    # small_run_dir), copied here under the name r
    shutil.copytree(small_run_dir / "runs" / "R", workdir / "runs" / "r")
    assert main(["replicate", "--name", "r", *SMALL_RUN]) == 0
    stamp = (workdir / "runs" / "r" / "corpus" / "done.json").read_text()
    code = main(["replicate", "--name", "r", *SMALL_RUN, "--seed", "5"])
    assert code == 2
    assert "was made with a different config" in capsys.readouterr().err
    # nothing was touched
    assert (workdir / "runs" / "r" / "corpus" / "done.json").read_text() == stamp
    # the same config again reuses the finished corpus
    assert main(["replicate", "--name", "r", *SMALL_RUN]) == 0
    assert (workdir / "runs" / "r" / "corpus" / "done.json").read_text() == stamp
    # a study setting with --overwrite re-runs the study stages and nothing upstream of them
    run = workdir / "runs" / "r"
    kept = {s: (run / s / "done.json").read_text() for s in ("corpus", "units", "mapping",
                                                            "stimuli")}
    assert main(["replicate", "--name", "r", *SMALL_RUN, "--overwrite", "--set",
                 "study.n_participants=6"]) == 0
    assert {s: (run / s / "done.json").read_text() for s in kept} == kept
    assert len(list((run / "study_data").glob("sub-*/sub-*_task-emotion_beh.csv"))) == 6
    assert json.loads((run / "analysis" / "done.json").read_text())["participants"] == 6


def test_synth_then_units_print_the_variance(workdir, capsys):
    assert main(["synth", "--out", "c", *TINY]) == 0
    assert "9 utterances" in capsys.readouterr().out
    assert main(["units", "--corpus", "c", "--out", "u"]) == 0
    out = capsys.readouterr().out
    assert "7 utterance MUs (neutral)" in out
    assert "2 expression MUs (smile)" in out and "2 expression MUs (sad)" in out
    assert "97.56%" in out and ">=98.13%" in out
    # an existing corpus folder is never overwritten without --overwrite
    assert main(["synth", "--out", "c", *TINY]) == 2
    assert "already exists and is not empty" in capsys.readouterr().err


def test_user_text_file(workdir, capsys):
    (workdir / "mine.txt").write_text("# my sentences\nA cat sat on the mat.\n\nWe went home.\n")
    assert main(["synth", "--out", "c", "--text", "mine.txt", "--set", "synth.expressions=[neutral]"]) == 0
    assert "2 utterances" in capsys.readouterr().out
    assert main(["synth", "--out", "d", "--text", "nope.txt"]) == 2
    assert "--text file nope.txt not found" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["replicate", "--name", "../x"], "run name '../x' is not allowed"),
    (["synth", "--out", "c", "--set", "synth.bogus=1"], "unknown config key synth.bogus"),
    (["units", "--corpus", "missing", "--out", "u"], "missing/manifest.csv: manifest not found"),
    (["report", "--name", "never"], "runs/never/config.yaml not found"),
])
def test_errors_are_one_clear_line(workdir, capsys, argv, message):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err


def test_ui_serves_the_same_store_on_localhost(workdir, monkeypatch, capsys):
    import talkingface.cli.main as cli

    calls = []
    monkeypatch.setattr(cli, "serve", lambda cmd, env=None: calls.append((cmd, env)) or 0)
    assert main(["ui", "--port", "5099"]) == 0
    cmd, env = calls[0]
    assert cmd[cmd.index("--host") + 1] == "127.0.0.1" and cmd[cmd.index("--port") + 1] == "5099"
    # one web worker and no job runner, as the lab server
    assert cmd[cmd.index("--workers") + 1] == "1"
    assert env["MLFLOW_SERVER_ENABLE_JOB_EXECUTION"] == "false"
    assert cmd[cmd.index("--backend-store-uri") + 1] == f"sqlite:///{workdir / 'mlflow.db'}"
    assert cmd[cmd.index("--default-artifact-root") + 1] == (workdir / "mlartifacts").as_uri()
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "postgresql://db.example/mlflow")
    assert main(["ui"]) == 0
    cmd = calls[1][0]
    assert cmd[cmd.index("--backend-store-uri") + 1] == "postgresql://db.example/mlflow"
    assert "--default-artifact-root" not in cmd
