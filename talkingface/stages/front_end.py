"""The ``front_end`` stage: our own causal phone front end, taught by hama (issue 40).

The default voices model reads hama (:mod:`mapping.hama_front`), a whole-utterance model: a
stream decodes the last second every third frame, which costs a frame's budget twice over on
one frame in three. This stage trains a small causal network (:mod:`mapping.causal_front`) to
give hama's phones frame by frame with a bounded look-ahead, by distillation
(:mod:`mapping.front_training`): on every utterance of its corpora hama hears the whole
utterance once (the *teacher pass*, content-keyed in the run's cache, on every core:
:func:`mapping.hearing.hear_all`), and the network learns, per 10-ms step and per look-ahead,
the class mass of the spike hama's timing rule reads there — and the corpus's own phone labels
(weighed by ``front_end.train.label_weight``). Augmented copies (``front_end.copies``,
:func:`mapping.augment.augment` with the mapping's augmentation settings) reuse the clean
audio's targets, re-timed when the tempo changes.

Its corpora (``front_end.corpora``):

* ``run``: the run's own training corpus (one voice);
* ``voices``: a many-voice corpus of the run's sentences and seed spoken by ``front_end.voices``
  (built here once; the voices stage reuses it for children that ask for the same voices);
* ``real``: the real speaker's training sentences (``real_speaker.corpus``, the utterance split
  of the run seed) *without* the recordings of the real-speech evaluation set. It makes the
  real speaker a *seen* speaker of every model that reads this front end, so it is off by
  default: GRID s1 is most of the set's independently labelled test recordings.

The stage runs when the voices grid has a child that reads the causal front end
(:func:`front_end_applies`); elsewhere the shipped front end (``mapping/models/``) serves.
The speakers of those corpora (:func:`analysis.speech_eval.training_speakers`) are written into
the model file, so every score of a model that reads it counts them as seen.

Files (``runs/<name>/front_end/``)::

    causal_front.npz   the trained front end (kind ``phone_front``; mapping.causal_front)
    corpora/voices/    the many-voice corpus; corpora/real/ the real speaker's part
    done.json          seconds of the teacher pass and of training, utterances and minutes of
                       audio per corpus, the teacher pass's recordings heard / reused, the
                       training's held-out figures
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from analysis.speech_eval import training_speakers
from analysis.speech_set import SET_DIR, read_manifest
from face_model.corpus import Corpus, load_corpus
from face_model.phones import PHONE_INDEX
from groundwork.audio import resample
from groundwork.cache import ArrayCache
from groundwork.errors import ParameterError, TalkingFaceError
from mapping import front_net
from mapping.augment import augment, retime_labels
from mapping.front_training import FrontExample, Teacher, train_front
from mapping.hearing import hear_all
from mapping.recogniser import hearing_cache, heard_entry
from talkingface.paths import RunPaths
from talkingface.stages.applies import synthesised
from talkingface.stages.grid import VOICES, grid_corpus
from talkingface.stages.motion import training_corpus
from talkingface.stages.real_speaker import real_corpus, real_inputs, training_part

FRONT_FILE = "causal_front.npz"
FRONT_SEED_OFFSET = 43  # the front end of run seed s trains with seed s + 43
STEP_S = 0.01  # the front end's step (s): teacher targets and labels per 10 ms
# torch threads while training: fixed, not the machine's cores, so the weights are the same on
# any machine (the sums a thread pool splits differ in their last bits with its size)
TRAIN_THREADS = 2


def front_end_applies(cfg) -> bool:
    """On for a synthesised run whose voices grid has a child that reads the causal front end
    without a model file of its own (``mapping.recogniser: causal``, ``mapping.front_model``
    empty): that child reads the run's. Elsewhere the shipped front end serves (the run's
    mapping trains before this stage, so a run whose own mapping reads the causal front end
    reads the shipped one, and speech_eval scores the shipped one)."""
    if not synthesised(cfg) or not VOICES.has_grid(cfg):
        return False
    try:
        children = VOICES.children(cfg)
    except TalkingFaceError:  # a bad grid is refused by the voices stage, naming its setting
        return False
    return any(c.mapping.gate_front_end == "recogniser" and c.mapping.recogniser == "causal"
               and not c.mapping.front_model for c in children.values())


def front_file(paths: RunPaths) -> Path:
    """The run's trained front end (it may not exist yet)."""
    return paths.stage("front_end") / FRONT_FILE


def voices_synth(cfg):
    """The synth settings of the front end's many-voice corpus: the run's, with
    ``front_end.voices``."""
    return dataclasses.replace(cfg.synth, voices=tuple(cfg.front_end.voices))


def set_recordings(speaker: str) -> set:
    """The file stems of the real-speech evaluation set's recordings of ``speaker``: never
    trained on."""
    return {Path(r["wav"]).stem for r in read_manifest(SET_DIR) if r["speaker"] == speaker}


def real_part(cfg) -> Corpus:
    """The real speaker's training sentences of the run seed, without the recordings of the
    real-speech evaluation set."""
    corpus = load_corpus(real_corpus(cfg))
    part = training_part(corpus, cfg.seed, cfg.mapping.train_fraction)
    keep = [u for u in part.utterances if u.utt_id not in set_recordings(u.speaker)]
    return Corpus(part.root, part.info, keep)


def front_corpora(paths: RunPaths, cfg) -> dict:
    """``{name: (Corpus, folder whose speakers it adds)}`` of ``front_end.corpora``."""
    out = paths.stage("front_end") / "corpora"
    found = {}
    for name in cfg.front_end.corpora:
        if name == "run":
            folder = training_corpus(paths, cfg)
            found[name] = (load_corpus(folder), folder)
        elif name == "voices":
            folder = grid_corpus(out / "voices", voices_synth(cfg), cfg.seed)
            found[name] = (load_corpus(folder), folder)
        else:
            part = real_part(cfg)
            found[name] = (part, Path(part.root))
    return found


def front_inputs(paths, cfg) -> dict:
    """With the ``real`` corpus, the real speaker's corpus (its manifest's hash) and the
    evaluation set's manifest (the recordings left out) join the stage's key."""
    if "real" not in cfg.front_end.corpora:
        return {}
    if real_corpus(cfg) is None:
        raise ParameterError("front_end.corpora lists 'real' but real_speaker.corpus names no "
                             "corpus; allowed: run, voices, and real with a real speaker")
    rows = sorted(f"{r['speaker']}/{Path(r['wav']).stem}" for r in read_manifest(SET_DIR))
    return {"real_corpus": real_inputs(paths, cfg)["real_corpus"], "set_recordings": rows}


def front_model_inputs(paths, cfg) -> dict:
    """``mapping.front_model`` (a causal front end's model file): read and checked before any
    stage runs, its checksummed name joining the key of the stages that read it."""
    model = cfg.mapping.front_model
    if not model:
        return {}
    if not Path(model).is_file():
        raise ParameterError(f"mapping.front_model {model}: not found (a causal front end's "
                             "model file, e.g. runs/<name>/front_end/causal_front.npz; empty: "
                             "the run's or the shipped one)")
    return {"front_model": front_net.front_name(model)}


def _labels(u, n_steps: int) -> np.ndarray:
    """The utterance's phone class per 10-ms step (instant s · 10 ms), silence outside its
    segments."""
    t = np.arange(n_steps) * STEP_S
    out = np.full(n_steps, PHONE_INDEX["sil"], dtype=np.int64)
    for seg in u.phones:
        out[(t >= seg.start_s) & (t < seg.end_s)] = PHONE_INDEX[seg.phone]
    return out


def _examples(corpora: dict, cache, cfg) -> tuple[list, dict]:
    """The training examples (clean, then ``front_end.copies`` augmented copies of each) and
    the teacher pass's record."""
    clean = []  # (utterance, 16 kHz audio)
    for corpus, _ in corpora.values():
        for u in corpus.utterances:
            clean.append((u, resample(u.audio, sr_in=u.sample_rate,
                                      sr_out=front_net.RATE)))
    jobs = [Teacher(y16) for _, y16 in clean]
    t0 = time.perf_counter()
    passes = hear_all(jobs, cache, workers=cfg.front_end.workers,
                      desc="hama teaching the front end")
    teacher_s = time.perf_counter() - t0
    settings = dataclasses.replace(cfg.mapping.augment, copies=cfg.front_end.copies)
    examples = []
    with hearing_cache(cache):
        for i, ((u, y16), job) in enumerate(zip(clean, jobs)):
            targets = heard_entry(job.key(), job.compute, job.names)["targets"]
            labels = _labels(u, len(targets))
            examples.append(FrontExample(y16, np.asarray(targets, np.float32), labels))
            for c in range(settings.copies):
                rng = np.random.default_rng([cfg.seed + FRONT_SEED_OFFSET, i, c])
                y, scale, _ = augment(y16, sr=front_net.RATE, settings=settings,
                                      rng=rng)
                n = front_net.n_steps(len(y))  # a tempo change re-times both
                examples.append(FrontExample(
                    y, retime_labels(np.asarray(targets, np.float32), scale, n),
                    retime_labels(labels, scale, n)))
    return examples, {"teacher": passes.as_dict(), "teacher_seconds": round(teacher_s, 1)}


def train_front_end(paths: RunPaths, cfg) -> dict:
    """Train the run's causal front end (stage ``front_end``; see the module docstring)."""
    out = paths.stage("front_end")
    out.mkdir(parents=True, exist_ok=True)
    corpora = front_corpora(paths, cfg)
    speakers = sorted(set().union(*(training_speakers(f) if name != "real" else
                                    {u.speaker for u in c.utterances}
                                    for name, (c, f) in corpora.items())))
    examples, record = _examples(corpora, ArrayCache(paths.cache), cfg)
    t0 = time.perf_counter()
    arrays, metadata = train_front(examples, cfg.front_end.train,
                                   seed=cfg.seed + FRONT_SEED_OFFSET, threads=TRAIN_THREADS,
                                   info={"training_speakers": speakers,
                                         "corpora": list(cfg.front_end.corpora),
                                         "run_seed": cfg.seed})
    train_s = time.perf_counter() - t0
    front_net.write_front(out / FRONT_FILE, arrays, metadata)
    minutes = {name: round(sum(len(u.audio) / u.sample_rate for u in c.utterances) / 60, 2)
               for name, (c, _) in corpora.items()}
    return {"model": FRONT_FILE, "training_speakers": speakers,
            "utterances": {name: len(c.utterances) for name, (c, _) in corpora.items()},
            "minutes_of_audio": minutes, "examples": len(examples), **record,
            "train_seconds": round(train_s, 1),
            "training": {k: metadata[k] for k in ("utterances", "train_minutes", "best_epoch",
                                                  "history")}}
