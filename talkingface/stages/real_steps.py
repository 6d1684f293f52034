"""Where the real speaker's Table II R goes (issue 39): the ``real_steps`` stage.

The ``real_speaker`` stage runs the paper's pipeline on a real speaker; its R is far below the
paper's. This stage measures, on the real speaker's **training** sentences only (the pipeline's
utterance split: :func:`mapping.dataset.training_sentences` with the run seed +
:data:`mapping.experiment.SPLIT_SEED_OFFSET` and ``mapping.train_fraction``, as the nested run
draws it), the steps that need no trained mapping (:mod:`analysis.real_ceiling`). The Motion
Units are fitted on those sentences with the run's ``units`` settings; the features are the
pipeline's (:func:`mapping.dataset.build_dataset`: ``mapping.n_mfcc``, ``mapping.mel_fmax_hz``).

Probe. A ridge regression from the features to the MUPs fitted on every other training sentence
and scored by Eq. 6 on the rest, then the other way round (mean R;
:func:`analysis.real_ceiling.offset_scores`): one fixed, fast, deterministic model, so that the
rows differ only in what they change. Its R is the pipeline's Table II R: on the displacements
the MUPs reconstruct (Eq. 2), each coordinate divided by its largest absolute displacement over
the training sentences.

Rows (``steps.json``):

* ``reconstruction_r`` — the aligned markers against their Motion Units' reconstruction;
* ``smoothing_floor`` — the truth (as Eq. 6 sees it) against its 3- and 5-frame moving
  average (landmark jitter);
* ``definition`` — the probe (±3 frames) scored by Eq. 6 as the paper (``paper``), against the
  aligned markers instead of their reconstruction (``markers``), and in pixels without the
  division by the largest displacement (``pixels``): what the definition alone moves;
* ``offset`` — R for audio–video lags of -6..6 frames and the best lag;
* ``context`` — R for 0, 3, 6, 10 and 15 frames of MFCC context either side;
* ``oracle`` — the true phones (one-hot; 3, 6, 10 frames) instead of the audio, and
  ``oracle_and_audio`` — both (6 frames);
* ``learning_curve`` — R of the probe (±3 frames) fitted on 25, 50, 100 sentences of one half
  (cut to the half's size; nested, seeded with the run seed) and scored on the other half;
* ``learning_projection`` — the curve's rise per doubling of the sentences and the R it
  projects for twice the largest size (:func:`analysis.real_ceiling.curve_projection`);
* ``regions`` — per region of the face (lips, cheeks, forehead, the glasses the alignment
  holds still): its share of what Eq. 6 weighs (the normalised truth's variance on its
  coordinates) and the probe's R (±3 frames) on its coordinates alone;
* ``units`` — per utterance Motion Unit: its share of the variance, where it moves (lips,
  cheeks, forehead, sideways) and the Pearson r the audio reaches on its MUP alone (6 frames).

Trained steps. The pipeline itself, one change at a time: each child of the grid
``real_steps.grid`` (by default ``configs/real_steps.yaml``: the run's mapping with the paper's
gate, the gate's phones from pocketsphinx or hama, the MLPs reading hama's phones, the oracle
that reads the true phones) is trained with ``real_steps.seeds`` seeds on a copy of the training
sentences (``corpora/train``, hard links) with Motion Units fitted on that copy's own training
sentences (``corpora/units``: the inner utterance split of the run seed), and scored on each
seed's own split of those sentences (:func:`talkingface.stages.grid.run_grid`): the random-frame
split beside the utterance split. ``results.csv`` has each step's mean R, its 95 % interval over
seeds and the paired test against ``ours``; ``replicates.csv`` each seed's figures.
The held-out sentences of the run are never read here.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from analysis.metrics import normalization_scale
from analysis.real_ceiling import (best_offset, curve_projection, learning_curve, offset_scores,
                                   phone_onehot, reconstruction_r, region_loadings,
                                   smoothing_floor)
from face_model.alignment import corpus_deformations
from face_model.corpus import load_corpus
from face_model.layout import REGIONS
from face_model.motion_units import MotionUnits
from face_model.phones import N_PHONES
from groundwork.atomic import atomic_file
from groundwork.cache import ArrayCache
from mapping.dataset import build_dataset
from mapping.experiment import recognise_context
from mapping.hearing import corpus_jobs, hear_all
from talkingface.paths import RunPaths
from talkingface.stages.child_runs import log_for
from talkingface.stages.foundation import fit_units_folder
from talkingface.stages.grid import REAL_STEPS, grid_rows, run_grid
from talkingface.stages.real_speaker import copy_training_part, real_corpus, training_part
from talkingface.stages.training import utterance_test_ids

LAGS = range(-6, 7)
CONTEXTS = (0, 3, 6, 10, 15)
ORACLE_CONTEXTS = (3, 6, 10)
PER_UNIT_CONTEXT = 6
LEARNING_SIZES = (25, 50, 100, 0)  # sentences the probe is fitted on (0: a whole half)
FACE_REGIONS = ("lips", "cheeks", "forehead")
EQ6_REGIONS = ("lips", "cheeks", "forehead", "glasses")  # every marker, in four regions


def measure_steps(corpus_dir: Path, cfg) -> dict:
    """Every row of the module text for the corpus ``corpus_dir`` under the run config
    ``cfg`` (seed, ``units``, ``mapping.train_fraction``, ``n_mfcc``, ``mel_fmax_hz``)."""
    part = training_part(load_corpus(corpus_dir), cfg.seed, cfg.mapping.train_fraction)
    defs = corpus_deformations(part, model=cfg.units.alignment)
    units = MotionUnits(cfg.units.n_utterance, cfg.units.n_expression).fit(
        {"neutral": np.concatenate([defs[u.utt_id] for u in part.utterances])},
        metadata={"alignment": cfg.units.alignment})
    data = build_dataset(part, units, n_mfcc=cfg.mapping.n_mfcc,
                         mel_fmax_hz=cfg.mapping.mel_fmax_hz)
    feats, mups = [d.features for d in data], [d.mups for d in data]
    markers = [defs[d.utt_id] for d in data]
    recon = [units.inverse_transform(m) for m in mups]
    m_all = np.concatenate(markers)
    # the paper's truth: the MUs' reconstruction, each coordinate divided by its largest
    # absolute displacement over the sentences (analysis.evaluation.database_scale)
    scale = normalization_scale(np.concatenate(recon))

    def paper(m: np.ndarray) -> np.ndarray:  # MUPs → the displacements Eq. 6 compares
        return units.inverse_transform(m) / scale

    out = {"corpus": str(corpus_dir), "training_sentences": len(data),
           "frames": int(sum(len(f) for f in feats)),
           "reconstruction_r": reconstruction_r(m_all, np.concatenate(recon)),
           "smoothing_floor": {w: smoothing_floor([r / scale for r in recon], w)
                               for w in (3, 5)}}
    # what the definition alone moves: the same probe scored against the aligned markers
    # (each coordinate divided by their largest displacement) and in pixels, undivided
    m_scale = normalization_scale(m_all)
    out["definition"] = {
        "paper": offset_scores(feats, mups, [0], project=paper)[0],
        "markers": offset_scores(feats, mups, [0], truths=[m / m_scale for m in markers],
                                 project=lambda m: units.inverse_transform(m) / m_scale)[0],
        "pixels": offset_scores(feats, mups, [0], project=units.inverse_transform)[0]}
    lags = offset_scores(feats, mups, LAGS, project=paper)
    out["offset"] = {"r": lags, "best": best_offset(lags)}
    out["context"] = {k: offset_scores(feats, mups, [0], context=k, project=paper)[0]
                      for k in CONTEXTS}
    onehot = [phone_onehot(d.phones, N_PHONES) for d in data]
    out["oracle"] = {k: offset_scores(onehot, mups, [0], context=k, project=paper)[0]
                     for k in ORACLE_CONTEXTS}
    out["oracle_and_audio"] = offset_scores([np.hstack(p) for p in zip(onehot, feats)], mups,
                                            [0], context=PER_UNIT_CONTEXT, project=paper)[0]
    out["learning_curve"] = learning_curve(feats, mups, LEARNING_SIZES, seed=cfg.seed,
                                           project=paper)
    if len(out["learning_curve"]) > 1:  # what twice the probe's data would give
        out["learning_projection"] = curve_projection(out["learning_curve"],
                                                      2 * max(out["learning_curve"]))
    truth = np.concatenate([r / scale for r in recon])
    weight = truth.var(0)  # what each coordinate weighs in Eq. 6's trace form
    out["regions"] = {}
    for name in EQ6_REGIONS:
        cols = np.array([2 * m + k for m in REGIONS[name] for k in (0, 1)])
        out["regions"][name] = {
            "weight": float(weight[cols].sum() / weight.sum()),
            "r": offset_scores(feats, mups, [0], project=lambda m, c=cols: paper(m)[:, c])[0]}
    n = units.n_utterance
    share = units.variance_[:n] / units.variance_[:n].sum()
    where = region_loadings(units.components_[:n], {k: REGIONS[k] for k in FACE_REGIONS})
    out["units"] = [{"unit": j, "variance_share": float(share[j]), **where[j],
                     "r_audio": offset_scores(feats, [m[:, j:j + 1] for m in mups], [0],
                                              context=PER_UNIT_CONTEXT)[0]}
                    for j in range(n)]
    return out


def train_steps(corpus_dir: Path, out: Path, cfg, cache=None) -> list[dict]:
    """The trained steps of the module text: every child of ``real_steps.grid`` on the
    training sentences of ``corpus_dir``, ``real_steps.seeds`` seeds each; writes
    ``replicates.csv`` and ``results.csv`` into ``out`` and returns the results' rows.
    With ``cache`` (the content-keyed cache's folder), the recognisers the children use hear
    the sentences first, on ``real_steps.workers`` processes (``passes.json``: how many were
    heard and how many read from the cache), so that no child hears them on one core while
    the others wait."""
    part = copy_training_part(corpus_dir, out / "corpora" / "train", cfg)
    units_dir = out / "corpora" / "units"
    if not (units_dir / "motion_units.npz").is_file():
        fit_units_folder(part, units_dir, cfg,
                         held_out=utterance_test_ids(load_corpus(part), cfg))
    children = REAL_STEPS.children(cfg)
    units_path = units_dir / "motion_units.npz"
    passes = None
    if cache is not None:  # every recogniser hears the sentences once, on every core
        loaded = load_corpus(part)
        contexts = dict.fromkeys(c for c in (recognise_context(ch.mapping)
                                             for ch in children.values()) if c is not None)
        passes = hear_all([j for c in contexts for j in corpus_jobs(loaded, c)],
                          ArrayCache(cache), workers=cfg.real_steps.workers,
                          desc="hearing the training sentences")
    results = run_grid({n: (part, units_path, c) for n, c in children.items()}, out,
                       seeds=REAL_STEPS.seeds(cfg), scheduler=cfg.cluster.scheduler,
                       workers=cfg.real_steps.workers, desc="real-speaker steps",
                       log=log_for(REAL_STEPS.name), stage=REAL_STEPS.tag, cache=cache)

    def describe(name, child) -> dict:
        m = child.mapping
        return {"method": m.method, "gate_front_end": m.gate_front_end,
                "recogniser": m.recogniser if m.gate_front_end == "recogniser" else "",
                "mlp_input": m.mlp_input}

    rows = grid_rows(results, children, REAL_STEPS, out, describe)
    if passes is not None:
        (out / "passes.json").write_text(json.dumps(passes.as_dict()) + "\n")
    return rows


def measure_real_steps(paths: RunPaths, cfg) -> dict:
    """The stage: :func:`measure_steps` on ``real_speaker.corpus``, written to
    ``real_steps/steps.json``, and :func:`train_steps` beside it; its done.json keeps the
    headline rows."""
    src = real_corpus(cfg)
    steps = measure_steps(src, cfg)
    out = paths.stage(REAL_STEPS.name)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_file(out / "steps.json") as tmp:
        tmp.write_text(json.dumps(steps, indent=1, default=float) + "\n")
    rows = train_steps(src, out, cfg, cache=paths.cache)
    return {"training_sentences": steps["training_sentences"],
            "reconstruction_r": steps["reconstruction_r"],
            "best_lag": steps["offset"]["best"],
            "context_3": steps["context"][3], "oracle_6": steps["oracle"][6],
            "grid": str(REAL_STEPS.grid_path(cfg)), "children": [r["step"] for r in rows],
            **{f"{r['step']}.utterance_R": r.get("utterance_R") for r in rows}}
