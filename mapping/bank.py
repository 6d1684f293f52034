"""The MLP bank of the paper's mapping (§VI-A): one three-layer MLP per gate class, trained
together as one batched module (:func:`mapping.nets.fit_many`), each frame estimated by the MLP
of its class. Hidden units grow with the class's training frames (:func:`hidden_units`)."""
from __future__ import annotations

import numpy as np

from groundwork.errors import NotFittedError, ParameterError
from mapping.config import TrainSettings
from mapping.nets import MLP, NetRegressor, fit_many
from mapping.state import ArrayGroup, nest, part_name, settings_from_params, settings_to_params


def hidden_units(n_frames: int, smallest: int, largest: int, lo: int = 15, hi: int = 25) -> int:
    """Hidden units of a subset's MLP: ``lo`` for the smallest subset, ``hi`` for the largest,
    in between linearly in log(size)."""
    if largest <= smallest:
        return hi
    t = (np.log(n_frames) - np.log(smallest)) / (np.log(largest) - np.log(smallest))
    return int(round(lo + (hi - lo) * float(np.clip(t, 0, 1))))


def fit_banks(prepared: list) -> list:
    """Train the networks of several banks (each from :meth:`MLPBank.prepare`) as one batch;
    returns the banks."""
    nets = [n for _, ns, _ in prepared for n in ns]
    data = [d for _, _, ds in prepared for d in ds]
    fit_many(nets, [x for x, _ in data], [y for _, y in data])
    return [bank for bank, _, _ in prepared]


class MLPBank:
    """One MLP per class; each frame is estimated by the MLP of its class."""

    def __init__(self, hidden_min: int = 15, hidden_max: int = 25,
                 settings: TrainSettings = TrainSettings(), seed: int = 0):
        self.hidden_min = hidden_min
        self.hidden_max = hidden_max
        self.settings = settings
        self.seed = seed

    def prepare(self, X: np.ndarray, Y: np.ndarray, subsets: dict) -> tuple:
        """The untrained bank, its networks and their ``(X, Y)``, for :func:`fit_banks`
        (``subsets``: class → row indices of X/Y used to train that class's MLP)."""
        sizes = {c: len(rows) for c, rows in subsets.items()}
        empty = [c for c, n in sizes.items() if n == 0]
        if empty:
            raise ParameterError(f"phone classes {empty} have no training frames for their MLP")
        lo, hi = min(sizes.values()), max(sizes.values())
        self.nets_, self.hidden_, data = {}, {}, []
        for i, (c, rows) in enumerate(sorted(subsets.items())):
            h = hidden_units(len(rows), lo, hi, self.hidden_min, self.hidden_max)
            self.nets_[c] = NetRegressor(MLP(X.shape[1], h, Y.shape[1]), self.settings,
                                         self.seed + 101 * i)
            self.hidden_[c] = h
            data.append((X[rows], Y[rows]))
        return self, list(self.nets_.values()), data

    def fit(self, X: np.ndarray, Y: np.ndarray, subsets: dict) -> "MLPBank":
        """``subsets``: class → row indices of X/Y used to train that class's MLP. The MLPs
        train together as one batched module (:func:`mapping.nets.fit_many`)."""
        return fit_banks([self.prepare(X, Y, subsets)])[0]

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

    # -- persistence (see mapping.state) -----------------------------------------------------
    def to_arrays(self) -> tuple[dict, dict]:
        """The bank as data: the arrays of class c's network under ``nets/<c>/``; parameters:
        the hyper-parameters, the ``classes`` in training order and per class its ``hidden``
        units and network parameters (``nets``)."""
        if not hasattr(self, "nets_"):
            raise NotFittedError("MLPBank is not fitted yet: call fit() first")
        arrays, nets = {}, []
        for c, net in self.nets_.items():
            a, p = net.to_arrays()
            arrays.update(nest(f"nets/{part_name(c)}", a))
            nets.append(p)
        params = {"hidden_min": self.hidden_min, "hidden_max": self.hidden_max,
                  "settings": settings_to_params(self.settings), "seed": self.seed,
                  "classes": [int(c) for c in self.nets_],
                  "hidden": [int(self.hidden_[c]) for c in self.nets_], "nets": nets}
        return arrays, params

    @classmethod
    def from_arrays(cls, arrays, params: dict) -> "MLPBank":
        """The trained bank of :meth:`to_arrays`."""
        g = ArrayGroup.of(arrays)
        bank = cls(params["hidden_min"], params["hidden_max"],
                   settings_from_params(params["settings"]), params["seed"])
        classes, hidden, nets = params["classes"], params["hidden"], params["nets"]
        if not len(classes) == len(hidden) == len(nets) or len(classes) == 0:
            raise ParameterError(f"an MLP bank needs one hidden size and one network per class, "
                                 f"got {len(classes)} classes, {len(hidden)} sizes and "
                                 f"{len(nets)} networks")
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in [*classes, *hidden]):
            raise ParameterError(f"MLP bank classes and hidden sizes must be integers, got "
                                 f"{classes!r} and {hidden!r}")
        bank.nets_, bank.hidden_ = {}, {}
        for c, h, p in zip(classes, hidden, nets):
            bank.nets_[c] = NetRegressor.from_arrays(g.group("nets").group(c), p)
            bank.hidden_[c] = h
        return bank
