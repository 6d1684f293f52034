"""The ``speech_eval`` stage and ``talkingface evaluate-speech``: trained mappings scored on the
real-speech evaluation set (:mod:`analysis.speech_set`, :mod:`analysis.speech_eval`), beside the
reference bar of a recogniser trained on real speech (:mod:`analysis.speech_recogniser`).

Files written (``runs/<name>/speech_eval/`` for the stage; for the command, ``--out FILE`` and
files named after it: ``FILE``, ``<stem>_per_file.csv``, ``<stem>.json``, ``<stem>_opening_…``):

    results.csv     per model (and each recogniser) × split (seen, unseen, all, the unseen
                    development and test parts, the test part's independently labelled and
                    aligner-labelled recordings): the pooled figures
    per_file.csv    per model × recording
    lookahead.csv   per recogniser × split × look-ahead (0–200 ms): streaming viseme accuracy
    lookahead.png   that curve on the unseen test speakers, both kinds of labels
    results.json    both, with the set, the threshold and which speakers counted as seen
    opening_<model>.png  predicted vs reference lip opening on one real sentence with its phones
"""
from __future__ import annotations

import csv
import json
from pathlib import Path

from analysis.speech_eval import opening_figure, score_model, training_speakers
from analysis.speech_recogniser import lookahead_figure, recogniser_scores
from analysis.speech_set import MANIFEST, SET_DIR, load_speech_set, read_manifest
from face_model.motion_units import MotionUnits
from groundwork.errors import ParameterError
from mapping.checkpoint import AudioMapping
from talkingface.paths import RunPaths
from talkingface.stages.base import read_done, write_csv
from talkingface.stages.models import model_units
from talkingface.stages.voices import voices_models

FIGURE_RECORDING = "slt_a0009"  # a real sentence with hand-checked (HTS) labels
STREAM_DELAY_S = 0.1


def set_files(paths, cfg) -> list:
    """The evaluation set's files (the stage is made again when one changes)."""
    rows = read_manifest(SET_DIR)
    return [SET_DIR / MANIFEST] + [SET_DIR / r[k] for r in rows for k in ("wav", "labels")]


def output_files(out_csv) -> dict:
    """The files written beside the results CSV ``out_csv`` (see the module docstring)."""
    out_csv = Path(out_csv)
    stem = "" if out_csv.stem == "results" else f"{out_csv.stem}_"
    return {"results": out_csv, "per_file": out_csv.with_name(f"{stem}per_file.csv"),
            "json": out_csv.with_suffix(".json"),
            "lookahead": out_csv.with_name(f"{stem}lookahead.csv"),
            "lookahead_figure": out_csv.with_name(f"{stem}lookahead.png"),
            "figure": lambda model: out_csv.with_name(f"{stem}opening_{model}.png")}


def evaluate_models(models: dict, out_csv, *, set_dir=SET_DIR, recogniser: bool = True,
                    progress=None) -> dict:
    """Score every ``models`` entry (name → ``(tfmap, motion_units.npz, training corpus folder
    or None)``) on the set at ``set_dir`` and write the files of the module docstring into
    :func:`output_files` of ``out_csv``. A recording is *seen* for a model when its speaker
    is one of the voices of that model's training corpus. Returns what the JSON file holds."""
    files = output_files(out_csv)
    files["results"].parent.mkdir(parents=True, exist_ok=True)
    items = load_speech_set(set_dir)
    summary, per_file, seen_by = [], [], {}
    figure_item = next((it for it in items if it.id == FIGURE_RECORDING), items[0])
    for name, (tfmap, units, corpus) in models.items():
        if progress:
            progress(f"scoring {name} on {len(items)} recordings")
        mapping = AudioMapping.load(tfmap)
        seen = training_speakers(corpus) if corpus is not None else frozenset()
        scores = score_model(name, mapping, MotionUnits.load(units), items, seen)
        seen_by[name] = sorted(seen)
        summary += scores.summary_rows()
        per_file += scores.per_file_rows()
        fig = next(f for f in scores.files if f.id == figure_item.id)
        opening_figure(fig, figure_item.phones, files["figure"](name),
                       title=f"{name} on {figure_item.id} ({figure_item.speaker}, "
                             f"{'seen' if fig.seen else 'unseen'}): \"{figure_item.transcript}\"")
    if recogniser:
        if progress:
            progress("the recognisers (pocketsphinx, hama) on the same recordings")
        seen_any = frozenset(s for v in seen_by.values() for s in v)
        rec_files, rec_summary, curve = recogniser_scores(items, seen_any,
                                                          delay_s=STREAM_DELAY_S)
        summary += rec_summary
        per_file += rec_files
        write_csv(files["lookahead"], curve)
        lookahead_figure(curve, files["lookahead_figure"])
    write_csv(files["results"], summary)
    write_csv(files["per_file"], per_file)
    result = {"set_dir": str(Path(set_dir)), "recordings": [it.id for it in items],
              "seconds": round(sum(it.duration_s for it in items), 2),
              "seen_speakers": seen_by, "stream_delay_s": STREAM_DELAY_S,
              "figure_recording": figure_item.id, "summary": summary, "per_file": per_file,
              "models": {n: str(m[0]) for n, m in models.items()}}
    files["json"].write_text(json.dumps(result, indent=1, default=float))
    return result


def run_models(paths: RunPaths) -> dict:
    """The trained mappings of a run: name (``<method>_<split>``) → (tfmap, units, corpus)."""
    done = read_done(paths.mapping)
    if done is None or not done.get("models"):
        raise ParameterError(f"{paths.mapping} holds no trained mapping: train the run first "
                             "(talkingface train --name NAME)")
    return {Path(f).stem: (paths.mapping / f, paths.units_model, paths.corpus)
            for f in done["models"].values()}


def find_models(model: str, runs_dir="runs") -> dict:
    """``--model``: a run name (under ``runs_dir``), a run folder, or one ``.tfmap`` file
    (its run's Motion Units and corpus beside it) → :func:`run_models`' mapping."""
    p = Path(model)
    if p.suffix == ".tfmap":
        if not p.is_file():
            raise ParameterError(f"--model {p}: file not found")
        units = model_units(p)
        run = units.parent.parent
        corpus = run / "corpus"
        return {p.stem: (p, units, corpus if (corpus / "manifest.csv").is_file() else None)}
    if p.is_dir():
        return run_models(RunPaths(p.name, p, Path("reports")))
    if not (Path(runs_dir) / model).is_dir():
        raise ParameterError(f"--model {model}: not a run under {runs_dir}/, a run folder or a "
                             ".tfmap file")
    return run_models(RunPaths.create(model, runs_dir=runs_dir))


def evaluate_speech(paths: RunPaths, cfg) -> dict:
    """The run's mapping model(s) and its voice-robust models (stage ``voices``, each with the
    corpus it was trained on) on the real-speech set (stage ``speech_eval``)."""
    models = run_models(paths)
    for name, (tfmap, corpus) in voices_models(paths).items():
        models[f"voices-{name}"] = (tfmap, paths.units_model, corpus)
    res = evaluate_models(models, paths.stage("speech_eval") / "results.csv")
    return {"summary": res["summary"], "seen_speakers": res["seen_speakers"],
            "models": res["models"]}
