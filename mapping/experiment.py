"""Training the mapping methods of an experiment (paper §VI, §VII-A): every method × split.

:func:`make_mapper` is the one place where a ``mapping`` config section becomes the estimators'
explicit hyper-parameters. :func:`run_experiment` trains every method on every split and returns
the fitted mappers with their predictions of every utterance; the paper's metrics and tables are
computed from these by :mod:`analysis.evaluation`.

The estimators get ``mapping.cmvn`` and ``mapping.cmvn_warmup_frames`` (their features'
normalisation, saved with them); ``mapping.vtlp_range`` and ``mapping.augment`` add augmented
copies of each split's training utterances to what the methods are fitted on
(:func:`~mapping.dataset.training_copies`, drawn once per split and shared by every method).
Predictions and the gate's accuracy are always of the original utterances.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

from tqdm import tqdm

from groundwork.errors import ParameterError
from mapping.baselines import BASELINES, Baseline
from mapping.config import MappingConfig
from mapping.dataset import split_masks, training_copies
from mapping.gated_mlp import GatedMLP
from mapping.nets import record_fits
from mapping.phone_gate import gate_accuracy

METHODS = ("gated_mlp", *BASELINES)
# Seconds a training of each method takes per split (bench/bench_profile.py's fit seconds on
# the paper-size corpus, plus ~3 s around the fit); only the order trainings start in depends
# on it (the dearest first, so that no long one starts last while other workers idle).
METHOD_COST = {"mlp_large": 37, "gmm_regression": 23, "gru": 22, "tdnn": 14, "gated_mlp": 7,
               "vq": 5, "linear": 3}
SPLIT_SEED_OFFSET = 17  # the split of a run seed is drawn with seed + 17, the same for every method
AUGMENT_SEED_OFFSET = 31  # the training copies of a run seed are drawn with seed + 31


def make_mapper(method: str, mcfg: MappingConfig, *, n_utterance: int = 7,
                random_state: int = 0):
    """A fresh, untrained mapping method by name (one of :data:`METHODS`)."""
    if method == "gated_mlp":
        return GatedMLP(n_utterance=n_utterance, context_back=mcfg.context_back,
                        context_forward=mcfg.context_forward, n_classes=mcfg.n_classes,
                        gate_components=mcfg.gate_components,
                        gate_covariance=mcfg.gate_covariance,
                        min_class_frames=mcfg.min_class_frames, hidden_min=mcfg.hidden_min,
                        hidden_max=mcfg.hidden_max, expression_model=mcfg.expression_model,
                        cascade_hidden=mcfg.cascade_hidden, cmvn=mcfg.cmvn,
                        cmvn_warmup_frames=mcfg.cmvn_warmup_frames,
                        gate_front_end=mcfg.gate_front_end, mlp_input=mcfg.mlp_input,
                        phone_training=mcfg.phone_training,
                        recogniser=recogniser_spec(mcfg), train=mcfg.train,
                        random_state=random_state)
    if method in BASELINES:
        return Baseline(method, context_back=mcfg.context_back,
                        context_forward=mcfg.context_forward, cmvn=mcfg.cmvn,
                        cmvn_warmup_frames=mcfg.cmvn_warmup_frames, train=mcfg.train,
                        random_state=random_state)
    raise ParameterError(f"unknown mapping method {method!r}; allowed: {', '.join(METHODS)}")


@dataclass
class TrainedMethod:
    """One method trained on one split: the fitted mapper and its estimate of every utterance."""

    method: str
    split: str
    fit_seconds: float
    reference: str
    mapper: object = field(repr=False, default=None)
    predictions: list = field(repr=False, default_factory=list)  # (n_frames, A0 + Ak) each
    masks: list = field(repr=False, default_factory=list)  # training frames of each utterance
    gate: dict | None = None  # gate accuracy and confusion (gated methods)
    fits: list = field(repr=False, default_factory=list)  # mapping.nets.record_fits' records


def augmented_copies(data: list, masks: list, mcfg: MappingConfig, *, seed: int
                     ) -> tuple[list, list]:
    """The training copies of a split (none unless ``mcfg`` asks for the warp or augmentation)."""
    return training_copies(data, masks, settings=mcfg.augment, vtlp_range=mcfg.vtlp_range,
                           n_mfcc=mcfg.n_mfcc, deltas=mcfg.deltas,
                           seed=seed + AUGMENT_SEED_OFFSET, window_align=mcfg.window_align,
                           recognise_context=(recognise_context(mcfg)
                                              if mcfg.mlp_input == "phones"
                                              and mcfg.phone_training == "recognised" else None))


def train_method(method: str, data: list, masks: list, mcfg: MappingConfig, *,
                 n_utterance: int, split: str, seed: int, copies=None) -> TrainedMethod:
    """Train one method on a split's training frames (and the augmented ``copies``:
    ``(data, masks)`` of :func:`augmented_copies`, drawn here when not given) and estimate
    every original utterance."""
    mapper = make_mapper(method, mcfg, n_utterance=n_utterance, random_state=seed)
    extra, extra_masks = copies if copies is not None else augmented_copies(data, masks, mcfg,
                                                                            seed=seed)
    t0 = time.perf_counter()
    with record_fits() as fits:
        mapper.fit([*data, *extra], [*masks, *extra_masks])
    seconds = time.perf_counter() - t0
    preds = [predict_utterance(mapper, d) for d in data]
    gate = gate_accuracy(mapper, data, masks) if hasattr(mapper, "gate_") else None
    return TrainedMethod(method, split, seconds, mapper.reference, mapper, preds, masks, gate,
                         fits)


def recognise_context(mcfg: MappingConfig) -> tuple | None:
    """The window ``(back, forward, recogniser)`` of recognised phones the data must carry: the
    mapping's context with the recogniser gate (decided with its look-ahead by the recogniser of
    ``mapping.recogniser``), else None (no recognition)."""
    if mcfg.gate_front_end != "recogniser":
        return None
    return (mcfg.context_back, mcfg.context_forward, recogniser_spec(mcfg))


def recogniser_spec(mcfg: MappingConfig) -> str:
    """The recogniser of ``mapping.recogniser`` as :mod:`mapping.recogniser` names it: with
    ``"causal"`` and a ``front_model``, ``"causal:<front_model>"`` (that model file)."""
    if mcfg.recogniser == "causal" and mcfg.front_model:
        return f"causal:{mcfg.front_model}"
    return mcfg.recogniser


def predict_utterance(mapper, d):
    """A trained method's MUPs of one :class:`~mapping.dataset.UttData` (with its recognised
    phones when the method's gate is the recogniser)."""
    if getattr(mapper, "needs_phones", False):
        return mapper.predict(d.features, d.expression, phones=mapper.utterance_phones(d))
    return mapper.predict(d.features, d.expression)


def experiment_methods(mcfg: MappingConfig) -> list[str]:
    """The primary method, then every baseline that is not the primary one."""
    return [mcfg.method, *[b for b in mcfg.baselines if b != mcfg.method]]


def run_experiment(data: list, mcfg: MappingConfig, *, n_utterance: int, seed: int,
                   methods=None, splits=None, progress: bool = False,
                   map_fn=None) -> list[TrainedMethod]:
    """Every method × split (default: :func:`experiment_methods` × ``mcfg.splits``); the split
    of a given seed is the same for every method.

    ``map_fn(fn, {key: args}) -> {key: fn(*args)}`` runs the trainings (each method × split is
    one call of :func:`train_method`; e.g. on a process pool); by default one after the other
    here. Each training is seeded alone, so where it runs does not change its result. The
    utterances are sent without their audio (the augmented copies are drawn here first)."""
    methods = list(methods or experiment_methods(mcfg))
    splits = list(splits or mcfg.splits)
    masks = {s: split_masks(data, s, train_fraction=mcfg.train_fraction,
                            seed=seed + SPLIT_SEED_OFFSET) for s in splits}
    copies = {s: augmented_copies(data, masks[s], mcfg, seed=seed) for s in splits}
    if map_fn is None:
        jobs = [(s, m) for s in splits for m in methods]
        return [train_method(method, data, masks[split], mcfg, n_utterance=n_utterance,
                             split=split, seed=seed, copies=copies[split])
                for split, method in tqdm(jobs, desc="training", unit="model",
                                          disable=not progress)]
    light = [replace(d, audio=None) for d in data]
    tasks = {(s, m): (m, light, masks[s], mcfg, n_utterance, s, seed, copies[s])
             for s in splits for m in methods}
    first = sorted(tasks, key=lambda key: -METHOD_COST.get(key[1], 7))
    done = map_fn(_train_task, {key: tasks[key] for key in first})
    return [done[key] for key in tasks]


def _train_task(method, data, masks, mcfg, n_utterance, split, seed, copies) -> TrainedMethod:
    """:func:`train_method` with positional arguments (a task of :func:`run_experiment`)."""
    return train_method(method, data, masks, mcfg, n_utterance=n_utterance, split=split,
                        seed=seed, copies=copies)
