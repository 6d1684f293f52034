"""The articulation fitted on the real speaker's mouth, and how well it draws the held-out lips
(stage ``articulation``).

The fit (:func:`fit_real_articulation`, run by ``tools/fit_articulation.py``, which writes the
shipped ``data_synth/articulation_models/grid-s1.npz``) reads the real speaker's corpus
(``real_speaker.corpus``), keeps its **training sentences only** (the utterance split of the run
seed, :func:`talkingface.stages.real_speaker.training_part`), aligns their markers by the
glasses markers, takes the rest face from their valid silence frames, brings every valid frame
into the articulatory space and fits the coarticulation model on the forced-aligned phones
(:mod:`data_synth.articulation_fit`). Nothing of a held-out sentence is read.

The stage scores, on the held-out sentences, how well each model draws the real lips from the
true phones (:func:`analysis.articulation_eval.articulation_table`): the articulatory space
itself (step 1's projection: the ceiling), the hand table, the shipped fitted model and the
run's own ``synth.articulation`` when it is another file. It writes ``articulation.csv`` and
``summary.json`` for the report.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from analysis.articulation_eval import HeldOutClip, articulation_table
from data_synth.articulation import (SHIPPED_DIR, Articulation, articulation_file, articulation_model,
                                     articulation_path, file_sha256)
from data_synth.articulation_fit import FaceMap, Sentence, fit_coarticulation, rest_face, \
    to_articulation
from face_model.alignment import align_markers
from face_model.corpus import corpus_hash, load_corpus
from face_model.phones import PHONE_INDEX
from groundwork.errors import ParameterError
from talkingface.paths import RunPaths
from talkingface.stages.base import write_csv
from talkingface.stages.real_speaker import real_corpus, training_part
from talkingface.stages.training import utterance_test_ids

SHIPPED = "grid-s1"  # the shipped model fitted on the built-in real speaker
COMMAND = "python tools/fit_articulation.py"


def _valid(u) -> np.ndarray:
    """Frames whose face was detected (not interpolated); all for a corpus without quality."""
    return np.ones(u.n_frames, bool) if u.quality is None else np.asarray(u.quality)[:, 1] == 0


_SIL = PHONE_INDEX["sil"]


def speaker_face(train_utts: list, synth_cfg) -> tuple[FaceMap, list]:
    """The articulation map around the speaker's rest face (the median of the training
    sentences' valid silence frames, aligned) and the aligned markers of each utterance."""
    aligned = [align_markers(u.markers) for u in train_utts]
    rest = rest_face(aligned, [_valid(u) & (u.phone_per_frame() == _SIL) for u in train_utts])
    return FaceMap.around(rest, synth_cfg), aligned


def fit_real_articulation(cfg, corpus_dir: Path | None = None, *, steps: int = 300
                          ) -> tuple[Articulation, dict]:
    """The coarticulation model fitted on the real speaker's training sentences, and its
    provenance record (the data, the settings, the fit's figures); ``steps``: the L-BFGS
    iterations of :func:`data_synth.articulation_fit.fit_coarticulation`.

    Raises
    ------
    ParameterError
        No real speaker configured (``real_speaker.corpus`` empty) and no ``corpus_dir``.
    """
    root = corpus_dir or real_corpus(cfg)
    if root is None:
        raise ParameterError("real_speaker.corpus is empty: the articulation is fitted on the "
                             "real speaker's training sentences; set real_speaker.corpus")
    corpus = load_corpus(root)
    train = training_part(corpus, cfg.seed, cfg.mapping.train_fraction).utterances
    face, aligned = speaker_face(train, cfg.synth)
    artic, rms = to_articulation(face, np.concatenate(aligned))
    sentences, k = [], 0
    for u, a in zip(train, aligned):
        n = len(a)
        sentences.append(Sentence(tuple(u.phones), np.arange(n) / u.fps, artic[k:k + n],
                                  _valid(u).astype(float)))
        k += n
    prior = Articulation.table(cfg.synth.theta_anticipation, cfg.synth.theta_carryover,
                               cfg.synth.dominance_power)
    model, fit = fit_coarticulation(sentences, prior, steps=steps)
    valid = np.concatenate([_valid(u) for u in train])
    record = {
        "source": f"{corpus.info.get('source', str(root))} (speaker "
                  f"{', '.join(sorted({u.speaker for u in train}))}): the training sentences "
                  "of the utterance split",
        "command": COMMAND,
        "corpus": Path(root).name, "corpus_hash": corpus_hash(root),
        "licence": corpus.info.get("licence", ""),
        "seed": cfg.seed, "train_fraction": cfg.mapping.train_fraction,
        "training_utterances": sorted(u.utt_id for u in train),
        "face_map": {k: getattr(cfg.synth, k) for k in ("jaw_px", "aperture_px", "spread_px",
                                                      "protrusion_px", "upper_raise_px",
                                                      "lower_tuck_px")},
        "prior": {"theta_anticipation": prior.theta_anticipation,
                  "theta_carryover": prior.theta_carryover, "power": prior.power},
        "projection_rms_px": float(np.sqrt(np.mean(rms[valid] ** 2))),
        "rest_face": np.round(face.rest, 4).tolist(),
        **{k: fit[k] for k in ("frames", "loss_start", "loss_end", "iterations",
                               "phone_frames")},
    }
    return model, record


def shipped_path() -> Path:
    return articulation_path(SHIPPED)


def held_out_clips(corpus, cfg) -> list[HeldOutClip]:
    """The held-out sentences of the utterance split, aligned."""
    test = set(utterance_test_ids(corpus, cfg))
    return [HeldOutClip(u.utt_id, u.speaker, align_markers(u.markers), tuple(u.phones), u.fps,
                        _valid(u)) for u in corpus.utterances if u.utt_id in test]


def models_to_compare(cfg) -> dict:
    """The hand table, the shipped fitted model, and the run's own file if it is another."""
    models = {"hand table": Articulation.table(cfg.synth.theta_anticipation,
                                               cfg.synth.theta_carryover,
                                               cfg.synth.dominance_power)}
    if shipped_path().is_file():
        models[f"fitted ({SHIPPED})"] = articulation_model(
            dataclasses.replace(cfg.synth, articulation=SHIPPED))
    own = articulation_file(cfg.synth)
    if own is not None and own.resolve() != shipped_path().resolve():
        models[f"fitted ({own.name})"] = articulation_model(cfg.synth)
    return models


def evaluate_articulation(paths: RunPaths, cfg) -> dict:
    """The stage: the models' held-out figures (module docstring)."""
    root = real_corpus(cfg)
    corpus = load_corpus(root)
    train = training_part(corpus, cfg.seed, cfg.mapping.train_fraction).utterances
    face, _ = speaker_face(train, cfg.synth)
    clips = held_out_clips(corpus, cfg)
    projection = [to_articulation(face, c.aligned)[0] for c in clips]
    rows = articulation_table(clips, face, models_to_compare(cfg), projection=projection)
    out = paths.stage("articulation")
    write_csv(out / "articulation.csv", rows)
    shipped = shipped_path()
    record = articulation_model(dataclasses.replace(cfg.synth, articulation=SHIPPED)).record \
        if shipped.is_file() else {}
    summary = {
        "speaker": sorted({c.speaker for c in clips}), "held_out_clips": len(clips),
        "training_clips": len(train), "rows": rows,
        "synth_articulation": cfg.synth.articulation,
        "shipped": {"file": str(shipped.name), "sha256": file_sha256(shipped)
                    if shipped.is_file() else None,
                    **{k: record.get(k) for k in ("theta_anticipation", "theta_carryover",
                                                  "power", "command", "source",
                                                  "projection_rms_px", "loss_start",
                                                  "loss_end")}},
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    return {"rows": len(rows), "held_out_clips": len(clips)}


def articulation_applies(cfg) -> bool:
    """On when the run has a real speaker (``real_speaker.corpus``)."""
    return real_corpus(cfg) is not None


def articulation_files(paths, cfg) -> list:
    """The model file the run's own ``synth.articulation`` reads (none for ``table``): a stage
    that draws faces depends on its content."""
    own = articulation_file(cfg.synth)
    return [] if own is None else [own]


def every_articulation_file(paths, cfg) -> list:
    """Every shipped articulation model and the run's own file: a grid's children may name
    any of them, and this stage compares them."""
    files = sorted(SHIPPED_DIR.glob("*.npz"))
    return files + [f for f in articulation_files(paths, cfg) if f not in files]
