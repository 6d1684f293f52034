"""The mapping's evaluation exactly as §VII-A, over methods and splits (Tables I and II).

The methods are trained by :mod:`mapping.experiment`; this module only measures them.

For every utterance, the true MUPs (the tracked MUP sequence) and the estimated MUPs are both
turned back into marker displacements with the Motion Units (Eq. 2). Each displacement value is
divided by the maximum absolute ground-truth displacement of that marker coordinate over the whole
database (every expression), then R (Eq. 6), ν (Eq. 7) and MSE (Eq. 8) are computed per expression
on the training frames (Table I) and on the test frames (Table II) of a split.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from analysis.metrics import METRIC_NAMES, PAPER_TABLES, normalization_scale, paper_metrics
from face_model.corpus import EXPRESSIONS
from face_model.errors import ParameterError
from mapping.experiment import TrainedMethod

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
    return (EXPRESSIONS.index(e) if e in EXPRESSIONS else len(EXPRESSIONS), e)


@dataclass
class MethodResult:
    """One trained method × split with its Tables I–II figures: ``tables[expression][part]`` is
    a :class:`analysis.metrics.PaperMetrics`; ``trained`` holds the mapper, its predictions, the
    split's masks and the gate diagnostics (:class:`mapping.experiment.TrainedMethod`)."""

    method: str
    split: str
    fit_seconds: float
    reference: str
    tables: dict
    trained: TrainedMethod = field(repr=False)


def evaluate_experiment(trained: list, data: list, units) -> list[MethodResult]:
    """The paper's metrics of every trained method × split, each value normalised by the
    database's maximum displacement of its marker coordinate (:func:`database_scale`)."""
    scale = database_scale(data, units)
    return [MethodResult(t.method, t.split, t.fit_seconds, t.reference,
                         evaluate_predictions(data, t.masks, t.predictions, units, scale), t)
            for t in trained]


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
