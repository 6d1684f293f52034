"""The ``speech_eval`` stage and ``talkingface evaluate-speech``: trained mappings scored on the
real-speech evaluation set (:mod:`analysis.speech_set`, :mod:`analysis.speech_eval`), beside the
phone recognisers trained on real speech (:mod:`analysis.speech_recogniser`) and the lip-sync
tools users already use (:mod:`analysis.speech_peers`), with the speaker as the unit
(:mod:`analysis.speech_pooling`).

Files written (``runs/<name>/speech_eval/`` for the stage; for the command, ``--out FILE`` and
files named after it: ``FILE``, ``<stem>_per_file.csv``, ``<stem>.json``, ``<stem>_opening_…``):

    results.csv     per system (model, recogniser, peer) × split (seen, unseen, all, test, the
                    unseen development and test parts, the test part's independently labelled
                    and aligner-labelled recordings), at the recordings' native rate: the pooled
                    figures, each with its chance baseline (``chance_*``), the speakers and
                    recordings behind it and speaker-level intervals (``*_lo``/``*_hi`` or
                    ``interval_note``)
    per_file.csv    per system × recording, native rate
    rates.csv       the pooled rows at every input rate (native, 16 kHz, 8 kHz: the default
                    model re-run on the resampled audio, every model with ``all_rates``;
                    the other models, recognisers and peers at the native rate)
    rates_per_file.csv  per model × recording at 16 kHz and 8 kHz
    per_speaker.csv per system × speaker of the test part, native rate and 16 kHz
    comparisons.csv the default model − each recogniser (streaming viseme accuracy at the
                    targets' look-ahead) and − each peer (viseme accuracy, closure, r) on the
                    same unseen test recordings, with paired speaker-level intervals
    lookahead.csv   per recogniser × split × look-ahead (0–200 ms): streaming viseme accuracy
    lookahead.png   that curve on the unseen test speakers, both kinds of labels
    results.json    the rows above, with the set (``recordings``: the ids scored;
                    ``speech_set``: ``per_speaker``, the setting ``speech_set.per_speaker``
                    they were picked by, 0 for every recording, and ``set_recordings``, how many
                    the set's manifest lists), each model's training speakers, the
                    speakers and recording ids of every split row, and whether each model's
                    live output equals its offline output
    opening_<model>.png  predicted vs reference lip opening on one real sentence with its phones
    latency.json    each candidate default (the voices children) and the default model streamed
                    alone through ``talkingface stream``'s animator, paced in real time, on one
                    recording (:mod:`talkingface.stages.latency`): latency and compute p50/p99;
                    the development rule excludes a model over ``targets.stream_latency_p99_ms``
"""
from __future__ import annotations

import json
from contextlib import nullcontext
from pathlib import Path

from analysis.config import TargetsConfig
from analysis.speech_eval import NATIVE, RATES, model_jobs, opening_figure, score_model, \
    synth_of, training_speakers
from analysis.speech_peers import peer_scores
from analysis.speech_pooling import SPLITS, compare, summarise
from analysis.speech_pooling import per_speaker as speaker_rows
from analysis.speech_recogniser import RECOGNISERS, lookahead_figure, recogniser_jobs, \
    recogniser_scores
from analysis.dev_rule import LATENCY_FILE
from analysis.speech_report import RECOGNISERS as RECOGNISER_ROWS
from analysis.speech_set import MANIFEST, SET_DIR, load_speech_set, read_manifest, subset_rows
from face_model.motion_units import MotionUnits
from groundwork.cache import ArrayCache
from groundwork.errors import ParameterError
from mapping.checkpoint import AudioMapping
from mapping.hearing import hear_all
from mapping.recogniser import hearing_cache, recogniser_speakers
from talkingface.paths import RunPaths
from talkingface.stages.base import read_done, write_csv
from talkingface.stages.front_end import front_end_applies, front_file
from talkingface.stages.latency import measure_models
from talkingface.stages.models import model_run, model_units
from talkingface.stages.voices import voices_models

FIGURE_RECORDING = "slt_a0009"  # a real sentence with hand-checked (HTS) labels


def set_files(paths, cfg) -> list:
    """The evaluation set's files the stage scores (its manifest, and the audio and labels of
    the recordings ``speech_set.per_speaker`` picks): the stage is made again when one changes,
    or when the setting picks others."""
    rows = subset_rows(read_manifest(SET_DIR), cfg.speech_set.per_speaker)
    return [SET_DIR / MANIFEST] + [SET_DIR / r[k] for r in rows for k in ("wav", "labels")]


def output_files(out_csv) -> dict:
    """The files written beside the results CSV ``out_csv`` (see the module docstring)."""
    out_csv = Path(out_csv)
    stem = "" if out_csv.stem == "results" else f"{out_csv.stem}_"
    return {"results": out_csv, "per_file": out_csv.with_name(f"{stem}per_file.csv"),
            "json": out_csv.with_suffix(".json"),
            "rates": out_csv.with_name(f"{stem}rates.csv"),
            "rates_per_file": out_csv.with_name(f"{stem}rates_per_file.csv"),
            "per_speaker": out_csv.with_name(f"{stem}per_speaker.csv"),
            "comparisons": out_csv.with_name(f"{stem}comparisons.csv"),
            "lookahead": out_csv.with_name(f"{stem}lookahead.csv"),
            "lookahead_figure": out_csv.with_name(f"{stem}lookahead.png"),
            "figure": lambda model: out_csv.with_name(f"{stem}opening_{model}.png")}


def stream_key(lookahead_ms: float) -> str:
    """The results column of streaming viseme accuracy at ``lookahead_ms``."""
    return f"viseme_acc_stream_{round(lookahead_ms)}ms"


def _comparisons(per_file: list, default: str | None, others: list, key: str) -> list:
    out = []
    if default is None:
        return out
    for other in others:
        figs = ((key,) if other.startswith(RECOGNISER_ROWS) else
                ("viseme_acc", "bilabial_closed_frac", "r_reference"))
        for fig in figs:
            for split in ("unseen-test", "unseen-test-independent"):
                row = compare(per_file, default, other, fig, key, split=split)
                if row is not None:
                    out.append(row)
    return out


def front_speakers(mapping) -> frozenset:
    """The speakers ``mapping``'s recogniser front end was trained on, when it is a causal front
    end of ours (a score on one of them is seen); else none."""
    if not mapping.needs_phones:
        return frozenset()
    return recogniser_speakers(getattr(mapping.mapper, "recogniser", "pocketsphinx"))


def run_recognisers(paths: RunPaths, cfg) -> tuple:
    """The recognisers a run scores: pocketsphinx, hama and its own causal front end (the
    ``front_end`` stage's model file; the shipped one when the stage does not run)."""
    front = front_file(paths)
    own = front_end_applies(cfg) and front.is_file()
    return (*(r for r in RECOGNISERS if r != "causal"),
            f"causal:{front.resolve()}" if own else "causal")


def _split_ids(per_file: list) -> dict:
    """``{model: {split: {"speakers": [...], "recordings": [...]}}}`` at the native rate."""
    out = {}
    for r in per_file:
        for split, keep in SPLITS.items():
            if keep(r):
                d = out.setdefault(r["model"], {}).setdefault(split, {"speakers": set(),
                                                                      "recordings": []})
                d["speakers"].add(r["speaker"])
                d["recordings"].append(r["id"])
    return {m: {s: {"speakers": sorted(d["speakers"]), "recordings": d["recordings"]}
                for s, d in v.items()} for m, v in out.items()}


def evaluate_models(models: dict, out_csv, *, set_dir=None, recogniser: bool = True,
                    peers: bool = True, rates=RATES, default_model: str | None = None,
                    all_rates: bool = False, targets: TargetsConfig = TargetsConfig(),
                    per_speaker: int = 0, progress=None, cache=None, workers: int = 0,
                    recognisers: tuple = RECOGNISERS) -> dict:
    """Score every ``models`` entry (name → ``(tfmap, motion_units.npz, training corpus folder
    or None)``) on the set at ``set_dir`` (default: the shipped set) at the native rate, and
    ``default_model`` (every model with ``all_rates``: each costs a full pass per rate) at each
    input rate of ``rates`` too, beside the recognisers and the peers (native rate), and
    write the files of the module docstring into :func:`output_files` of ``out_csv``. A
    recording is *seen* for a model when its speaker is one of that model's training speakers
    (:func:`analysis.speech_eval.training_speakers`); the recognisers and peers take the
    splits of ``default_model`` (default: the first model), the model every comparison is made
    against. The streaming column is at ``targets.lookahead_ms``. ``per_speaker`` (the
    setting ``speech_set.per_speaker``): 0 scores every recording of the set, N the first N
    of each speaker and part (:func:`analysis.speech_set.subset_rows`); the JSON file says
    which (``speech_set``). ``cache`` (a :class:`groundwork.cache.ArrayCache`): every
    recording each model's recogniser front end and the recognisers hear is heard first, on
    ``workers`` processes (0: all cores; :func:`mapping.hearing.hear_all`), into the cache,
    and the scores read it (the result's ``recogniser_passes`` counts recordings heard and
    reused); None: heard one by one while scoring. The figures are the same either way.
    ``recognisers``: the recognisers scored beside the models (``recogniser``: whether any
    is); a run names its own causal front end's model file (``causal:<file>``). A recording
    is also *seen* for a model whose recogniser front end is a causal front end trained on its
    speaker, and for that front end's own rows (:func:`mapping.recogniser.recogniser_speakers`).
    Returns what the JSON file holds."""
    files = output_files(out_csv)
    files["results"].parent.mkdir(parents=True, exist_ok=True)
    set_dir = SET_DIR if set_dir is None else set_dir
    items = load_speech_set(set_dir, per_speaker=per_speaker)
    n_set = len(read_manifest(set_dir))
    key = stream_key(targets.lookahead_ms)
    default_model = default_model if default_model in models else next(iter(models), None)
    mappings = {name: AudioMapping.load(tfmap) for name, (tfmap, _, _) in models.items()}
    rates_of = {name: rates if all_rates or name == default_model else (NATIVE,)
                for name in models}
    passes = None
    if cache is not None:
        if progress:
            progress("hearing the recordings (each recogniser front end, the recognisers)")
        jobs = [j for name, mp in mappings.items() for j in model_jobs(mp, items, rates_of[name])]
        if recogniser:
            jobs += recogniser_jobs(items, recognisers=recognisers)
        passes = hear_all(jobs, cache, workers=workers, desc="hearing the speech set")
    with hearing_cache(cache) if cache is not None else nullcontext():
        res = _score(models, mappings, rates_of, items, files, key, default_model, set_dir,
                     recogniser=recogniser and tuple(recognisers), peers=peers, rates=rates, targets=targets,
                     progress=progress)
    res["speech_set"] = {"per_speaker": per_speaker, "set_recordings": n_set}
    if passes is not None:
        res["recogniser_passes"] = passes.as_dict()
    files["json"].write_text(json.dumps(res, indent=1, default=float))
    return res


def _score(models, mappings, rates_of, items, files, key, default_model, set_dir, *,
           recogniser, peers, rates, targets, progress) -> dict:
    """:func:`evaluate_models`' scores and files, the recordings heard or read as they come."""
    per_file, train_by, stream_by, default_synth = [], {}, {}, None
    figure_item = next((it for it in items if it.id == FIGURE_RECORDING), items[0])
    for name, (tfmap, units, corpus) in models.items():
        if progress:
            progress(f"scoring {name} on {len(items)} recordings at {len(rates_of[name])} "
                     "input rate(s)")
        mapping = mappings[name]
        train_by[name] = ((training_speakers(corpus) if corpus is not None else frozenset())
                          | front_speakers(mapping))
        scores = score_model(name, mapping, MotionUnits.load(units), items, train_by[name],
                             rates=rates_of[name],
                             lookahead_s=targets.lookahead_ms / 1000,
                             check_item=figure_item)
        stream_by[name] = scores.stream
        per_file += scores.per_file_rows(key)
        if name == default_model:
            default_synth = synth_of(mapping)
        fig = next(f for f in scores.files if f.id == figure_item.id)
        opening_figure(fig, figure_item.phones, files["figure"](name),
                       title=f"{name} on {figure_item.id} ({figure_item.speaker}, "
                             f"{'seen' if fig.seen else 'unseen'}): \"{figure_item.transcript}\"")
    seen_default = train_by.get(default_model, frozenset())
    others = []
    if recogniser:
        if progress:
            progress(f"the recognisers ({', '.join(recogniser)}) on the same recordings")
        rec_files, _, curve = recogniser_scores(items, seen_default, summary=False,
                                                recognisers=recogniser,
                                                delay_s=targets.lookahead_ms / 1000)
        per_file += rec_files
        others += list(dict.fromkeys(r["model"] for r in rec_files))
        write_csv(files["lookahead"], curve)
        lookahead_figure(curve, files["lookahead_figure"])
    if peers and default_synth is not None:
        peer_rows = peer_scores(items, set_dir, *default_synth, seen=seen_default,
                                stream_key=key, progress=progress)
        per_file += peer_rows
        others += list(dict.fromkeys(r["model"] for r in peer_rows))
    summary_all = summarise(per_file, key)
    native = [r for r in per_file if r["input_rate"] == NATIVE]
    summary = [r for r in summary_all if r["input_rate"] == NATIVE]
    speakers = speaker_rows(native, key) + speaker_rows(per_file, key, input_rate="16000")
    comparisons = _comparisons(native, default_model, others, key)
    write_csv(files["results"], summary)
    write_csv(files["per_file"], native)
    write_csv(files["rates"], summary_all)
    write_csv(files["rates_per_file"], [r for r in per_file if r["input_rate"] != NATIVE])
    write_csv(files["per_speaker"], speakers)
    write_csv(files["comparisons"], comparisons)
    set_speakers = {it.speaker for it in items}
    result = {"set_dir": str(Path(set_dir)), "recordings": [it.id for it in items],
              "speakers": sorted(set_speakers),
              "seconds": round(sum(it.duration_s for it in items), 2),
              "training_speakers": {m: sorted(s) for m, s in train_by.items()},
              "seen_speakers": {m: sorted(s & set_speakers) for m, s in train_by.items()},
              "default_model": default_model, "stream_key": key,
              "stream_delay_s": targets.lookahead_ms / 1000, "stream": stream_by,
              "rates": [str(r) for r in rates], "split_ids": _split_ids(native),
              "figure_recording": figure_item.id, "summary": summary,
              "rates_summary": summary_all, "per_speaker": speakers,
              "comparisons": comparisons, "per_file": native,
              "models": {n: str(m[0]) for n, m in models.items()}}
    return result


def run_models(paths: RunPaths) -> dict:
    """The trained mappings of a run: name (``<method>_<split>``) → (tfmap, units, corpus)."""
    done = read_done(paths.mapping)
    if done is None or not done.get("models"):
        raise ParameterError(f"{paths.mapping} holds no trained mapping: train the run first "
                             "(talkingface train --name NAME)")
    return {Path(f).stem: (paths.mapping / f, paths.units_model, paths.corpus)
            for f in done["models"].values()}


def _tfmap_corpus(tfmap: Path) -> Path | None:
    """The corpus a ``.tfmap`` was trained on: a voice-robust model's own corpus
    (``<run>/voices/<child>/``, from the voices stage's record), else its run's ``corpus/``
    (``runs/<name>/mapping`` or a nested real run's ``runs/<name>/real/mapping``); None when
    that folder holds no manifest."""
    run = model_run(tfmap)
    if tfmap.parent.parent.name == "voices":
        for path, corpus, _ in voices_models(RunPaths.at(run)).values():
            if Path(path).resolve() == tfmap.resolve():
                return corpus if (Path(corpus) / "manifest.csv").is_file() else None
    corpus = run / "corpus"
    return corpus if (corpus / "manifest.csv").is_file() else None


def find_models(model: str, runs_dir="runs") -> dict:
    """``--model``: a run name (under ``runs_dir``), a run folder (a nested real-speaker run
    ``runs/<name>/real`` too), or one ``.tfmap`` file (its run's Motion Units and training
    corpus found from it: :func:`_tfmap_corpus`) → :func:`run_models`' mapping."""
    p = Path(model)
    if p.suffix == ".tfmap":
        if not p.is_file():
            raise ParameterError(f"--model {p}: file not found")
        units = model_units(p)
        return {p.stem: (p, units, _tfmap_corpus(p))}
    if p.is_dir():
        return run_models(RunPaths.at(p, reports_dir="reports"))
    if not (Path(runs_dir) / model).is_dir():
        raise ParameterError(f"--model {model}: not a run under {runs_dir}/, a run folder or a "
                             ".tfmap file")
    return run_models(RunPaths.create(model, runs_dir=runs_dir))


def model_cache(model: str, runs_dir="runs") -> Path:
    """The content-keyed cache of ``--model`` (as :func:`find_models` reads it): the cache of
    the run it belongs to (:attr:`talkingface.paths.RunPaths.cache`)."""
    p = Path(model)
    if p.suffix == ".tfmap":
        run = model_run(p)
    elif p.is_dir():
        run = p
    else:
        run = Path(runs_dir) / model
    return RunPaths.at(run).cache


def evaluate_speech(paths: RunPaths, cfg) -> dict:
    """The run's mapping model(s) and its voice-robust models (stage ``voices``, each with the
    corpus it was trained on) on the real-speech set (stage ``speech_eval``); the comparisons
    are made against the run's default model (the voices stage's pick, else the mapping); the
    recordings are those ``speech_set.per_speaker`` picks."""
    models = run_models(paths)
    for name, (tfmap, corpus, units) in voices_models(paths).items():
        models[f"voices-{name}"] = (tfmap, units, corpus)
    chosen = (read_done(paths.stage("voices")) or {}).get("model")
    default = f"voices-{chosen}" if chosen else f"{cfg.mapping.method}_utterance"
    res = evaluate_models(models, paths.stage("speech_eval") / "results.csv",
                          default_model=default, targets=cfg.targets,
                          per_speaker=cfg.speech_set.per_speaker,
                          cache=ArrayCache(paths.cache), workers=0,
                          recognisers=run_recognisers(paths, cfg))
    # after the scores, whose hearing uses every core: each candidate streamed alone
    timed = {n: m for n, m in models.items() if n.startswith("voices-") or n == default}
    latency = measure_models(timed, out_json=paths.stage("speech_eval") / LATENCY_FILE)
    return {"latency": {m: v["latency_p99_ms"] for m, v in latency["models"].items()},
            "summary": res["summary"], "seen_speakers": res["seen_speakers"],
            "speech_set": {**res["speech_set"], "recordings": len(res["recordings"])},
            "training_speakers": res["training_speakers"], "models": res["models"],
            "recogniser_passes": res["recogniser_passes"]}
