"""The ``talkingface`` command: one sub-command per stage, and ``replicate`` for all of them.

Every sub-command takes ``--config FILE`` (YAML, any subset of keys) and ``--set key=value``
(repeatable); unknown keys are errors. Errors the project raises on bad input are printed as one
line (``error: ...``) with exit status 2.
"""
from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import sys
import threading
import traceback
from pathlib import Path

from analysis.speech_set import SET_DIR
from data_synth.generate import synthesize_corpus
from face_model.corpus import load_corpus
from groundwork.atomic import check_output_file
from groundwork.cache import ArrayCache
from groundwork.errors import TalkingFaceError
from groundwork.memory import keep_freed_memory
from groundwork.owner import acquire, release_all
from talkingface.cli import cache as cache_cli, faces as faces_cli, lab_server as server_cli, runs, \
    study as study_cli
from talkingface.cli.animate import animate_file, stream_file, stream_microphone
from talkingface.cli.args import (config_args, corpus_arg, grid_args, grid_overrides,
                                  resolve_config, run_args, visual_source_arg)
from talkingface.cli.errors import error_line, os_error_line
from talkingface.cli.interrupts import INTERRUPTED, interrupts_for, end_after_interrupt
from talkingface.live import input_devices
from talkingface.config import apply_overrides, dump_config, load_config
from talkingface.experiments.log import (artifact_root, check_tracking, log_speech_eval_model,
                                        mlflow_run, tracking_uri)
from talkingface.experiments.mlflow_app import (APP_NAME, check_installed, find_experiment,
                                    grid_link_text, link_text)
from talkingface.experiments.processes import check_free
from talkingface.paths import RunPaths
from talkingface.stages import run
from talkingface.stages.foundation import fit_units_folder
from talkingface.stages.speech_eval import (evaluate_models, find_models, model_cache,
                                              output_files)


def cmd_synth(args) -> int:
    cfg = resolve_config(args)
    changes = {}
    if args.text:
        changes["text_file"] = str(args.text)
        if args.sentences is None:
            changes["n_sentences"] = 0  # all of the user's sentences
    if args.sentences is not None:
        changes["n_sentences"] = args.sentences
    if args.speakers is not None:
        changes["speakers"] = args.speakers
    cfg = apply_overrides(cfg, {"synth": changes})
    out = synthesize_corpus(args.out, cfg.synth, cfg.seed, overwrite=args.overwrite)
    dump_config(cfg, out / "config.yaml")
    c = load_corpus(out)
    print(f"wrote {out}: {len(c)} utterances, {c.n_frames} frames")
    return 0


def cmd_units(args) -> int:
    cfg = resolve_config(args)
    model = Path(args.out) / "motion_units.npz"
    if model.exists() and not args.overwrite:
        raise TalkingFaceError(f"{model} already exists; pass --overwrite to replace it (a "
                               "mapping trained on those Motion Units needs them as they are)")
    res = fit_units_folder(Path(args.corpus), Path(args.out), cfg)
    s = res["summary"]
    print(f"Motion Units fitted in {res['fit_seconds']:.2f} s -> "
          f"{Path(args.out) / 'motion_units.npz'}")
    print(f"{'':32s}{'ours':>10s}{'paper':>10s}")
    print(f"{s['n_utterance']} utterance MUs (neutral){'':7s}{100 * s['explained']['neutral']:9.2f}%"
          f"{100 * s['paper']['neutral']:9.2f}%")
    for k, v in s["explained"].items():
        if k != "neutral":
            print(f"{s['n_expression']} expression MUs ({k}){'':<{13 - len(k)}s}{100 * v:9.2f}%"
                  f"  >={100 * s['paper'][k]:.2f}%")
    return 0


def cmd_replicate(args) -> int:
    cfg = resolve_config(args, *grid_overrides(args))
    print(f"report: {runs.replicate(args.name, cfg, overwrite=args.overwrite)}")
    return 0


def cmd_train(args) -> int:
    done = runs.train(args.name, resolve_config(args), overwrite=args.overwrite)
    for split, rk in done["ranking"].items():
        print(f"{split} split, mean test R / MSE:")
        for x in rk:
            print(f"  {x['rank']}. {x['method']:<15} R={x['R']:.3f}  MSE={x['MSE']:.4f}")
    print(f"tables and models: {RunPaths.create(args.name).mapping}")
    return 0


def cmd_track(args) -> int:
    # a tracked run: train, ablate and replicate then reuse the tracked corpus
    cfg = resolve_config(args, "mapping.visual_source=tracked")
    done = runs.track(args.name, cfg, overwrite=args.overwrite)
    print(f"{done['utterances']} utterances ({done['frames']} frames) rendered at image noise sd "
          f"{cfg.tracker.corpus_noise_sd:g} and tracked from the {cfg.tracker.init} placement: "
          f"marker error mean {done['error_px_mean']:.3f} px, 95th percentile "
          f"{done['error_px_p95']:.3f} px")
    print(f"tracked corpus: {RunPaths.create(args.name).tracked} (train on it with "
          "--visual-source tracked)")
    return 0


def cmd_front_end(args) -> int:
    done = runs.front_end(args.name, resolve_config(args), overwrite=args.overwrite)
    minutes = sum(done["minutes_of_audio"].values())
    print(f"front end taught by hama on {minutes:.1f} min of audio ({done['examples']} "
          f"examples with the augmented copies; speakers: {', '.join(done['training_speakers'])})"
          f": teacher pass {done['teacher_seconds']:.0f} s ({done['teacher']['heard']} heard, "
          f"{done['teacher']['reused']} from the cache), training {done['train_seconds']:.0f} s")
    t = done["training"]
    last = t["history"][-1]
    print(f"  {t['train_minutes']:.1f} min of training audio, {t['utterances']['heldout']} "
          f"utterances held out; {len(t['history'])} epochs, the weights of epoch "
          f"{t['best_epoch']} kept (held-out loss {last['heldout_loss']:.3f} at the last)")
    print(f"model: {RunPaths.create(args.name).stage('front_end') / done['model']} (use it with "
          "--set mapping.recogniser=causal --set mapping.front_model=FILE)")
    return 0


def cmd_ablate(args) -> int:
    done = runs.ablate(args.name, resolve_config(args, *grid_overrides(args)),
                       overwrite=args.overwrite)
    for r in done["rows"]:
        figures = "  ".join(f"{k}={float(v):.4f}" for k, v in r.items()
                            if k.endswith(("_R", "_MSE")) and v != "")
        print(f"  {r['setting']:<24} {figures}")
    print(f"results: {RunPaths.create(args.name).ablations / 'results.csv'}")
    return 0


def cmd_report(args) -> int:
    if args.study_data is not None:
        seed = study_cli.monte_carlo_seed(args.seed)
        print("report: " + str(study_cli.study_report(args.study_data, args.name, seed=seed,
                                                      allow_incomplete=args.allow_incomplete,
                                                      overwrite=args.overwrite)))
        return 0
    if not args.name:
        raise TalkingFaceError("give --name RUN (a replication's report) or --study-data DIR "
                               "(a study's report from its data alone)")
    paths = RunPaths.create(args.name)
    if not paths.config.is_file():
        raise TalkingFaceError(f"{paths.config} not found: run 'talkingface replicate --name "
                               f"{args.name}' first")
    acquire(paths.root, "run")
    run(["report"], paths, load_config(paths.config))
    print(f"report: {paths.pdf}")
    return 0


def cmd_ui(args) -> int:
    cfg = load_config(args.config, args.overrides)
    check_tracking(cfg)  # a store of another kind, or a file that is not a database: one line
    uri = tracking_uri(cfg)
    check_free("127.0.0.1", args.port)  # a bad port, or one in use: one line, before MLflow
    check_installed()  # the app below is registered in this environment
    # MLflow's server with this project's app: a browser that has not chosen MLflow's GenAI
    # or model-training view opens experiments on their runs table (talkingface/experiments/mlflow_app.py)
    # one web worker and no job runner (MLflow's GenAI jobs), as `talkingface server`: MLflow's
    # default four workers and its runner each import MLflow at start, which doubled the wait
    # for the first page on 2 cores (tests/talkingface/test_ui_landing.py)
    cmd = [sys.executable, "-m", "mlflow", "server", "--backend-store-uri", uri,
           "--host", "127.0.0.1", "--port", str(args.port), "--workers", "1",
           "--app-name", APP_NAME]
    if uri.startswith("sqlite:"):
        cmd += ["--default-artifact-root", artifact_root()]
    base = f"http://127.0.0.1:{args.port}"
    print(f"MLflow UI on {base} (store: {uri}); Ctrl-C stops it", flush=True)
    up = threading.Event()
    announce = threading.Thread(target=_print_link_when_up, daemon=True,
                                args=(base, cfg.mlflow.experiment, up))
    announce.start()
    try:
        return serve(cmd, env={**os.environ, "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"})
    finally:
        up.set()  # the server stopped: no link to wait for
        announce.join(timeout=15)


def _print_link_when_up(base: str, experiment: str, stop: threading.Event) -> None:
    """Once the server answers: the link to the experiment's pipeline runs and grid parents
    (looked up through the server, read only) and one to its grids' runs, or to the front page
    when the store has no such experiment yet."""
    while not stop.wait(0.5):
        try:
            found = find_experiment(base, experiment, timeout=5)
        except (OSError, ValueError):  # not up yet (or still migrating the store)
            continue
        print(f"MLflow UI: {link_text(base, experiment, found)}", flush=True)
        grids = grid_link_text(base, found)
        if grids:
            print(f"MLflow UI: {grids}", flush=True)
        return


def serve(cmd: list, env: dict | None = None) -> int:
    """Run a server process (environment ``env``, else this one's) until it exits; SIGTERM or
    SIGINT to this process is passed on to it (its own workers stop with it) and waited for,
    so nothing is left running."""
    proc = subprocess.Popen(cmd, env=env)

    def forward(signum, frame):
        if proc.poll() is None:
            proc.send_signal(signum)

    old = {sig: signal.signal(sig, forward) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        while True:
            try:
                return proc.wait()
            except KeyboardInterrupt:  # pragma: no cover - SIGINT is handled by forward()
                forward(signal.SIGINT, None)
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def cmd_animate(args) -> int:
    res = animate_file(args.wav, args.out, expression=args.expression, model=args.model,
                       markers_out=args.markers, keyframes_out=args.keyframes,
                       overwrite=args.overwrite)
    if res["warning"]:
        print(f"warning: {res['warning']}", file=sys.stderr)
    print(f"{args.out}: {res['frames']} frames ({res['audio_s']:.2f} s of audio) in "
          f"{res['seconds']:.2f} s = {res['x_realtime']:.1f}x real time; model {res['model']}")
    return 0


def cmd_stream(args) -> int:
    if args.list_devices:
        devices = input_devices()
        for d in devices:
            print(f"{d['index']}: {d['name']} ({d['channels']} in, {d['rate']:.0f} Hz)")
        if not devices:
            print("no audio input devices")
        return 0
    if (args.wav is None) == (not args.mic):
        raise TalkingFaceError("give a WAV file or --mic (one of them)")
    if args.seconds is not None and not (math.isfinite(args.seconds) and args.seconds > 0):
        raise TalkingFaceError(f"--seconds {args.seconds:g}: allowed: a finite number > 0")
    if args.show and not os.environ.get("DISPLAY"):
        raise TalkingFaceError("--show needs an X display and DISPLAY is not set; run without "
                               "--show, or where a display is (xvfb-run for none)")
    show = args.show
    if args.mic:
        device = int(args.device) if args.device and args.device.isdigit() else args.device
        res = stream_microphone(expression=args.expression, model=args.model,
                                seconds=args.seconds, device=device, show=show)
        source = f"the microphone ({res['device']}, {res['device_rate']} Hz)"
    else:
        res = stream_file(args.wav, expression=args.expression, model=args.model,
                          paced=not args.fast, show=show)
        source = str(args.wav)
    if res["warning"]:
        print(f"warning: {res['warning']}", file=sys.stderr)
    line = (f"{res['frames']} frames streamed from {res['audio_s']:.2f} s of audio from "
            f"{source}; algorithmic latency {1000 * res['algorithmic_latency_s']:.0f} ms; "
            f"compute per frame p50 {1000 * res['compute_p50_s']:.2f} ms, p99 "
            f"{1000 * res['compute_p99_s']:.2f} ms")
    if res["paced"]:  # wall-clock latency only means something when the input is real time
        line += (f"; measured latency p50 {1000 * res['latency_p50_s']:.0f} ms, p99 "
                 f"{1000 * res['latency_p99_s']:.0f} ms")
    else:
        line += "; the audio arrived faster than real time, so no latency is measured"
    print(line)
    return 0


def cmd_evaluate_speech(args) -> int:
    cfg = resolve_config(args)
    check_tracking(cfg)  # before the evaluation, not after it
    models = find_models(args.model)
    files = output_files(args.out)
    for path in (files["results"], files["per_file"], files["json"]):
        check_output_file(path, "--out", overwrite=args.overwrite)
    res = evaluate_models(models, args.out, set_dir=args.set_dir, targets=cfg.targets,
                          per_speaker=cfg.speech_set.per_speaker,
                          progress=lambda msg: print(msg, file=sys.stderr),
                          cache=ArrayCache(model_cache(args.model)), workers=0)
    part = res["speech_set"]
    if part["per_speaker"]:
        print(f"a part of the set: {len(res['recordings'])} of {part['set_recordings']} "
              f"recordings (the first {part['per_speaker']} of each speaker and part; "
              "speech_set.per_speaker)", file=sys.stderr)
    passes = res["recogniser_passes"]
    print(f"recognisers: {passes['heard']} recordings heard, {passes['reused']} read from the "
          "cache", file=sys.stderr)
    key = res["stream_key"]
    cols = (("viseme_acc", "viseme"), ("chance_viseme_acc", "chance"), (key, "stream"),
            ("bilabial_closed_frac", "p b m"), ("chance_bilabial_closed_frac", "chance"),
            ("r_reference", "r speech"), ("chance_r_reference", "chance"))
    print(f"native input rate; chance: the same prediction circularly shifted; "
          f"stream: live output at {key.rsplit('_', 1)[-1]} of look-ahead")
    print(f"{'system':<30}{'split':<25}{'spk/rec':>8}" + "".join(f"{c:>9}" for _, c in cols))
    for r in res["summary"]:
        if not r.get("files") or r["split"] not in ("seen", "unseen-test",
                                                    "unseen-test-independent", "unseen-dev"):
            continue
        figures = "".join(f"{r[k]:9.3f}" if isinstance(r.get(k), float) and r[k] == r[k]
                          else f"{'-':>9}" for k, _ in cols)
        who = f"{r['speakers']}/{r['files']}"
        print(f"{r['model'][:29]:<30}{r['split']:<25}{who:>8}{figures}")
    for m in res["models"]:
        print(f"training speakers of {m}: {', '.join(res['training_speakers'][m]) or 'none'}"
              f" (seen in the set: {', '.join(res['seen_speakers'][m]) or 'none'})")
    for model in res["models"]:
        with mlflow_run(cfg, run_name=f"speech_eval:{model}") as mlf:
            if mlf is not None:
                log_speech_eval_model(mlf, res, files["results"].parent, model)
    print(f"results: {files['results']} (per file: {files['per_file']}; per speaker: "
          f"{files['per_speaker']}; by input rate: {files['rates']}; {files['json']})")
    return 0


def _corpus_commands(sub) -> None:
    s = sub.add_parser("synth", help="generate the synthetic audio-visual corpus")
    s.add_argument("--out", required=True, type=Path, help="corpus folder to create")
    s.add_argument("--text", type=Path, help="your own sentences, one per line")
    s.add_argument("--sentences", type=int, help="number of sentences (default: 100; 0: every "
                   "sentence of the source, 360 built in, or all of --text)")
    s.add_argument("--speakers", type=int, help="number of speakers (default: 1)")
    s.add_argument("--overwrite", action="store_true", help="replace an existing corpus folder")
    config_args(s)
    s.set_defaults(func=cmd_synth)

    s = sub.add_parser("units", help="fit the Motion Units on a corpus")
    s.add_argument("--corpus", required=True, type=Path)
    s.add_argument("--out", required=True, type=Path, help="folder for motion_units.npz")
    s.add_argument("--overwrite", action="store_true", help="replace the Motion Units there")
    config_args(s)
    s.set_defaults(func=cmd_units)


def _run_commands(sub) -> None:
    s = sub.add_parser("replicate", help="run every stage into runs/<name> and write the report")
    run_args(s, "run name (runs/<name>, reports/<name>.pdf)")
    corpus_arg(s)
    visual_source_arg(s)
    grid_args(s, required=False, workers_help="worker processes for ablations (0: all cores)")
    s.add_argument("--voices", metavar="GRID",
                   help="voice-robust models trained and scored on real speech ('none' to "
                        "skip; default: the project's configs/voices.yaml; same as --set "
                        "voices.grid=GRID)")
    s.set_defaults(func=cmd_replicate)

    s = sub.add_parser("train", help="train and evaluate the mapping and the baselines "
                       "(runs/<name>/mapping), logged to MLflow with the pyfunc model")
    run_args(s, "run name (its corpus and MUs are made if missing)")
    corpus_arg(s)
    visual_source_arg(s)
    s.set_defaults(func=cmd_train)

    s = sub.add_parser("track", help="render the run's corpus as marker video and track it with "
                       "the MU-constrained tracker (runs/<name>/tracked, a corpus); the run "
                       "trains on it (its config gets mapping.visual_source=tracked)")
    run_args(s, "run name (its corpus and MUs are made if missing)")
    s.set_defaults(func=cmd_track)

    s = sub.add_parser("front-end", help="teach the run's causal phone front end from hama "
                       "(runs/<name>/front_end/causal_front.npz)")
    run_args(s, "run name (its corpus is made if missing)")
    s.set_defaults(func=cmd_front_end)

    s = sub.add_parser("ablate", help="one MLflow child run per setting of an ablation grid")
    grid_args(s, required=True, workers_help="worker processes (0: all cores)")
    run_args(s, "run whose corpus and MUs are used")
    corpus_arg(s)
    visual_source_arg(s)
    s.set_defaults(func=cmd_ablate)

    s = sub.add_parser("report", help="rebuild reports/<name>.pdf from runs/<name>, or a study "
                       "report from study data alone (--study-data)")
    s.add_argument("--name", help="run name (with --study-data: the PDF's name; default: the "
                   "data folder's name, with a part of its path when another study has that "
                   "name)")
    s.add_argument("--study-data", type=Path, help="a study data folder (real or simulated): "
                   "reports/study/<name>.pdf")
    s.add_argument("--allow-incomplete", action="store_true", help="with --study-data: analyse "
                   "the complete sessions of a folder that has incomplete ones (said in the PDF)")
    s.add_argument("--seed", type=int, help="seed of the Monte Carlo parts (default 0)")
    s.add_argument("--overwrite", action="store_true", help="with --study-data: replace a "
                   "study report of that name")
    s.set_defaults(func=cmd_report)

    s = sub.add_parser("evaluate-speech", help="score trained mappings on the real-speech "
                       "evaluation set (viseme accuracy, lip closure, labiodental contact, "
                       "reference correlation, each with its chance baseline, per speaker and "
                       "at native/16 kHz/8 kHz input) beside the recognisers and the lip-sync "
                       "peers; one MLflow run each")
    s.add_argument("--model", required=True, help="run name, run folder (all its models; a "
                   "nested real-speaker run runs/NAME/real too) or .tfmap file")
    s.add_argument("--set-dir", type=Path, default=SET_DIR, help="evaluation set folder with "
                   "manifest.csv (default: the shipped analysis/real_speech)")
    s.add_argument("--out", type=Path, default=Path("speech_eval") / "results.csv",
                   help="results CSV; the per-file CSV, JSON and figures are written beside it")
    s.add_argument("--overwrite", action="store_true", help="replace output files that exist")
    config_args(s)
    s.set_defaults(func=cmd_evaluate_speech)

    s = sub.add_parser("ui", help="start the MLflow UI on 127.0.0.1 against the same store "
                       "(it opens experiments on their runs table; one web worker, no job "
                       "runner) and print the link to the runs of the experiment "
                       "(mlflow.experiment)")
    s.add_argument("--port", type=int, default=5000)
    s.add_argument("--config", metavar="FILE")
    s.add_argument("--set", dest="overrides", action="append", default=[])
    s.set_defaults(func=cmd_ui)


def _face_commands(sub) -> None:
    s = sub.add_parser("animate", help="animate a face from a WAV file into an MP4 (H.264, "
                       "30 fps, audio muxed)")
    s.add_argument("wav", type=Path, help="speech (any sample rate, mono or stereo)")
    s.add_argument("-o", "--out", type=Path, required=True, help="the MP4 to write")
    s.add_argument("--expression", default="neutral", help="neutral, smile or sad")
    s.add_argument("--model", help="run name, run folder or .tfmap (default: the latest run)")
    s.add_argument("--markers", type=Path, help="also write the markers (n_frames, 79, 2) .npy")
    s.add_argument("--overwrite", action="store_true", help="replace output files that exist")
    s.add_argument("--keyframes", type=Path, help="also write keyframe tracks (.json or .csv: "
                   "weights of smile, sad, i, a, o, f, u, m per frame)")
    s.set_defaults(func=cmd_animate)

    s = sub.add_parser("stream", help="stream a WAV through the real-time animator, paced in "
                       "real time, and report the latency")
    s.add_argument("wav", type=Path, nargs="?", help="speech to stream (or --mic)")
    s.add_argument("--mic", action="store_true", help="stream from the microphone (the default "
                   "input device, or --device) until Ctrl-C or --seconds")
    s.add_argument("--device", help="input device index or name (see --list-devices)")
    s.add_argument("--seconds", type=float, help="with --mic: stop after this much audio")
    s.add_argument("--list-devices", action="store_true", help="list the audio input devices")
    s.add_argument("--expression", default="neutral")
    s.add_argument("--model", help="run name, run folder or .tfmap (default: the latest run)")
    s.add_argument("--show", action="store_true", help="show the face in a window (needs a "
                   "display)")
    s.add_argument("--fast", action="store_true", help="do not pace the input in real time")
    s.set_defaults(func=cmd_stream)


class _Parser(argparse.ArgumentParser):
    """argparse with a usage mistake (a missing argument, a value of the wrong type) as one
    line ``error: ...`` and exit status 2, like every other user error (its sub-command
    parsers are of this class too)."""

    def error(self, message):
        self.exit(2, f"error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="talkingface", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    _corpus_commands(sub)
    _run_commands(sub)
    _face_commands(sub)
    faces_cli.add_parser(sub)
    study_cli.add_parser(sub)
    server_cli.add_parser(sub)
    cache_cli.add_parser(sub)
    return p


def main(argv=None) -> int:
    """Run one command. A user's mistake (a value, a file the user named) is one line on stderr
    with exit status 2; anything else is a bug and keeps its traceback."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help, or a usage mistake (its line is printed)
        return exc.code
    keep_freed_memory()  # every epoch's tensors reuse memory (groundwork.memory)
    try:
        with interrupts_for(args.command):  # Ctrl-C: this process's, not its workers'
            return args.func(args)
    except TalkingFaceError as exc:
        print(error_line(str(exc)), file=sys.stderr)
    except OSError as exc:  # a path that is missing, a folder, unreadable or not writable
        line = os_error_line(exc)
        if line is None:  # no path to name: a bug
            raise
        print(line, file=sys.stderr)
    except KeyboardInterrupt:
        print(INTERRUPTED, file=sys.stderr)
        end_after_interrupt()
        return 130
    finally:
        release_all()  # the runs and sessions this command held
    return 2


def entry() -> None:
    """The console command: ``main`` with a line under an unexpected traceback."""
    try:
        code = main()
    except Exception:
        traceback.print_exc()
        print("error: the traceback above is a bug in talkingface, not a mistake in your input; "
              "please report it with the command you ran", file=sys.stderr)
        code = 1
    sys.exit(code)


if __name__ == "__main__":
    entry()
