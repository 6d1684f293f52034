"""Where the real speaker's Table II R goes (issue 39): the ``real_steps`` stage.

The ``real_speaker`` stage runs the paper's pipeline on a real speaker; its R is far below the
paper's. This stage measures, on the real speaker's **training** sentences only (the pipeline's
utterance split: :func:`mapping.dataset.training_sentences` with the run seed +
:data:`mapping.experiment.SPLIT_SEED_OFFSET` and ``mapping.train_fraction``, as the nested run
draws it), the steps that need no trained mapping (:mod:`analysis.real_ceiling`). The Motion
Units are fitted on those sentences with the run's ``units`` settings; the features are the
pipeline's (:func:`mapping.dataset.build_dataset`: ``mapping.n_mfcc``, ``mapping.mel_fmax_hz``).

Probe. A ridge regression fitted on every other training sentence and scored by Eq. 6 on the
rest, then the other way round (mean R; :func:`analysis.real_ceiling.offset_scores`): one fixed,
fast, deterministic model, so that the rows differ only in what they change.

Rows (``steps.json``):

* ``reconstruction_r`` — the aligned markers against their Motion Units' reconstruction;
* ``smoothing_floor`` — the truth against its 3- and 5-frame moving average (landmark jitter);
* ``offset`` — R for audio–video lags of -6..6 frames and the best lag;
* ``context`` — R for 0, 3, 6, 10 and 15 frames of MFCC context either side;
* ``oracle`` — the true phones (one-hot; 3, 6, 10 frames) instead of the audio, and
  ``oracle_and_audio`` — both (6 frames);
* ``learning_curve`` — R of the probe (±3 frames) fitted on 25, 50, 100 sentences of one half
  (cut to the half's size; nested, seeded with the run seed) and scored on the other half;
* ``units`` — per utterance Motion Unit: its share of the variance, where it moves (lips,
  cheeks, forehead, sideways) and the R the audio reaches on it alone (6 frames).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from analysis.real_ceiling import (best_offset, learning_curve, offset_scores, phone_onehot,
                                   reconstruction_r, region_loadings, smoothing_floor)
from face_model.alignment import corpus_deformations
from face_model.corpus import Corpus, load_corpus
from face_model.layout import REGIONS
from face_model.motion_units import MotionUnits
from face_model.phones import N_PHONES
from groundwork.atomic import atomic_file
from mapping.dataset import build_dataset, training_sentences
from mapping.experiment import SPLIT_SEED_OFFSET
from talkingface.paths import RunPaths
from talkingface.stages.real_speaker import real_corpus

LAGS = range(-6, 7)
CONTEXTS = (0, 3, 6, 10, 15)
ORACLE_CONTEXTS = (3, 6, 10)
PER_UNIT_CONTEXT = 6
LEARNING_SIZES = (25, 50, 100, 0)  # sentences the probe is fitted on (0: a whole half)
FACE_REGIONS = ("lips", "cheeks", "forehead")


def training_part(corpus: Corpus, seed: int, train_fraction: float) -> Corpus:
    """The corpus's utterances whose sentence is a training sentence of the utterance split of
    run seed ``seed``."""
    train = training_sentences([u.text for u in corpus.utterances],
                               train_fraction=train_fraction, seed=seed + SPLIT_SEED_OFFSET)
    return Corpus(corpus.root, corpus.info, [u for u in corpus.utterances if u.text in train])


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
    scale = np.where(np.abs(m_all).max(0) > 0, np.abs(m_all).max(0), 1.0)
    out = {"corpus": str(corpus_dir), "training_sentences": len(data),
           "frames": int(sum(len(f) for f in feats)),
           "reconstruction_r": reconstruction_r(m_all, np.concatenate(recon)),
           "smoothing_floor": {w: smoothing_floor([m / scale for m in markers], w)
                               for w in (3, 5)}}
    lags = offset_scores(feats, mups, LAGS)
    out["offset"] = {"r": lags, "best": best_offset(lags)}
    out["context"] = {k: offset_scores(feats, mups, [0], context=k)[0] for k in CONTEXTS}
    onehot = [phone_onehot(d.phones, N_PHONES) for d in data]
    out["oracle"] = {k: offset_scores(onehot, mups, [0], context=k)[0] for k in ORACLE_CONTEXTS}
    out["oracle_and_audio"] = offset_scores([np.hstack(p) for p in zip(onehot, feats)], mups,
                                            [0], context=PER_UNIT_CONTEXT)[0]
    out["learning_curve"] = learning_curve(feats, mups, LEARNING_SIZES, seed=cfg.seed)
    n = units.n_utterance
    share = units.variance_[:n] / units.variance_[:n].sum()
    where = region_loadings(units.components_[:n], {k: REGIONS[k] for k in FACE_REGIONS})
    out["units"] = [{"unit": j, "variance_share": float(share[j]), **where[j],
                     "r_audio": offset_scores(feats, [m[:, j:j + 1] for m in mups], [0],
                                              context=PER_UNIT_CONTEXT)[0]}
                    for j in range(n)]
    return out


def measure_real_steps(paths: RunPaths, cfg) -> dict:
    """The stage: :func:`measure_steps` on ``real_speaker.corpus``, written to
    ``real_steps/steps.json``; its done.json keeps the headline rows."""
    steps = measure_steps(real_corpus(cfg), cfg)
    out = paths.stage("real_steps")
    with atomic_file(out / "steps.json") as tmp:
        tmp.write_text(json.dumps(steps, indent=1, default=float) + "\n")
    return {"training_sentences": steps["training_sentences"],
            "reconstruction_r": steps["reconstruction_r"],
            "best_lag": steps["offset"]["best"],
            "context_3": steps["context"][3], "oracle_6": steps["oracle"][6]}
