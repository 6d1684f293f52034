"""The ``mapping`` stage (paper §VI, §VII-A) and the training function the grid stages share.

``mapping/`` — every method (the paper's gated MLP and the baselines) trained on both splits by
:mod:`mapping.experiment` and measured by :mod:`analysis.evaluation`:

    tables.csv        every method × split × expression × train/test: R, ν, ν', MSE, paper values
    ranking_<split>.csv   methods ranked by mean test R
    gate.json         gate accuracy per split, the small-class merges
    confusion_<split>.csv/.png  the gate's confusion on neutral test frames (true class per row)
    <method>_<split>.tfmap the primary method trained on each split (AudioMapping file)
    trajectories.png  predicted vs true MUPs of test sentences

Each task of a grid stage (``ablations``, ``ceiling``, ``voices``: :mod:`talkingface.stages.grid`)
trains with the same function, :func:`train_and_evaluate`, on its own child's settings.
"""
from __future__ import annotations

import csv
import json
import time
from contextlib import nullcontext
from functools import partial
from pathlib import Path

from analysis.evaluation import evaluate_experiment, ranking, table_rows
from analysis.figures import confusion_matrix, mup_trajectories
from face_model.corpus import corpus_hash, load_corpus
from face_model.motion_units import MotionUnits
from groundwork.cache import ArrayCache
from mapping.checkpoint import AudioMapping, rest_mups
from mapping.dataset import build_dataset, held_out_utterances
from mapping.experiment import SPLIT_SEED_OFFSET, recognise_context, run_experiment
from mapping.hearing import corpus_jobs, hear_all
from mapping.recogniser import hearing_cache
from talkingface.config import to_dict
from talkingface.executor import map_tasks
from talkingface.paths import RunPaths
from talkingface.stages.applies import expression_note
from talkingface.stages.base import write_csv
from talkingface.stages.motion import training_corpus


def _write_gate(out_dir: Path, r, figure: bool = True) -> dict:
    """The gate's confusion (CSV, and the heat map with ``figure``) of one trained method; its
    accuracy figures."""
    gate = dict(r.trained.gate)
    conf = gate.pop("confusion")
    with open(out_dir / f"confusion_{r.split}.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["true\\gated", *gate["class_names"]])
        for name, row in zip(gate["class_names"], conf):
            w.writerow([name, *row.tolist()])
    if figure:
        confusion_matrix(conf, gate["class_names"], out_dir / f"confusion_{r.split}.png",
                         title=f"Gate confusion, neutral test frames ({r.split} split)")
    return gate


def train_and_evaluate(corpus_dir: Path, units_path: Path, out_dir: Path, cfg, *,
                       methods=None, splits=None, progress: bool = True, cache=None,
                       figures: bool = True, map_fn=None) -> dict:
    """Train and evaluate ``methods`` (default: the primary method and every baseline) on
    ``splits``; write the files listed in the module docstring into ``out_dir`` and return the
    summary the report and MLflow read. ``cache``: the folder of the content-keyed cache
    (:mod:`groundwork.cache`) that keeps the corpus's features and recognised phones for
    every task and run; ``figures``: draw the gate's confusion and the trajectories (a grid's
    tasks write the tables and the confusion's CSV only: the figures would cost them a third
    of their time, and the report draws the mapping stage's); ``map_fn``: where the methods ×
    splits train (:func:`mapping.experiment.run_experiment`). The expression cascade is trained
    for the expressions the corpus holds (none on neutral speech only: the summary's ``note``
    says so)."""
    m = cfg.mapping
    corpus = load_corpus(corpus_dir)
    units = MotionUnits.load(units_path)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    store = None if cache is None else ArrayCache(cache)
    # the recogniser's phones of the corpus and of the augmented copies: one cache entry each
    with hearing_cache(store) if store is not None else nullcontext():
        data = build_dataset(corpus, units, n_mfcc=m.n_mfcc, deltas=m.deltas,
                             recognise_context=recognise_context(m),
                             window_align=m.window_align, mel_fmax_hz=m.mel_fmax_hz,
                             progress=progress, cache=store)
        feature_seconds = time.perf_counter() - t0
        trained = run_experiment(data, m, n_utterance=units.n_utterance, seed=cfg.seed,
                                 methods=methods, splits=splits, progress=progress,
                                 map_fn=map_fn)
    results = evaluate_experiment(trained, data, units)
    rows = table_rows(results)
    write_csv(out_dir / "tables.csv", rows)
    splits_run = list(dict.fromkeys(r.split for r in results))
    ranks = {s: ranking(results, s) for s in splits_run}
    for s, rk in ranks.items():
        write_csv(out_dir / f"ranking_{s}.csv", rk)
    gate, models = {}, {}
    meta = {"corpus_hash": corpus_hash(corpus_dir), "seed": cfg.seed, "config": to_dict(cfg)}
    first = corpus.utterances[0]
    for r in results:
        if r.trained.gate is not None:
            gate[f"{r.method}/{r.split}"] = _write_gate(out_dir, r, figures)
        if r.method == m.method:
            path = out_dir / f"{r.method}_{r.split}.tfmap"
            AudioMapping(r.trained.mapper, sample_rate=first.sample_rate, fps=first.fps,
                         n_mfcc=m.n_mfcc, deltas=m.deltas, n_utterance=units.n_utterance,
                         rest_mups=rest_mups(units), metadata={**meta, "split": r.split},
                         window_align=m.window_align, mel_fmax_hz=m.mel_fmax_hz).save(path)
            models[r.split] = str(path.name)
    (out_dir / "gate.json").write_text(json.dumps(gate, indent=1))
    traj = (mup_trajectories(_trajectory_items(data, results, m.method, units.n_utterance),
                             out_dir / "trajectories.png") if figures else None)
    held = next((r for r in results if r.split == "utterance"), None)
    test_utts = ([d.utt_id for d, mk in zip(data, held.trained.masks) if not mk.any()]
                 if held is not None else [])
    record = {"rows": rows, "ranking": ranks, "gate": gate, "models": models,
              "expressions": list(dict.fromkeys(u.expression for u in corpus.utterances)),
              "test_utterances": test_utts,
              "feature_seconds": feature_seconds,
              "trajectories": traj.name if traj else None,
              "fit_seconds": {f"{r.method}/{r.split}": r.fit_seconds for r in results},
              "fits": network_costs(f for r in results for f in r.trained.fits),
              "config": to_dict(cfg)}
    note = expression_note(record["expressions"])
    if note:  # no expression cascade for an expression the corpus does not hold
        record["note"] = note
    return record


def utterance_test_ids(corpus, cfg) -> list:
    """The ids of the ``utterance`` split's test utterances of ``corpus`` (a loaded corpus)
    under ``cfg``: the split :func:`mapping.experiment.run_experiment` draws (seed
    ``cfg.seed + SPLIT_SEED_OFFSET``, ``mapping.train_fraction``), known before anything is
    fitted — the units stage leaves them out on a given corpus
    (:func:`talkingface.stages.foundation.units_held_out`)."""
    return held_out_utterances(corpus.utterances, train_fraction=cfg.mapping.train_fraction,
                               seed=cfg.seed + SPLIT_SEED_OFFSET)


def network_costs(fits) -> dict:
    """Per network type, the trainings' ``members``, ``epochs``, ``seconds`` and ``flops``
    summed (records of :func:`mapping.nets.record_fits`; ``bench/bench_profile.py --run``
    sets them against the arithmetic floor)."""
    out: dict = {}
    for f in fits:
        n = out.setdefault(f["network"], {"trainings": 0, "members": 0, "epochs": 0,
                                          "seconds": 0.0, "flops": 0.0})
        n["trainings"] += 1
        for k in ("members", "epochs", "seconds", "flops"):
            n[k] += f[k]
    return out


def _trajectory_items(data, results, primary: str, n_utterance: int) -> list[dict]:
    """For one test sentence per expression (utterance split if run): the true MUPs and the
    estimates of the primary method and of the best-ranked baseline."""
    split = "utterance" if any(r.split == "utterance" for r in results) else results[0].split
    by = {r.method: r for r in results if r.split == split}
    others = [x["method"] for x in ranking(results, split) if x["method"] != primary]
    shown = [primary] + others[:1]
    masks = (by[primary] if primary in by else next(iter(by.values()))).trained.masks
    items = []
    for expr in dict.fromkeys(d.expression for d in data):
        idx = [i for i, d in enumerate(data) if d.expression == expr and not masks[i].any()]
        if not idx:  # random_frames: every sentence has training frames; take the first
            idx = [i for i, d in enumerate(data) if d.expression == expr]
        i = idx[0]
        items.append({"title": f"{data[i].utt_id} ({expr}, {split} split)",
                      "truth": data[i].mups, "n_utterance": n_utterance,
                      "estimates": {meth: by[meth].trained.predictions[i] for meth in shown
                                    if meth in by}})
    return items


def train(paths: RunPaths, cfg) -> dict:
    """The mapping and the baselines trained and evaluated on the run's training corpus."""
    map_fn = partial(map_tasks, scheduler=cfg.cluster.scheduler, workers=cfg.mapping.workers,
                     desc="training")
    corpus_dir = training_corpus(paths, cfg)
    context = recognise_context(cfg.mapping)
    passes = None
    if context is not None:  # the recogniser front end: the corpus heard on every core first
        passes = hear_all(corpus_jobs(load_corpus(corpus_dir), context), ArrayCache(paths.cache),
                          workers=cfg.mapping.workers, desc="hearing the corpus")
    record = train_and_evaluate(corpus_dir, paths.units_model, paths.mapping, cfg,
                                cache=paths.cache, map_fn=map_fn)
    if passes is not None:
        record["recogniser_passes"] = passes.as_dict()
    return record
