"""The mapping's evaluation exactly as §VII-A, over methods and splits (Tables I and II).

The methods are trained by :mod:`mapping.experiment`; this module only measures them.

For every utterance, the true MUPs (the tracked MUP sequence) and the estimated MUPs are both
turned back into marker displacements with the Motion Units (Eq. 2). Each displacement value is
divided by the maximum absolute ground-truth displacement of that marker coordinate over the whole
database (every expression), then R (Eq. 6), ν (Eq. 7) and MSE (Eq. 8) are computed per expression
on the training frames (Table I) and on the test frames (Table II) of a split. Beside them, the
lip and face metrics of :mod:`analysis.lip_metrics` (LVE, FDD, per-region R, closure on /p b m/)
on the same frames.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from analysis.lip_metrics import LIP_METRIC_NAMES, lip_metrics
from analysis.metrics import METRIC_NAMES, PAPER_TABLES, normalization_scale, paper_metrics
from face_model.corpus import EXPRESSIONS
from groundwork.errors import ParameterError
from mapping.experiment import TrainedMethod

PARTS = ("train", "test")
# the figures of a table row that are logged: the paper's, then the lips' and face's
ROW_METRIC_NAMES = METRIC_NAMES + LIP_METRIC_NAMES


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


def evaluate_lips(data: list, masks: list, predictions: list, units, scale: np.ndarray) -> dict:
    """``{expression: {"train": LipMetrics, "test": LipMetrics}}`` for one split (the frames
    of :func:`evaluate_predictions`)."""
    out: dict = {}
    for e in sorted({d.expression for d in data}, key=_expr_order):
        utts = [(d, m, p) for d, m, p in zip(data, masks, predictions) if d.expression == e]
        truths = [displacements(units, d.mups, e) for d, _, _ in utts]
        ests = [displacements(units, p, e) for _, _, p in utts]
        phones = [d.phones for d, _, _ in utts]
        for part in PARTS:
            uses = [np.asarray(m) if part == "train" else ~np.asarray(m) for _, m, _ in utts]
            if sum(int(u.sum()) for u in uses) >= 2:
                out.setdefault(e, {})[part] = lip_metrics(truths, ests, phones, uses, scale)
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
    lips: dict = field(default_factory=dict)  # [expression][part] -> LipMetrics


def evaluate_experiment(trained: list, data: list, units) -> list[MethodResult]:
    """The paper's metrics of every trained method × split, each value normalised by the
    database's maximum displacement of its marker coordinate (:func:`database_scale`)."""
    scale = database_scale(data, units)
    return [MethodResult(t.method, t.split, t.fit_seconds, t.reference,
                         evaluate_predictions(data, t.masks, t.predictions, units, scale), t,
                         evaluate_lips(data, t.masks, t.predictions, units, scale))
            for t in trained]


def table_rows(results: list[MethodResult]) -> list[dict]:
    """One flat row per method × split × expression × part, with the paper's values."""
    rows = []
    for r in results:
        for e, parts in r.tables.items():
            for part, m in parts.items():
                paper = PAPER_TABLES[part].get(e, (np.nan,) * 4)
                lips = r.lips.get(e, {}).get(part)
                rows.append({"method": r.method, "split": r.split, "expression": e, "part": part,
                             **m.as_dict(),
                             **{f"paper_{k}": v for k, v in zip(METRIC_NAMES, paper)},
                             **(lips.as_dict() if lips is not None else {})})
    return rows


def _pooled_closure(lips: list) -> float:
    """Closure over the bilabial segments of every expression's set together."""
    n = sum(m.bilabial_segments for m in lips)
    return (float(sum(m.closure * m.bilabial_segments for m in lips if m.bilabial_segments) / n)
            if n else float("nan"))


def row_metrics(row: dict, prefix: str = "") -> dict:
    """The logged figures of one :func:`table_rows` row, named
    ``<prefix><split>.<expression>.<part>.<metric>``."""
    where = f"{prefix}{row['split']}.{row['expression']}.{row['part']}"
    return {f"{where}.{k}": row[k] for k in ROW_METRIC_NAMES if k in row}


def ranking(results: list[MethodResult], split: str = "utterance") -> list[dict]:
    """Methods ranked by mean test R over expressions on ``split`` (ties: lower MSE first)."""
    rows = []
    for r in results:
        if r.split != split:
            continue
        test = [p["test"] for p in r.tables.values() if "test" in p]
        lips = [p["test"] for p in r.lips.values() if "test" in p]
        rows.append({"method": r.method, "reference": r.reference,
                     "R": float(np.mean([m.R for m in test])),
                     "MSE": float(np.mean([m.MSE for m in test])),
                     "LVE": float(np.mean([m.LVE for m in lips])) if lips else float("nan"),
                     "R_lips": float(np.mean([m.R_lips for m in lips])) if lips
                     else float("nan"),
                     "closure": _pooled_closure(lips),
                     "fit_seconds": r.fit_seconds})
    rows.sort(key=lambda x: (-x["R"], x["MSE"]))
    for i, x in enumerate(rows, 1):
        x["rank"] = i
    return rows
