"""The voice-robust models (issue 12): the ``voices`` stage.

Its grid (``voices.grid``, by default ``configs/voices.yaml``) has the form of the ablation grid
(:func:`talkingface.stages.grid_files.load_grid`) plus ``model``, the child that ``animate``,
``stream`` and the study's synthetic face use by default. Every child trains the paper's mapping
(its ``mapping.method``) on the run's Motion Units:

* a child that leaves ``synth`` as the run has it trains on the run's corpus (one voice);
* a child that changes ``synth`` (``synth.voices``: many voices; ``synth.articulation``: the
  mouth moved by another coarticulation model) trains on a corpus of its own, made with the
  run's seed — the same faces and sentences, the speech drawn from its voices —
  under ``voices/corpora/<k>/``, built once for every child that asks for the same settings
  (hard links to the ``front_end`` stage's many-voice corpus when its settings are the same);
* a child whose recogniser is the causal front end (``mapping.recogniser: causal``) without a
  ``mapping.front_model`` reads the run's own (the ``front_end`` stage's model file), and its
  model keeps a copy of it;
* a child with ``voices.real_face: alone`` trains on the real speaker's training sentences
  (``real_speaker.corpus``, the utterance split of the run seed: its held-out sentences are
  never read) instead, ``added`` on those beside its drawn faces' corpus; each such corpus gets
  Motion Units fitted on it, which the model keeps beside its file (``<child>/
  motion_units.npz``). A grid's real-face children are left out of a run without a real
  speaker.

Files (``runs/<name>/voices/``)::

    <child>/               the child's tables.csv, gate.json, <method>_<split>.tfmap, summary.json
                           (and motion_units.npz when they are not the run's)
    corpora/<k>/           the many-voice corpora
    corpora/real/, corpora/<k>-real/, corpora/*-units/
                           the real speaker's training sentences alone or beside corpus <k>,
                           and their Motion Units
    results.csv            per child: its corpus, settings, test R on its own corpus, and the
                           in-domain test R on the run's single-voice corpus (utterance split)

The in-domain R puts every child on the paper's Table II footing: its predictions for the test
sentences of the run's own corpus (the same sentences every child held out, since the split is
drawn by sentence with the run's seed), measured as :mod:`analysis.evaluation` measures Table II
with the child's own Motion Units, on the expressions those have (a real face: neutral speech).

The stage is described by :data:`talkingface.stages.grid.VOICES` (its grid is read by
:func:`talkingface.stages.grid_files.load_voices_grid`; its children's MLflow tags are
``voices.setting``, ``voices.seed``, …).
"""
from __future__ import annotations

import csv
import dataclasses
import os
import shutil
from pathlib import Path

import numpy as np

from analysis.evaluation import database_scale, evaluate_predictions
from face_model.corpus import Corpus, load_corpus
from face_model.motion_units import MotionUnits
from groundwork.cache import ArrayCache
from groundwork.errors import ParameterError
from mapping.checkpoint import AudioMapping
from mapping.dataset import build_dataset, training_sentences
from mapping.experiment import SPLIT_SEED_OFFSET, predict_utterance, recognise_context
from mapping.hearing import corpus_jobs, hear_all
from talkingface.paths import RunPaths
from talkingface.stages.base import read_done, write_csv
from talkingface.stages.child_runs import log_for
from talkingface.stages.foundation import fit_units_folder
from talkingface.stages.front_end import front_file, voices_synth
from talkingface.stages.given_corpus import combine_corpora, link_or_copy
from talkingface.stages.grid import VOICES, grid_corpus, run_children
from talkingface.stages.grid_files import load_voices_grid
from talkingface.stages.motion import training_corpus
from talkingface.stages.real_speaker import copy_training_part, real_corpus, real_inputs


def _synthetic_corpus(child, cfg, paths: RunPaths, out: Path, built: list) -> Path:
    """The drawn faces' corpus of a child: the run's own, or one of other voices or another
    articulation built under ``out`` once for every child that asks for the same synth settings
    (``built``)."""
    if dataclasses.replace(child.synth, workers=cfg.synth.workers) == cfg.synth:
        return training_corpus(paths, cfg)
    folder = next((f for s, f in built if s == child.synth), None)
    if folder is None:
        folder = out / f"{len(built)}"
        front = paths.stage("front_end") / "corpora" / "voices"
        if (child.synth == voices_synth(cfg) and (front / "manifest.csv").is_file()
                and not (folder / "manifest.csv").is_file()):
            link_tree(front, folder)  # the front end's many-voice corpus: the same settings
        grid_corpus(folder, child.synth, cfg.seed)
        built.append((child.synth, folder))
    return folder


def link_tree(src: Path, dst: Path) -> Path:
    """A copy of the folder ``src`` at ``dst`` made of hard links (copies where a link cannot be
    made), swapped into place whole."""
    tmp = dst.with_name(dst.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(src, tmp, copy_function=lambda a, b: link_or_copy(Path(a), Path(b)))
    os.replace(tmp, dst)
    return dst


def with_front(child, paths: RunPaths):
    """A child whose recogniser is the causal front end with no model file of its own reads
    the run's (the ``front_end`` stage's), when the run has one."""
    m = child.mapping
    front = front_file(paths)
    if m.recogniser != "causal" or m.front_model or not front.is_file():
        return child
    return dataclasses.replace(child, mapping=dataclasses.replace(
        m, front_model=str(front.resolve())))


def _corpora(children: dict, cfg, paths: RunPaths, out: Path) -> dict:
    """Child → (corpus folder, motion_units.npz): the drawn faces' corpus with the run's Motion
    Units; or, for a child that trains on the real speaker (``voices.real_face``), the real
    speaker's training sentences alone (``out/real``) or beside its drawn faces' corpus
    (``out/<k>-real``: ``synthetic/`` and ``real/``), with Motion Units fitted on that corpus
    (``<corpus>-units/``), each built once."""
    built: list = []  # [(synth settings, folder)]
    where = {}
    for name, child in children.items():
        synthetic = _synthetic_corpus(child, cfg, paths, out, built)
        mode = child.voices.real_face
        if mode == "none":
            where[name] = (synthetic, paths.units_model)
            continue
        real = copy_training_part(real_corpus(cfg), out / "real", cfg)
        if mode == "added":
            real = combine_corpora([(synthetic, None, "synthetic"), (real, None, "real")],
                                   out / f"{synthetic.name}-real")
        units = real.with_name(f"{real.name}-units")
        if not (units / "motion_units.npz").is_file():
            fit_units_folder(real, units, cfg)
        where[name] = (real, units / "motion_units.npz")
    return where


def hear_corpora(children: dict, corpora: dict, own_corpus, cache, *, workers: int = 0):
    """Every distinct (corpus, recogniser context) the children's recogniser front ends and
    :func:`in_domain_R` (the run's corpus ``own_corpus``) hear, heard into ``cache`` on
    ``workers`` processes (0: all cores) before the children start, so that no child hears a
    corpus on one core while the others wait (:func:`mapping.hearing.hear_all`; the augmented
    copies a child draws are heard by the child). Returns the
    :class:`~mapping.hearing.Passes`."""
    loaded = {Path(own_corpus.root).resolve(): own_corpus}
    needs = {}  # (corpus folder, context), in the children's order
    for name, child in children.items():
        context = recognise_context(child.mapping)
        if context is not None:
            needs[(Path(own_corpus.root).resolve(), context)] = True
            needs[(Path(corpora[name][0]).resolve(), context)] = True
    jobs = []
    for folder, context in needs:
        if folder not in loaded:
            loaded[folder] = load_corpus(folder)
        jobs += corpus_jobs(loaded[folder], context)
    return hear_all(jobs, cache, workers=workers, desc="hearing the voices' corpora")


def in_domain_R(tfmap: Path, data: list, masks: list, scale, units) -> dict:
    """Test R (Eq. 6) per expression and their mean of the model ``tfmap`` on the run's own
    corpus (``data``, its utterance-split ``masks``), as Table II measures it."""
    mapping = AudioMapping.load(tfmap)
    preds = [predict_utterance(mapping.mapper, d) for d in data]
    tables = evaluate_predictions(data, masks, preds, units, scale)
    r = {e: float(t["test"].R) for e, t in tables.items() if "test" in t}
    return {**{f"in_domain_R_{e}": v for e, v in r.items()},
            "in_domain_R": float(np.mean(list(r.values())))}


def train_voices(paths: RunPaths, cfg) -> dict:
    """Every child of the voices grid, trained (``voices.workers`` processes, 0: all cores)
    and measured (stage ``voices``)."""
    children, model = load_voices_grid(VOICES.grid_path(cfg), cfg)
    children = {name: with_front(child, paths) for name, child in children.items()}
    out = paths.stage(VOICES.name)
    out.mkdir(parents=True, exist_ok=True)
    corpora = _corpora(children, cfg, paths, out / "corpora")
    own_corpus = load_corpus(training_corpus(paths, cfg))
    passes = hear_corpora(children, corpora, own_corpus, ArrayCache(paths.cache),
                          workers=cfg.voices.workers)
    summaries = run_children({name: (*corpora[name], child)
                              for name, child in children.items()}, out,
                             scheduler=cfg.cluster.scheduler, workers=cfg.voices.workers,
                             desc="voice-robust models", cache=paths.cache,
                             log=log_for(VOICES.name), stage=VOICES.tag)
    own: dict = {}  # (units, n_mfcc, ...) -> (data, masks, scale) of the run's corpus
    rows, models = [], {}
    for name, child in children.items():
        m = child.mapping
        corpus, units_path = corpora[name]
        units = MotionUnits.load(units_path)
        tfmap = out / name / f"{m.method}_utterance.tfmap"
        if not tfmap.is_file():
            raise ParameterError(f"{VOICES.what} child {name!r} trained no utterance-split "
                                 "model; keep 'utterance' in its mapping.splits")
        if units_path != paths.units_model:  # the model's own units beside it (model_units)
            link_or_copy(units_path, tfmap.parent / "motion_units.npz")
        key = (str(units_path), m.n_mfcc, m.deltas, recognise_context(m), m.window_align,
               m.mel_fmax_hz)
        if key not in own:  # the expressions the model's units have (a real face: neutral)
            held = {"neutral", *units.expressions_}
            corpus_part = Corpus(own_corpus.root, own_corpus.info,
                                 [u for u in own_corpus.utterances if u.expression in held])
            data = build_dataset(corpus_part, units, n_mfcc=m.n_mfcc, deltas=m.deltas,
                                 recognise_context=key[3], window_align=m.window_align,
                                 mel_fmax_hz=m.mel_fmax_hz, progress=True,
                                 cache=ArrayCache(paths.cache))
            # the run's split, drawn over all its sentences, whatever part is scored
            train = training_sentences([u.text for u in own_corpus.utterances],
                                       train_fraction=cfg.mapping.train_fraction,
                                       seed=cfg.seed + SPLIT_SEED_OFFSET)
            own[key] = (data, [np.full(d.n_frames, d.text in train) for d in data],
                        database_scale(data, units))
        models[name] = {"tfmap": str(tfmap.relative_to(out)),
                        "corpus": "" if corpus == training_corpus(paths, cfg)
                        else str(corpus.relative_to(out)),
                        "units": "" if units_path == paths.units_model
                        else str(Path(units_path).relative_to(out))}
        summary = summaries[name]["summary"]
        own_R = next(x["R"] for x in summary["ranking"]["utterance"] if x["method"] == m.method)
        rows.append({"model": name, "default": name == model,
                     "corpus": models[name]["corpus"] or "the run's",
                     "real_face": child.voices.real_face,
                     "articulation": ("" if child.voices.real_face == "alone"
                                      else child.synth.articulation),
                     "voices": ("" if child.voices.real_face == "alone" else
                                " ".join(child.synth.voices) or "(the run's voice)"),
                     "cmvn": m.cmvn, "vtlp_range": "-".join(map(str, m.vtlp_range)),
                     "augment_copies": m.augment.copies, "own_corpus_test_R": own_R,
                     **in_domain_R(tfmap, *own[key], units),
                     "seconds": round(summaries[name]["seconds"], 1)})
    write_csv(out / "results.csv", rows)
    return {"grid": str(VOICES.grid_path(cfg)), "model": model, "models": models, "rows": rows,
            "recogniser_passes": passes.as_dict()}


def voices_models(paths: RunPaths) -> dict:
    """The trained voice-robust models of a run: child name → (tfmap, the corpus it was
    trained on: its own corpus, or the run's, its Motion Units: its own, or the run's); empty
    when the run has none."""
    done = read_done(paths.stage("voices"))
    if not done:
        return {}
    out = paths.stage("voices")
    return {name: (out / m["tfmap"], out / m["corpus"] if m["corpus"] else paths.corpus,
                   out / m["units"] if m.get("units") else paths.units_model)
            for name, m in done.get("models", {}).items()}


def voices_inputs(paths, cfg) -> dict:
    """The real speaker's corpus (:func:`talkingface.stages.real_speaker.real_inputs`) joins
    the stage's key when a child of its grid trains on it (``voices.real_face``)."""
    if not VOICES.has_grid(cfg) or all(c.voices.real_face == "none"
                                       for c in VOICES.children(cfg).values()):
        return {}
    return {"real_corpus": real_inputs(paths, cfg)["real_corpus"]}


def read_results(paths: RunPaths) -> list[dict]:
    """``voices/results.csv`` as rows (empty when the run has none)."""
    f = paths.stage("voices") / "results.csv"
    if not f.is_file():
        return []
    with open(f, newline="", encoding="utf-8-sig") as fh:
        return list(csv.DictReader(fh))
