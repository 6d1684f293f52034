"""The mapping's evaluation exactly as §VII-A, over methods and splits (Tables I and II).

For every utterance, the true MUPs (the tracked MUP sequence) and the estimated MUPs are both
turned back into marker displacements with the Motion Units (Eq. 2). Each displacement value is
divided by the maximum absolute ground-truth displacement of that marker coordinate over the whole
database (every expression), then R (Eq. 6), ν (Eq. 7) and MSE (Eq. 8) are computed per expression
on the training frames (Table I) and on the test frames (Table II) of a split.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from analysis.metrics import METRIC_NAMES, PAPER_TABLES, normalization_scale, paper_metrics
from face_model.errors import ParameterError
from mapping import make_mapper
from mapping.dataset import split_masks
from mapping.gate import confusion

PARTS = ("train", "test")


def displacements(units, mups: np.ndarray, expression: str) -> np.ndarray:
    """(n_frames, 158) displacements reconstructed from MUPs by Eq. 2."""
    return units.inverse_transform(mups, expression)


def database_scale(data: list, units) -> np.ndarray:
    """Per marker coordinate, the maximum absolute true displacement in the database (158,)."""
    return normalization_scale(np.concatenate([displacements(units, d.mups, d.expression)
                                               for d in data]))


def evaluate_predictions(data: list, masks: list, predictions: list, units,
                         scale: np.ndarray) -> dict:
    """``{expression: {"train": PaperMetrics, "test": PaperMetrics}}`` for one split."""
    if not len(data) == len(masks) == len(predictions):
        raise ParameterError(f"{len(data)} utterances, {len(masks)} masks and "
                             f"{len(predictions)} predictions must agree")
    out: dict = {}
    for e in sorted({d.expression for d in data}, key=_expr_order):
        for part in PARTS:
            truth, est = [], []
            for d, m, p in zip(data, masks, predictions):
                if d.expression != e:
                    continue
                if p.shape != d.mups.shape:
                    raise ParameterError(f"utterance {d.utt_id}: estimated MUPs {p.shape} and "
                                         f"true MUPs {d.mups.shape} differ in shape")
                sel = m if part == "train" else ~m
                truth.append(displacements(units, d.mups[sel], e))
                est.append(displacements(units, p[sel], e))
            t, s = np.concatenate(truth), np.concatenate(est)
            if len(t) >= 2:
                out.setdefault(e, {})[part] = paper_metrics(t, s, scale)
    return out


def _expr_order(e: str) -> tuple:
    order = ("neutral", "smile", "sad")
    return (order.index(e) if e in order else len(order), e)


def gate_accuracy(mapper, data: list, masks: list) -> dict:
    """Frame accuracy of the gate (after the small-class rule) on neutral training and test
    frames and on all test frames, with the confusion matrix of the neutral test frames."""
    n = len(mapper.class_names_)
    hits = {f"{s}_{p}": [0, 0] for p in PARTS for s in ("neutral", "all")}
    conf = np.zeros((n, n), int)
    for d, m in zip(data, masks):
        pred = mapper.gate_classes(d.features)  # once per utterance, both parts
        true = mapper.group_of_phone_[d.phones]
        for part, sel in (("train", m), ("test", ~m)):
            scopes = ("neutral", "all") if d.expression == "neutral" else ("all",)
            for scope in scopes:
                hits[f"{scope}_{part}"][0] += int((pred[sel] == true[sel]).sum())
                hits[f"{scope}_{part}"][1] += int(sel.sum())
            if part == "test" and d.expression == "neutral":
                conf += confusion(true[sel], pred[sel], n)
    out = {k: h / t if t else float("nan") for k, (h, t) in hits.items()}
    out["confusion"] = conf
    out["class_names"] = list(mapper.class_names_)
    out["merges"] = dict(mapper.merges_)
    return out


@dataclass
class MethodResult:
    method: str
    split: str
    tables: dict  # expression → part → PaperMetrics
    fit_seconds: float
    reference: str
    mapper: object = field(repr=False, default=None)
    predictions: list = field(repr=False, default_factory=list)
    gate: dict | None = None
    masks: list = field(repr=False, default_factory=list)


def run_method(method: str, data: list, masks: list, units, mcfg, *, split: str, seed: int,
               scale: np.ndarray) -> MethodResult:
    """Train one method on a split's training frames and evaluate both parts."""
    mapper = make_mapper(method, mcfg, n_utterance=units.n_utterance, seed=seed)
    t0 = time.perf_counter()
    mapper.fit(data, masks)
    seconds = time.perf_counter() - t0
    preds = [mapper.predict(d.features, d.expression) for d in data]
    tables = evaluate_predictions(data, masks, preds, units, scale)
    gate = gate_accuracy(mapper, data, masks) if hasattr(mapper, "gate_") else None
    return MethodResult(method, split, tables, seconds, mapper.reference, mapper, preds, gate,
                        masks)


def run_experiment(data: list, units, mcfg, *, seed: int, methods=None, splits=None,
                   progress: bool = False) -> list[MethodResult]:
    """Every method × split; the split of a given seed is the same for every method."""
    methods = list(methods or [mcfg.method, *[b for b in mcfg.baselines if b != mcfg.method]])
    splits = list(splits or mcfg.splits)
    scale = database_scale(data, units)
    jobs = [(s, m) for s in splits for m in methods]
    try:
        from tqdm import tqdm
        it = tqdm(jobs, desc="training", unit="model", disable=not progress)
    except ImportError:  # pragma: no cover - tqdm is a dependency
        it = jobs
    out = []
    for split, method in it:
        masks = split_masks(data, split, train_fraction=mcfg.train_fraction, seed=seed + 17)
        out.append(run_method(method, data, masks, units, mcfg, split=split, seed=seed,
                              scale=scale))
    return out


def table_rows(results: list[MethodResult]) -> list[dict]:
    """One flat row per method × split × expression × part, with the paper's values."""
    rows = []
    for r in results:
        for e, parts in r.tables.items():
            for part, m in parts.items():
                paper = PAPER_TABLES[part].get(e, (np.nan,) * 4)
                rows.append({"method": r.method, "split": r.split, "expression": e, "part": part,
                             **m.as_dict(),
                             **{f"paper_{k}": v for k, v in zip(METRIC_NAMES, paper)}})
    return rows


def ranking(results: list[MethodResult], split: str = "utterance") -> list[dict]:
    """Methods ranked by mean test R over expressions on ``split`` (ties: lower MSE first)."""
    rows = []
    for r in results:
        if r.split != split:
            continue
        test = [p["test"] for p in r.tables.values() if "test" in p]
        rows.append({"method": r.method, "reference": r.reference,
                     "R": float(np.mean([m.R for m in test])),
                     "MSE": float(np.mean([m.MSE for m in test])),
                     "fit_seconds": r.fit_seconds})
    rows.sort(key=lambda x: (-x["R"], x["MSE"]))
    for i, x in enumerate(rows, 1):
        x["rank"] = i
    return rows
