"""The corpus, the Motion Units and the keyframes (paper §IV, §VII-A): three stages.

``corpus/``: the synthetic corpus (:mod:`data_synth`), or a given one (``corpus.source``:
:mod:`talkingface.stages.given_corpus`). ``units/``: the Motion Units fitted on it and their
variance table (no expression MUs for an expression the corpus does not hold: a ``note`` says
so). ``keyframes/``: the Eq. 3–4 keyframe model, its MUP → keyframe → MUP round trip per
expression (``roundtrip.csv``) and the keyframe shapes drawn on the face (on a corpus without
smile or sad, no model: ``skipped`` in its record says why).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from analysis.corpus_report import summarize_units
from data_synth.generate import synthesize_corpus
from face_model.alignment import corpus_deformations, speaker_neutrals, unflatten
from face_model.corpus import Corpus, corpus_hash, load_corpus
from face_model.keyframes import EXPRESSION_KEYFRAMES, KEYFRAMES, KeyframeModel
from face_model.layout import default_layout
from face_model.motion_units import MotionUnits, fit_corpus_units
from face_model.render import FaceRenderer, face_grid
from groundwork.atomic import atomic_file
from groundwork.errors import ParameterError
from talkingface.paths import RunPaths
from talkingface.stages.applies import expression_note, given
from talkingface.stages.base import write_csv
from talkingface.stages.given_corpus import take_given_corpus
from talkingface.stages.training import utterance_test_ids

def make_corpus(paths: RunPaths, cfg) -> dict:
    """The run's corpus: the given one (``corpus.source``) validated and linked in, or the
    synthetic one."""
    if given(cfg):
        return take_given_corpus(paths, cfg)
    synthesize_corpus(paths.corpus, cfg.synth, cfg.seed, overwrite=True, progress=True)
    return {"corpus_hash": corpus_hash(paths.corpus)}


def sentence_file(paths: RunPaths, cfg) -> list:
    """The user's sentence file, when the corpus synthesises one that reads it (its contents
    join the key; a given corpus's files join it as its inputs:
    :func:`talkingface.stages.given_corpus.corpus_inputs`)."""
    if given(cfg) or not cfg.synth.text_file:
        return []
    if not Path(cfg.synth.text_file).is_file():
        raise ParameterError(f"synth.text_file {cfg.synth.text_file} not found")
    return [Path(cfg.synth.text_file)]


def fit_units_folder(corpus_dir: Path, out_dir: Path, cfg, *, held_out=()) -> dict:
    """Fit the Motion Units on a corpus folder; write ``motion_units.npz`` and
    ``variance.csv`` into ``out_dir``. Used by the stage and by ``talkingface units``.

    ``held_out``: utterance ids left out of the fit — the units *and* the speakers' neutral
    faces (:func:`face_model.alignment.speaker_neutrals`) come from the other utterances only;
    the ids and the neutral faces used are kept in the units' metadata (``held_out_utterances``,
    ``neutrals``: speaker → (79, 2) list, aligned pixels). Expression MUs are fitted for the
    expressions the corpus holds (none for a corpus of neutral speech only); the result's
    ``expressions`` lists them, and its ``note``
    (:func:`talkingface.stages.applies.expression_note`) says what is skipped without smile or
    sad."""
    corpus = load_corpus(corpus_dir)
    held = set(held_out)
    unknown = held - {u.utt_id for u in corpus.utterances}
    if unknown:
        raise ParameterError(f"held-out utterances {sorted(unknown)[:3]} are not in the corpus "
                             f"at {corpus_dir}")
    fitted = Corpus(corpus.root, corpus.info,
                    [u for u in corpus.utterances if u.utt_id not in held])
    if not fitted.utterances:
        raise ParameterError(f"{corpus_dir}: every utterance is held out; none left to fit")
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    # the fit's deformations are taken from these same neutral faces (speaker_neutrals of the
    # utterances fitted: face_model.motion_units.fit_corpus_units)
    neutrals = speaker_neutrals(fitted, model=cfg.units.alignment)
    meta = {"corpus_hash": corpus_hash(corpus_dir)}
    if held:
        meta.update({"held_out_utterances": sorted(held),
                     "neutrals": {k: v.tolist() for k, v in neutrals.items()}})
    units, _ = fit_corpus_units(fitted, n_utterance=cfg.units.n_utterance,
                                n_expression=cfg.units.n_expression,
                                alignment=cfg.units.alignment, metadata=meta)
    seconds = time.perf_counter() - t0
    with atomic_file(out_dir / "motion_units.npz") as tmp:
        units.save(tmp)
    summary = summarize_units(units)
    with atomic_file(out_dir / "variance.csv") as tmp, open(tmp, "w") as f:
        f.write("motion_units,number,explained,paper\n")
        for k, v in summary["explained"].items():
            n = units.n_utterance if k == "neutral" else units.n_expression
            f.write(f"{k},{n},{v:.6f},{summary['paper'][k]}\n")
    record = {"fit_seconds": seconds, "summary": summary,
              "expressions": list(units.expressions_), "held_out": len(held),
              "fitted_utterances": len(fitted.utterances)}
    note = expression_note(u.expression for u in corpus.utterances)
    if note:
        record["note"] = note
    return record


def units_held_out(corpus_dir: Path, cfg) -> list:
    """The utterances the run's Motion Units must not see: on a given corpus (real data,
    ``corpus.source`` set) the held-out sentences of the mapping's ``utterance`` split
    (:func:`talkingface.stages.training.utterance_test_ids`, the same the mapping stage holds
    out), so no score on them comes from units or a neutral face fitted on them. On the
    synthetic corpus none: its units are fitted on the whole corpus, as the paper's Table I
    (MU variance over the whole corpus) is, and its tables compare with that."""
    if not given(cfg):
        return []
    return utterance_test_ids(load_corpus(corpus_dir), cfg)


def units_inputs(paths: RunPaths, cfg) -> dict:
    """What the units stage's key needs beyond its ``units`` section: on a given corpus, the
    split that decides its held-out sentences (the seed and ``mapping.train_fraction``)."""
    if not given(cfg):
        return {}
    return {"units_split": {"seed": cfg.seed, "train_fraction": cfg.mapping.train_fraction}}


def fit_units(paths: RunPaths, cfg) -> dict:
    """The Motion Units of the run's corpus (on a given corpus, its training sentences only:
    :func:`units_held_out`)."""
    return fit_units_folder(paths.corpus, paths.units, cfg,
                            held_out=units_held_out(paths.corpus, cfg))


def fit_keyframes(paths: RunPaths, cfg) -> dict:
    """The keyframe model of the run's corpus and Motion Units, with its round trip; on a
    corpus without smile or sad (the paper's eight keyframes need both), no model: the record's
    ``skipped`` says why."""
    corpus = load_corpus(paths.corpus)
    units = MotionUnits.load(paths.units_model)
    missing = [k for k in EXPRESSION_KEYFRAMES if k not in units.expressions_]
    if missing:
        return {"skipped": f"The keyframes (Eqs. 3–4) are skipped: the paper's eight keyframes "
                           f"include smile and sad, and the corpus holds no "
                           f"{' or '.join(missing)} speech.",
                "note": expression_note(u.expression for u in corpus.utterances)}
    defs = corpus_deformations(corpus, model=units.metadata_.get("alignment", "similarity"))
    model = KeyframeModel().fit(corpus, units, deformations=defs)
    out_dir = paths.keyframes
    model.save(paths.keyframes_model)
    rows = []
    for expr in dict.fromkeys(u.expression for u in corpus.utterances):
        mups = np.concatenate([units.transform(defs[u.utt_id], expr)
                               for u in corpus.utterances if u.expression == expr])
        e = model.round_trip_error(mups, expr)
        rows.append({"expression": expr, "frames": e.n_frames, "mup_relative": e.mup_relative,
                     "pixel_rmse": e.pixel_rmse, "pixel_max": e.pixel_max,
                     "shape_relative": e.shape_relative})
    write_csv(out_dir / "roundtrip.csv", rows)
    neutral = default_layout().neutral
    renderer = FaceRenderer(mesh=False)
    images = [renderer.render(neutral + unflatten(s[None])[0]) for s in model.shapes_]
    face_grid(images, list(KEYFRAMES), out_dir / "keyframes.png", ncols=4)
    return {"roundtrip": rows, "condition": float(model.condition_),
            "samples": {k: len(v) for k, v in model.selection_.items()}}
