"""The paper's mapping (§VI): a phone-class gate choosing one of a bank of small MLPs, and the
expression cascade Υ_k (§VI-B).

Training, as in the paper:

1. The gate's mixtures are fitted on the neutral training frames (Ψ_0), labelled with their
   phone class (after the small-class rule of :mod:`mapping.gate`).
2. The neutral training frames are divided into subsets by the gate's decision (the paper
   classifies every sample with the mixtures); one three-layer MLP Ξ_0i per subset maps the
   7-frame audio context to the utterance MUPs. A subset smaller than ``min_class_frames`` is
   joined by the frames labelled with its class, so each MLP sees at least that many frames.
   Hidden units grow with the subset size (:func:`hidden_units`), from ``hidden_min`` for the
   smallest subset to ``hidden_max`` for the largest.
3. ``cascade``: for each expression k, the bank estimates the utterance MUPs of the training
   frames of Ψ_k, and Υ_k (one hidden layer, ``cascade_hidden`` units) maps those estimates to
   the true utterance + expression MUPs. ``bank``: the paper's "straightforward" alternative,
   a bank retrained on Ψ_k with the full MUPs as targets (the gate is shared).

Estimation: features → context → gate → the chosen MLP → utterance MUPs → Υ_k (or bank_k).
Neutral speech has zero expression MUPs.
"""
from __future__ import annotations

import numpy as np

from face_model.errors import NotFittedError, ParameterError
from mapping.features import ContextFeatures
from mapping.gate import PhoneGate, class_groups, merge_small_classes
from mapping.nets import MLP, NetRegressor, TrainSettings

EXPRESSION_MODELS = ("cascade", "bank")


def hidden_units(n_frames: int, smallest: int, largest: int, lo: int = 15, hi: int = 25) -> int:
    """Hidden units of a subset's MLP: ``lo`` for the smallest subset, ``hi`` for the largest,
    in between linearly in log(size)."""
    if largest <= smallest:
        return hi
    t = (np.log(n_frames) - np.log(smallest)) / (np.log(largest) - np.log(smallest))
    return int(round(lo + (hi - lo) * float(np.clip(t, 0, 1))))


class MLPBank:
    """One MLP per class; each frame is estimated by the MLP of its class."""

    def __init__(self, hidden_min: int = 15, hidden_max: int = 25,
                 settings: TrainSettings = TrainSettings(), seed: int = 0):
        self.hidden_min = hidden_min
        self.hidden_max = hidden_max
        self.settings = settings
        self.seed = seed

    def fit(self, X: np.ndarray, Y: np.ndarray, subsets: dict) -> "MLPBank":
        """``subsets``: class → row indices of X/Y used to train that class's MLP."""
        sizes = {c: len(rows) for c, rows in subsets.items()}
        empty = [c for c, n in sizes.items() if n == 0]
        if empty:
            raise ParameterError(f"phone classes {empty} have no training frames for their MLP")
        lo, hi = min(sizes.values()), max(sizes.values())
        self.nets_, self.hidden_ = {}, {}
        for i, (c, rows) in enumerate(sorted(subsets.items())):
            h = hidden_units(len(rows), lo, hi, self.hidden_min, self.hidden_max)
            net = NetRegressor(MLP(X.shape[1], h, Y.shape[1]), self.settings, self.seed + 101 * i)
            self.nets_[c], self.hidden_[c] = net.fit(X[rows], Y[rows]), h
        return self

    def predict(self, X: np.ndarray, classes: np.ndarray) -> np.ndarray:
        if not hasattr(self, "nets_"):
            raise NotFittedError("MLPBank is not fitted yet: call fit() first")
        out = None
        for c in np.unique(classes):
            if c not in self.nets_:
                raise ParameterError(f"class {c!r} has no MLP; trained classes: "
                                     f"{sorted(self.nets_)}")
            rows = classes == c
            pred = self.nets_[c].predict(X[rows])
            if out is None:
                out = np.zeros((len(X), pred.shape[1]), np.float32)
            out[rows] = pred
        return out


class GatedMLP:
    """The paper's audio-to-MUP mapping: gate + MLP bank + expression cascade.

    Parameters
    ----------
    mcfg : MappingConfig
    n_utterance : int
        A0: the first ``n_utterance`` MUPs are the utterance part the bank estimates.
    seed : int
    """

    name = "gated_mlp"
    reference = "Hong, Wen & Huang (2002), §VI"

    def __init__(self, mcfg, n_utterance: int = 7, seed: int = 0):
        if mcfg.expression_model not in EXPRESSION_MODELS:
            raise ParameterError(f"mapping.expression_model must be one of {EXPRESSION_MODELS}, "
                                 f"got {mcfg.expression_model!r}")
        self.mcfg = mcfg
        self.n_utterance = n_utterance
        self.seed = seed

    # -- training --------------------------------------------------------------------------
    def fit(self, data: list, masks: list) -> "GatedMLP":
        m = self.mcfg
        settings = TrainSettings.from_config(m)
        self.context_ = ContextFeatures(m.context_back, m.context_forward).fit(
            [d.features for d in data], masks)
        group_of_phone, names, visemes = class_groups(m.n_classes)
        X, Y, labels, expr = self._stack(data, masks, group_of_phone)
        neutral = expr == "neutral"
        if not neutral.any():
            raise ParameterError("the mapping needs neutral training frames (Ψ_0) for the gate "
                                 "and the MLP bank; the training set has none")
        target, self.merges_ = merge_small_classes(labels[neutral], names, visemes,
                                                   m.min_class_frames)
        self.group_of_phone_ = target[group_of_phone]
        self.class_names_ = names
        labels = target[labels]
        classes = np.unique(labels[neutral])
        self.gate_ = PhoneGate(m.gate_components, m.gate_covariance, self.seed).fit(
            X[neutral], labels[neutral], classes)
        gated = self.gate_.predict(X)
        self.bank_ = MLPBank(m.hidden_min, m.hidden_max, settings, self.seed + 1).fit(
            X, Y[:, :self.n_utterance], self._subsets(gated, labels, neutral, classes))
        self.expressions_ = tuple(sorted({e for e in expr if e != "neutral"}))
        self.n_mups_ = Y.shape[1]
        self.experts_ = {}
        for j, k in enumerate(self.expressions_):
            rows = expr == k
            if m.expression_model == "cascade":
                c0 = self.bank_.predict(X[rows], gated[rows])
                net = NetRegressor(MLP(c0.shape[1], m.cascade_hidden, Y.shape[1]), settings,
                                   self.seed + 7919 * (j + 1))
                self.experts_[k] = net.fit(c0, Y[rows])
            else:
                sub = self._subsets(gated[rows], labels[rows], np.ones(rows.sum(), bool), classes)
                self.experts_[k] = MLPBank(m.hidden_min, m.hidden_max, settings,
                                           self.seed + 7919 * (j + 1)).fit(X[rows], Y[rows], sub)
        return self

    def _stack(self, data, masks, group_of_phone):
        xs, ys, ls, es = [], [], [], []
        for d, mk in zip(data, masks):
            xs.append(self.context_.transform(d.features)[mk])
            ys.append(d.mups[mk])
            ls.append(group_of_phone[d.phones[mk]])
            es.append(np.full(int(mk.sum()), d.expression))
        return (np.concatenate(xs), np.concatenate(ys).astype(np.float32), np.concatenate(ls),
                np.concatenate(es))

    def _subsets(self, gated, labels, use, classes) -> dict:
        subsets = {}
        for c in classes:
            rows = np.flatnonzero(use & (gated == c))
            if len(rows) < self.mcfg.min_class_frames:
                rows = np.union1d(rows, np.flatnonzero(use & (labels == c)))
            subsets[c] = rows
        return subsets

    # -- estimation ------------------------------------------------------------------------
    def _check_fitted(self):
        if not hasattr(self, "bank_"):
            raise NotFittedError("GatedMLP is not trained yet: call fit() first")

    def gate_classes(self, features: np.ndarray) -> np.ndarray:
        """The class chosen by the gate for each frame of one utterance's raw features."""
        self._check_fitted()
        return self.gate_.predict(self.context_.transform(features))

    def predict(self, features: np.ndarray, expression: str = "neutral") -> np.ndarray:
        """MUPs (n_frames, A0 + Ak) of one utterance from its raw features (n_frames, n_feat)."""
        self._check_fitted()
        return self.predict_stacked(self.context_.transform(features), expression)

    def predict_stacked(self, X: np.ndarray, expression: str = "neutral") -> np.ndarray:
        """MUPs from normalised, context-stacked features (n_frames, n_inputs); each row is
        estimated on its own, which is what the streaming animator needs."""
        self._check_fitted()
        if expression != "neutral" and expression not in self.experts_:
            raise ParameterError(f"expression {expression!r} was not trained; allowed: neutral, "
                                 f"{', '.join(self.expressions_)}")
        gated = self.gate_.predict(X)
        c0 = self.bank_.predict(X, gated)
        if expression == "neutral":
            return np.concatenate([c0, np.zeros((len(X), self.n_mups_ - c0.shape[1]),
                                                np.float32)], axis=1)
        if self.mcfg.expression_model == "cascade":
            return self.experts_[expression].predict(c0)
        return self.experts_[expression].predict(X, gated)
