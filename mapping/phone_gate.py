"""The phone-class gate (paper §VI-A): one Gaussian mixture per class; a frame goes to the class
whose mixture gives its features the highest likelihood.

Classes. The paper's 44 phone classes (footnote 2), or coarser groupings for ablations: 8 groups
(the six keyframe visemes ``i a o f u m``, the other speech sounds, and silence) or 1 group (no
gate: one MLP for everything). :func:`class_groups` gives the grouping.

Small classes (the explicit rule). A class with fewer than ``min_frames`` training frames cannot
support its own mixture and MLP. It is merged into the largest class (by training frames) of the
same viseme that has enough frames, or, when its viseme has none, into the largest class of all
(when no class has enough, everything joins the largest class).
Merging is decided on the training frames only and written down in ``merges_``, so the gate never
meets a class without frames. :class:`PhoneGate` itself refuses a class with no frames.
"""
from __future__ import annotations

import numpy as np
from sklearn.mixture import GaussianMixture

from face_model.phones import PHONES, viseme
from groundwork.errors import NotFittedError, ParameterError
from groundwork.numerics import single_threaded
from mapping.state import ArrayGroup, nest

N_CLASS_CHOICES = (1, 8, 44)
COVARIANCE_TYPES = ("diag", "full", "tied", "spherical")
# The fitted arrays of a scikit-learn GaussianMixture that a saved gate keeps.
_MIXTURE_ARRAYS = ("weights", "means", "covariances", "precisions", "precisions_cholesky")
_GROUPS_8 = ("i", "a", "o", "f", "u", "m", "other", "sil")


def class_groups(n_classes: int) -> tuple[np.ndarray, tuple, tuple]:
    """Map the 44 phone classes onto ``n_classes`` groups.

    Returns ``(group_of_phone (44,), group_names, group_visemes)``.
    """
    if n_classes == 44:
        return np.arange(len(PHONES)), tuple(PHONES), tuple(viseme(p) for p in PHONES)
    if n_classes == 8:
        def grp(p):
            if p == "sil":
                return "sil"
            v = viseme(p)
            return "other" if v == "neutral" else v
        g = np.array([_GROUPS_8.index(grp(p)) for p in PHONES])
        return g, _GROUPS_8, _GROUPS_8
    if n_classes == 1:
        return np.zeros(len(PHONES), int), ("all",), ("all",)
    raise ParameterError(f"n_classes must be one of {N_CLASS_CHOICES}, got {n_classes!r}")


def merge_small_classes(labels: np.ndarray, names: tuple, visemes: tuple,
                        min_frames: int) -> tuple[np.ndarray, dict]:
    """Apply the small-class rule to training labels (group indices).

    Returns ``(target (n_groups,), merges)``: ``target[g]`` is the class that group ``g`` is
    modelled by, and ``merges`` maps each merged name to the name it joined.
    """
    counts = np.bincount(labels, minlength=len(names))
    if counts.sum() == 0:
        raise ParameterError("the gate has no training frames at all")
    big = counts >= min_frames
    if not big.any():  # a tiny corpus: every class joins the largest (one MLP, as n_classes=1)
        big = counts == counts.max()
        big[np.flatnonzero(big)[1:]] = False
    target = np.arange(len(names))
    merges = {}
    for g in np.flatnonzero(~big):
        same = [h for h in np.flatnonzero(big) if visemes[h] == visemes[g]]
        pool = same or list(np.flatnonzero(big))
        target[g] = max(pool, key=lambda h: (counts[h], -h))
        merges[names[g]] = names[target[g]]
    return target, merges


class PhoneGate:
    """One scikit-learn ``GaussianMixture`` per class; ``predict`` picks the most likely class.

    Parameters
    ----------
    n_components : int
        Mixture components per class (reduced for a class with few frames, to at most one
        component per 10 frames).
    covariance_type : str
        scikit-learn covariance type (``diag`` by default).
    random_state : int
    """

    def __init__(self, n_components: int = 4, covariance_type: str = "diag",
                 random_state: int = 0):
        self.n_components = n_components
        self.covariance_type = covariance_type
        self.random_state = random_state

    @single_threaded
    def fit(self, X: np.ndarray, y: np.ndarray, classes) -> "PhoneGate":
        """Fit one mixture per entry of ``classes`` on the rows of ``X`` labelled with it.

        X : (n_frames, n_features); y : (n_frames,) class labels; classes : the labels to model.
        """
        X = np.asarray(X, dtype=np.float64)
        y = np.asarray(y)
        if X.ndim != 2 or len(X) != len(y):
            raise ParameterError(f"features {X.shape} and labels {y.shape} must have the same "
                                 "number of frames")
        if not np.all(np.isfinite(X)):
            raise ParameterError("features hold NaN or inf values")
        self.classes_ = np.asarray(list(classes))
        self.mixtures_ = []
        for i, c in enumerate(self.classes_):
            rows = X[y == c]
            if len(rows) == 0:
                raise ParameterError(f"phone class {c!r} has no frames in the training data; "
                                     "merge it (mapping.min_class_frames) or leave it out")
            gmm = self._mixture(int(max(1, min(self.n_components, len(rows) // 10))), i)
            self.mixtures_.append(gmm.fit(rows) if len(rows) > 1 else
                                  gmm.fit(np.concatenate([rows, rows + 1e-3])))
        self._pack()
        return self

    def _mixture(self, k: int, i: int) -> GaussianMixture:
        """The (unfitted) mixture of ``k`` components of the ``i``-th class."""
        return GaussianMixture(k, covariance_type=self.covariance_type, reg_covar=1e-3,
                               random_state=self.random_state + i, max_iter=200)

    def _pack(self) -> None:
        """For diagonal mixtures, stack every component of every class so one matrix product
        scores all of them (the real-time path; identical to ``score_samples``)."""
        self.packed_ = None
        if self.covariance_type != "diag":
            return
        prec = np.concatenate([g.precisions_ for g in self.mixtures_])  # (K, d)
        mean = np.concatenate([g.means_ for g in self.mixtures_])
        const = (np.concatenate([np.log(g.weights_) for g in self.mixtures_])
                 + 0.5 * np.log(prec).sum(1) - 0.5 * mean.shape[1] * np.log(2 * np.pi)
                 - 0.5 * (mean**2 * prec).sum(1))
        owner = np.concatenate([np.full(g.n_components, i) for i, g in enumerate(self.mixtures_)])
        self.packed_ = (-0.5 * prec.T, (mean * prec).T, const, owner)

    def log_likelihood(self, X: np.ndarray) -> np.ndarray:
        """(n_frames, n_classes) log-likelihood of every frame under every class mixture."""
        if not hasattr(self, "mixtures_"):
            raise NotFittedError("PhoneGate is not fitted yet: call fit() first")
        X = np.asarray(X, dtype=np.float64)
        if not np.all(np.isfinite(X)):
            raise ParameterError("features hold NaN or inf values")
        if getattr(self, "packed_", None) is None:
            return np.stack([g.score_samples(X) for g in self.mixtures_], axis=1)
        a, b, const, owner = self.packed_
        comp = (X**2) @ a + X @ b + const  # (n, K): log w_c + log N(x | component c)
        starts = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1]])  # owner is sorted
        top = np.maximum.reduceat(comp, starts, axis=1)  # per-class log-sum-exp, stably
        return top + np.log(np.add.reduceat(np.exp(comp - top[:, owner]), starts, axis=1))

    def predict(self, X: np.ndarray) -> np.ndarray:
        """The class label of each frame (the highest likelihood)."""
        ll = self.log_likelihood(X)  # checks that the gate is fitted first
        return self.classes_[ll.argmax(1)]

    # -- persistence (see mapping.state) -----------------------------------------------------
    def to_arrays(self) -> tuple[dict, dict]:
        """The gate as data: ``classes`` (n_classes,) and, for the i-th class's mixture,
        ``mixtures/<i>/weights``, ``means``, ``covariances``, ``precisions`` and
        ``precisions_cholesky`` (scikit-learn's fitted arrays: what ``score_samples`` and the
        packed real-time path read); parameters: the hyper-parameters, ``n_features`` and per
        mixture its ``n_components``, ``converged``, ``n_iter`` and ``lower_bound``."""
        if not hasattr(self, "mixtures_"):
            raise NotFittedError("PhoneGate is not fitted yet: call fit() first")
        if self.classes_.dtype.kind not in "iu":
            raise ParameterError(f"only a gate with integer class labels can be saved, got "
                                 f"{self.classes_.dtype}")
        arrays = {"classes": self.classes_}
        mixtures = []
        for i, g in enumerate(self.mixtures_):
            arrays.update(nest(f"mixtures/{i}", {name: getattr(g, name + "_")
                                                  for name in _MIXTURE_ARRAYS}))
            mixtures.append({"n_components": int(g.n_components), "converged": bool(g.converged_),
                             "n_iter": int(g.n_iter_), "lower_bound": float(g.lower_bound_)})
        params = {"n_components": self.n_components, "covariance_type": self.covariance_type,
                  "random_state": self.random_state,
                  "n_features": int(self.mixtures_[0].means_.shape[1]), "mixtures": mixtures}
        return arrays, params

    @classmethod
    def from_arrays(cls, arrays, params: dict) -> "PhoneGate":
        """The fitted gate of :meth:`to_arrays`: each ``GaussianMixture`` is rebuilt with the
        hyper-parameters ``fit`` gives it and its fitted arrays set back."""
        g = ArrayGroup.of(arrays)
        if params["covariance_type"] not in COVARIANCE_TYPES:
            raise ParameterError(f"gate covariance_type must be one of {COVARIANCE_TYPES}, got "
                                 f"{params['covariance_type']!r}")
        gate = cls(params["n_components"], params["covariance_type"], params["random_state"])
        d = int(params["n_features"])
        gate.classes_ = g.take("classes", (None,), kinds="iu")
        if len(params["mixtures"]) != len(gate.classes_):
            raise ParameterError(f"the gate has {len(gate.classes_)} classes but "
                                 f"{len(params['mixtures'])} mixtures")
        gate.mixtures_ = []
        for i, p in enumerate(params["mixtures"]):
            k = int(p["n_components"])
            cov = {"full": (k, d, d), "diag": (k, d), "tied": (d, d),
                   "spherical": (k,)}[gate.covariance_type]
            shapes = {"weights": (k,), "means": (k, d), "covariances": cov, "precisions": cov,
                      "precisions_cholesky": cov}
            mix = g.group("mixtures").group(i)
            gmm = gate._mixture(k, i)
            for name in _MIXTURE_ARRAYS:
                setattr(gmm, name + "_", mix.take(name, shapes[name], kinds="f"))
            gmm.n_features_in_ = d
            gmm.converged_, gmm.n_iter_ = bool(p["converged"]), int(p["n_iter"])
            gmm.lower_bound_ = float(p["lower_bound"])
            gate.mixtures_.append(gmm)
        gate._pack()
        return gate


def confusion(true: np.ndarray, pred: np.ndarray, n: int) -> np.ndarray:
    """(n, n) counts: row = true class, column = gated class."""
    m = np.zeros((n, n), int)
    np.add.at(m, (np.asarray(true), np.asarray(pred)), 1)
    return m


def gate_accuracy(mapper, data: list, masks: list) -> dict:
    """Frame accuracy of a trained gated mapping's gate (after the small-class rule) on neutral
    training and test frames and on all test frames, with the confusion matrix of the neutral
    test frames.

    ``mapper`` has ``gate_classes(features, phones)``, ``utterance_phones(d)``,
    ``group_of_phone_``, ``class_names_`` and
    ``merges_`` (:class:`mapping.gated_mlp.GatedMLP`); ``data`` are :class:`mapping.dataset.UttData`
    with their training-frame ``masks``.
    """
    n = len(mapper.class_names_)
    parts = ("train", "test")
    hits = {f"{s}_{p}": [0, 0] for p in parts for s in ("neutral", "all")}
    conf = np.zeros((n, n), int)
    for d, m in zip(data, masks):
        pred = mapper.gate_classes(d.features, mapper.utterance_phones(d))  # once per utt.
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
