"""Motion Units: PCA of facial deformations (paper §IV-A, Eqs. 1–2).

Utterance MUs ``M_0`` are the mean ``m_00`` and the first ``A_0`` principal axes of the neutral
deformations ``D_0``. For each expression k, the residual of ``D_k`` beyond the utterance MUs is

    r = d − m_00 − Σ_j m_0j m_0jᵀ (d − m_00)

(the residual consistent with Eqs. 2 and 4; Eq. 1 as printed omits ``m_00``), and the Expression
MUs ``M_k`` are its mean ``m_k0`` and first ``A_k`` principal axes. MUPs of a frame are
``c_0 = M_0ᵀ (d − m_00)`` (``A_0`` values) followed by ``c_k = M_kᵀ (r − m_k0)`` (``A_k`` values,
zeros for a neutral frame); Eq. 2 reconstructs ``d`` from them.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from face_model.alignment import corpus_deformations
from face_model.layout import LAYOUT_VERSION, N_MARKERS
from groundwork import modelfile
from groundwork.errors import NotFittedError, ParameterError
from groundwork.numerics import single_threaded, svd

N_DIM = 2 * N_MARKERS
# The record of to_arrays (also embedded in keyframe model files); it has not changed.
FORMAT = "talkingface.motion_units/1"
# The file (motion_units.npz), a groundwork.modelfile of this kind. Versions:
# 1: np.savez of the record's arrays and its JSON under ``metadata``; no kind, no checksum
#    (still read);
# 2: written by groundwork.modelfile: the same arrays and record, plus kind, version, array
#    manifest and SHA-256 in the metadata, written atomically.
KIND, VERSION = "motion_units", 2


def _pca(X: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean (d,), the first ``n`` axes (n, d) with deterministic signs, and the variance of every
    axis (all eigenvalues, descending)."""
    mean = X.mean(0)
    _, s, vt = svd(X - mean, full_matrices=False)  # one BLAS thread, gesvd if gesdd fails
    # Deterministic signs: the largest-magnitude loading of each axis is positive (svd_flip).
    signs = np.sign(vt[np.arange(len(vt)), np.abs(vt).argmax(1)])
    vt *= signs[:, None]
    var = s**2 / max(len(X) - 1, 1)
    return mean, vt[:n].copy(), var


def _as_2d(d, name="deformations") -> np.ndarray:
    d = np.asarray(d, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != N_DIM:
        raise ParameterError(f"{name} must have shape (n_frames, {N_DIM}), got {d.shape}")
    if not np.all(np.isfinite(d)):
        raise ParameterError(f"{name} hold NaN or inf values")
    return d


class MotionUnits:
    """Utterance and Expression Motion Units, scikit-learn style.

    Parameters
    ----------
    n_utterance : int
        A_0, the number of utterance MUs (paper: 7).
    n_expression : int
        A_k, the number of MUs per expression (paper: 2).

    Attributes (after ``fit``)
    --------------------------
    mean_ : ndarray (158,)                 m_00
    components_ : ndarray (A_0, 158)       m_01 … m_0A0, orthonormal rows
    variance_ : ndarray                    every eigenvalue of D_0's covariance (descending)
    expressions_ : tuple of str            the non-neutral expressions fitted
    expression_mean_ : dict k → (158,)     m_k0
    expression_components_ : dict k → (A_k, 158)
    expression_variance_ : dict k → ndarray   eigenvalues of R_k's covariance
    """

    def __init__(self, n_utterance: int = 7, n_expression: int = 2):
        self.n_utterance = n_utterance
        self.n_expression = n_expression

    # -- fitting ---------------------------------------------------------------------------
    @single_threaded
    def fit(self, deformations: dict, metadata: dict | None = None) -> "MotionUnits":
        """Learn the MUs from ``{"neutral": D_0, "smile": D_1, ...}``, each (n_frames, 158)."""
        if "neutral" not in deformations:
            raise ParameterError("MotionUnits.fit needs neutral deformations (key 'neutral'); "
                                 f"got keys {sorted(deformations)}")
        for name, value in (("n_utterance", self.n_utterance), ("n_expression", self.n_expression)):
            if not isinstance(value, (int, np.integer)) or not 1 <= value <= N_DIM:
                raise ParameterError(f"{name} must be an integer in 1..{N_DIM}, got {value!r}")
        d0 = _as_2d(deformations["neutral"], "neutral deformations")
        if len(d0) <= self.n_utterance:
            raise ParameterError(f"{len(d0)} neutral frames cannot give {self.n_utterance} MUs")
        self.mean_, self.components_, self.variance_ = _pca(d0, self.n_utterance)
        self.expressions_ = tuple(k for k in deformations if k != "neutral")
        self.expression_mean_, self.expression_components_, self.expression_variance_ = {}, {}, {}
        for k in self.expressions_:
            dk = _as_2d(deformations[k], f"{k} deformations")
            if len(dk) <= self.n_expression:
                raise ParameterError(f"{len(dk)} {k} frames cannot give {self.n_expression} MUs")
            r = self._residual(dk)
            m, c, v = _pca(r, self.n_expression)
            self.expression_mean_[k], self.expression_components_[k] = m, c
            self.expression_variance_[k] = v
        self.metadata_ = dict(metadata or {})
        return self

    def _check_fitted(self):
        if not hasattr(self, "components_"):
            raise NotFittedError("MotionUnits is not fitted yet: call fit() or MotionUnits.load()")

    def _residual(self, d: np.ndarray) -> np.ndarray:
        c0 = (d - self.mean_) @ self.components_.T
        return d - self.mean_ - c0 @ self.components_

    def _check_expression(self, expression: str) -> None:
        if expression != "neutral" and expression not in self.expressions_:
            raise ParameterError(f"expression {expression!r} has no MUs; allowed: neutral, "
                                 f"{', '.join(self.expressions_)}")

    # -- the Eq. 2 model -------------------------------------------------------------------
    @property
    def n_mups(self) -> int:
        return self.n_utterance + self.n_expression

    def transform(self, deformations, expression: str = "neutral") -> np.ndarray:
        """MUPs (n_frames, A_0 + A_k): utterance part c_0, then expression part c_k (zeros for
        neutral)."""
        self._check_fitted()
        self._check_expression(expression)
        d = _as_2d(deformations)
        c0 = (d - self.mean_) @ self.components_.T
        ck = np.zeros((len(d), self.n_expression))
        if expression != "neutral":
            r = d - self.mean_ - c0 @ self.components_
            ck = (r - self.expression_mean_[expression]) @ self.expression_components_[expression].T
        return np.concatenate([c0, ck], axis=1)

    def inverse_transform(self, mups, expression: str = "neutral") -> np.ndarray:
        """Deformations (n_frames, 158) from MUPs by Eq. 2."""
        self._check_fitted()
        self._check_expression(expression)
        mups = np.asarray(mups, dtype=np.float64)
        if mups.ndim != 2 or mups.shape[1] != self.n_mups:
            raise ParameterError(f"MUPs must have shape (n_frames, {self.n_mups}), got {mups.shape}")
        d = self.mean_ + mups[:, : self.n_utterance] @ self.components_
        if expression != "neutral":
            d = (d + self.expression_mean_[expression]
                 + mups[:, self.n_utterance:] @ self.expression_components_[expression])
        return d

    # -- variance --------------------------------------------------------------------------
    def explained_variance_ratio(self, expression: str = "neutral") -> np.ndarray:
        """Cumulative fraction of variance explained by the first 1, 2, … axes (all axes) of
        D_0 (``neutral``) or of the residual R_k."""
        self._check_fitted()
        self._check_expression(expression)
        v = self.variance_ if expression == "neutral" else self.expression_variance_[expression]
        return np.cumsum(v) / v.sum()

    def variance_explained(self) -> dict[str, float]:
        """Fraction explained by the kept MUs: ``neutral`` by A_0, each expression by A_k."""
        out = {"neutral": float(self.explained_variance_ratio("neutral")[self.n_utterance - 1])}
        for k in self.expressions_:
            out[k] = float(self.explained_variance_ratio(k)[self.n_expression - 1])
        return out

    # -- persistence -----------------------------------------------------------------------
    def to_arrays(self) -> tuple[dict[str, np.ndarray], dict]:
        """The fitted model as named arrays and a JSON-serialisable metadata record.

        Returns
        -------
        arrays : dict str → ndarray
            ``mean`` (158,), ``components`` (A_0, 158), ``variance``, and for every expression
            k ``k__mean`` (158,), ``k__components`` (A_k, 158), ``k__variance``.
        metadata : dict
            ``format``, ``layout_version``, ``n_utterance``, ``n_expression``, ``expressions``
            and the entries of ``metadata_``.

        :meth:`from_arrays` is the inverse; :meth:`save` writes both into one ``.npz``, and
        other files that embed Motion Units (the keyframe model) store them the same way.
        """
        self._check_fitted()
        meta = {"format": FORMAT, "layout_version": LAYOUT_VERSION,
                "n_utterance": self.n_utterance, "n_expression": self.n_expression,
                "expressions": list(self.expressions_), **self.metadata_}
        arrays = {"mean": self.mean_, "components": self.components_, "variance": self.variance_}
        for k in self.expressions_:
            arrays[f"{k}__mean"] = self.expression_mean_[k]
            arrays[f"{k}__components"] = self.expression_components_[k]
            arrays[f"{k}__variance"] = self.expression_variance_[k]
        return arrays, meta

    @classmethod
    def from_arrays(cls, arrays, metadata: dict, *, source: str = "Motion Units") -> "MotionUnits":
        """Rebuild a fitted model from the output of :meth:`to_arrays`.

        Parameters
        ----------
        arrays : mapping str → ndarray
            E.g. an open ``np.load`` file; only the names of :meth:`to_arrays` are read.
        metadata : dict
            The metadata record; every entry other than the model's own settings (and
            ``layout_version``) goes back into ``metadata_``.
        source : str
            Names the file or record in error messages.
        """
        if metadata.get("format") != FORMAT:
            raise ParameterError(f"{source}: not a Motion Units file (format "
                                 f"{metadata.get('format')!r}, expected {FORMAT!r})")
        mu = cls(metadata["n_utterance"], metadata["n_expression"])
        expressions = tuple(metadata["expressions"])
        names = ["mean", "components", "variance"] + [
            f"{k}__{a}" for k in expressions for a in ("mean", "components", "variance")]
        missing = [n for n in names if n not in arrays]
        if missing:
            raise ParameterError(f"{source}: Motion Units arrays {', '.join(missing)} are "
                                 "missing")
        mu.mean_, mu.components_, mu.variance_ = (arrays["mean"], arrays["components"],
                                                  arrays["variance"])
        mu.expressions_ = expressions
        mu.expression_mean_ = {k: arrays[f"{k}__mean"] for k in expressions}
        mu.expression_components_ = {k: arrays[f"{k}__components"] for k in expressions}
        mu.expression_variance_ = {k: arrays[f"{k}__variance"] for k in expressions}
        skip = {"format", "layout_version", "n_utterance", "n_expression", "expressions"}
        mu.metadata_ = {k: v for k, v in metadata.items() if k not in skip}
        mu.metadata_["layout_version"] = metadata["layout_version"]
        return mu

    def save(self, path) -> Path:
        """Write one model file (:mod:`groundwork.modelfile`, kind ``motion_units``, version
        :data:`VERSION`) holding every array of :meth:`to_arrays` and, as its metadata, the
        JSON record; atomically (never half-written under ``path``)."""
        arrays, meta = self.to_arrays()
        return modelfile.write_model(path, arrays, meta, kind=KIND, version=VERSION)

    @classmethod
    def load(cls, path) -> "MotionUnits":
        """Rebuild a model saved by :meth:`save`, or by the version-1 code (no checksum).

        Raises
        ------
        ParameterError
            Naming the file: missing, not a model file, damaged (checksum), another kind, a
            newer version, Python objects inside, or not a Motion Units record.
        """
        path = Path(path)
        if not path.is_file():
            raise ParameterError(f"Motion Units file {path} not found")
        found = modelfile.read_model(path, kind=KIND, versions=(VERSION,),
                                     what="Motion Units file", legacy=(modelfile.METADATA,))
        return cls.from_arrays(found.arrays, found.metadata, source=str(path))

def fit_corpus_units(corpus, *, n_utterance: int = 7, n_expression: int = 2,
                     alignment: str = "similarity", metadata: dict | None = None):
    """Align, compute deformations and fit MUs on a whole corpus.

    Returns ``(units, deformations_by_utterance)``.
    """
    defs = corpus_deformations(corpus, model=alignment)
    by_expr: dict[str, list] = {}
    for u in corpus.utterances:
        by_expr.setdefault(u.expression, []).append(defs[u.utt_id])
    stacked = {k: np.concatenate(v) for k, v in by_expr.items()}
    meta = {"alignment": alignment, **(metadata or {})}
    units = MotionUnits(n_utterance, n_expression).fit(stacked, metadata=meta)
    return units, defs
