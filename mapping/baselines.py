"""Baselines from the paper's related work (§III-C), under the same evaluation as the gated MLP.

Each baseline maps audio features to the full MUPs (utterance + expression part) and is trained
separately per expression on that expression's training frames, the paper's "straightforward"
way to handle expressions. Inputs are the normalised MFCC with a context window; unless said
otherwise the paper's 3 + 1 + 3 frames, so that the baselines differ from the gated MLP in the
mapping only.

=================  ======================================================================
``vq``             vector quantisation [43]: k-means codebook of the audio vectors; each
                   codeword outputs the mean MUPs of its training frames
``linear``         affine / linear regression [44] (ridge, α = 1)
``gmm_regression`` Gaussian mixture regression [45]: a joint GMM of (audio, MUPs); the estimate
                   is the posterior-weighted sum of each component's linear estimate E[v | a]
``mlp_large``      one large MLP, 11-frame context (5 + 1 + 5), 600 hidden units [48]
``tdnn``           time-delay neural network [49], [50] on the single-frame MFCC sequence
``gru``            a modern sequence model: a unidirectional GRU (64 units) over the
                   context-stacked frames, so its look-ahead is still 3 frames (real time)
=================  ======================================================================
"""
from __future__ import annotations

import numpy as np
from scipy.special import logsumexp
from sklearn.cluster import KMeans
from sklearn.linear_model import Ridge
from sklearn.mixture import GaussianMixture
from sklearn.utils._openmp_helpers import _openmp_effective_n_threads

from groundwork.errors import NotFittedError, ParameterError
from groundwork.numerics import single_threaded
from mapping.config import TrainSettings
from mapping.features import ContextFeatures, check_context, check_seed
from mapping.nets import GRUNet, MLP, TDNN, NetRegressor, fit_many
from mapping.normalize import check_cmvn
from mapping.state import (ArrayGroup, nest, part_name, settings_from_params,
                           settings_to_params)

BASELINES = ("vq", "linear", "gmm_regression", "mlp_large", "tdnn", "gru")
REFERENCES = {"vq": "[43] vector quantisation", "linear": "[44] affine transformation",
              "gmm_regression": "[45] Gaussian mixture", "mlp_large": "[48] MLP, 11 frames, 600 "
              "hidden", "tdnn": "[49], [50] TDNN", "gru": "modern: GRU sequence model"}
NETWORK_OF = {"mlp_large": "MLP", "tdnn": "TDNN", "gru": "GRUNet"}  # the networks' classes


class VQRegressor:
    """Codebook of ``n_codes`` k-means centroids; the output of a code is its mean target."""

    def __init__(self, n_codes: int = 64, seed: int = 0):
        self.n_codes, self.seed = n_codes, seed

    @single_threaded
    def fit(self, X, Y):
        k = int(min(self.n_codes, len(X)))
        self.km_ = KMeans(k, n_init=4, random_state=self.seed).fit(X)
        lab = self.km_.labels_
        self.table_ = np.stack([Y[lab == c].mean(0) for c in range(k)])
        return self

    def predict(self, X):
        return self.table_[self.km_.predict(X)]

    def to_arrays(self) -> tuple[dict, dict]:
        """``centers`` (n_codes, n_in), ``table`` (n_codes, n_out); ``n_codes``, ``seed``."""
        if not hasattr(self, "km_"):
            raise NotFittedError("VQRegressor is not fitted yet: call fit() first")
        return ({"centers": self.km_.cluster_centers_, "table": self.table_},
                {"n_codes": self.n_codes, "seed": self.seed})

    @classmethod
    def from_arrays(cls, arrays, params: dict) -> "VQRegressor":
        """The codebook of :meth:`to_arrays`, as a fitted k-means that ``predict`` asks."""
        g = ArrayGroup.of(arrays)
        vq = cls(params["n_codes"], params["seed"])
        centers = g.take("centers", (None, None), kinds="f")
        vq.table_ = g.take("table", (len(centers), None), kinds="f")
        km = KMeans(len(centers), n_init=4, random_state=vq.seed)
        # the fitted state KMeans.predict reads (fit sets the same)
        km.cluster_centers_, km.n_features_in_ = centers, centers.shape[1]
        km._n_threads = _openmp_effective_n_threads()
        vq.km_ = km
        return vq


class GMMRegressor:
    """Joint-density GMM regression (Gaussian mixture mapping of [45])."""

    def __init__(self, n_components: int = 8, seed: int = 0):
        self.n_components, self.seed = n_components, seed

    @single_threaded
    def fit(self, X, Y):
        self.d_ = X.shape[1]
        k = int(max(1, min(self.n_components, len(X) // (4 * (X.shape[1] + Y.shape[1])))))
        Z = np.concatenate([X, Y], axis=1).astype(np.float64)
        g = GaussianMixture(k, covariance_type="full", reg_covar=1e-3, random_state=self.seed,
                            max_iter=200).fit(Z)
        d = self.d_
        self.weights_ = g.weights_
        self.mx_, self.my_ = g.means_[:, :d], g.means_[:, d:]
        sxx, syx = g.covariances_[:, :d, :d], g.covariances_[:, d:, :d]
        self.gain_ = np.stack([syx[i] @ np.linalg.inv(sxx[i]) for i in range(k)])
        self.chol_ = np.stack([np.linalg.cholesky(sxx[i]) for i in range(k)])
        return self

    def _log_px(self, X):
        out = []
        for w, m, L in zip(self.weights_, self.mx_, self.chol_):
            z = np.linalg.solve(L, (X - m).T)
            out.append(np.log(w) - 0.5 * (z**2).sum(0) - np.log(np.diag(L)).sum()
                       - 0.5 * self.d_ * np.log(2 * np.pi))
        return np.stack(out, axis=1)

    def predict(self, X):
        X = np.asarray(X, dtype=np.float64)
        lp = self._log_px(X)
        post = np.exp(lp - logsumexp(lp, axis=1, keepdims=True))
        est = np.stack([self.my_[i] + (X - self.mx_[i]) @ self.gain_[i].T
                        for i in range(len(self.weights_))], axis=1)
        return (post[:, :, None] * est).sum(1)

    _ARRAYS = ("weights", "mx", "my", "gain", "chol")

    def to_arrays(self) -> tuple[dict, dict]:
        """``weights`` (k,), ``mx`` (k, d), ``my`` (k, n_out), ``gain`` (k, n_out, d),
        ``chol`` (k, d, d); ``n_components``, ``seed``, ``n_features`` (d)."""
        if not hasattr(self, "gain_"):
            raise NotFittedError("GMMRegressor is not fitted yet: call fit() first")
        return ({name: getattr(self, name + "_") for name in self._ARRAYS},
                {"n_components": self.n_components, "seed": self.seed, "n_features": self.d_})

    @classmethod
    def from_arrays(cls, arrays, params: dict) -> "GMMRegressor":
        """The fitted regression of :meth:`to_arrays`."""
        g = ArrayGroup.of(arrays)
        reg = cls(params["n_components"], params["seed"])
        reg.d_ = d = int(params["n_features"])
        reg.weights_ = g.take("weights", (None,), kinds="f")
        k = len(reg.weights_)
        reg.mx_ = g.take("mx", (k, d), kinds="f")
        reg.my_ = g.take("my", (k, None), kinds="f")
        reg.gain_ = g.take("gain", (k, reg.my_.shape[1], d), kinds="f")
        reg.chol_ = g.take("chol", (k, d, d), kinds="f")
        return reg


def ridge_to_arrays(model: Ridge) -> tuple[dict, dict]:
    """A fitted scikit-learn ``Ridge`` as data: ``coef`` (n_out, n_in), ``intercept``
    (n_out,); ``alpha``."""
    if not hasattr(model, "coef_"):
        raise NotFittedError("Ridge is not fitted yet: call fit() first")
    return ({"coef": model.coef_, "intercept": np.asarray(model.intercept_)},
            {"alpha": float(model.alpha)})


def ridge_from_arrays(arrays, params: dict) -> Ridge:
    """The fitted ``Ridge`` of :func:`ridge_to_arrays` (its fitted attributes set back)."""
    g = ArrayGroup.of(arrays)
    model = Ridge(alpha=params["alpha"])
    model.coef_ = g.take("coef", (None, None), kinds="f")
    model.intercept_ = g.take("intercept", model.coef_.shape[:1], kinds="f")
    model.n_features_in_ = model.coef_.shape[1]
    return model


class Baseline:
    """One regressor per expression from context-stacked, normalised audio features to MUPs.

    Parameters (stored as given, checked in ``fit``)
    ----------
    kind : str
        One of :data:`BASELINES`.
    context_back, context_forward : int
        Audio context of the frame models (``mlp_large`` uses ±5 and ``tdnn`` its own delays).
    cmvn, cmvn_warmup_frames :
        Causal cepstral normalisation of the features (:class:`~mapping.features.ContextFeatures`).
    train : TrainSettings
        Optimisation of the networks.
    random_state : int
    """

    def __init__(self, kind: str, *, context_back: int = 3, context_forward: int = 3,
                 cmvn: str = "none", cmvn_warmup_frames: int = 30,
                 train: TrainSettings = TrainSettings(), random_state: int = 0):
        self.kind = kind
        self.context_back = context_back
        self.context_forward = context_forward
        self.cmvn = cmvn
        self.cmvn_warmup_frames = cmvn_warmup_frames
        self.train = train
        self.random_state = random_state

    @property
    def name(self) -> str:
        return self.kind

    @property
    def reference(self) -> str:
        return REFERENCES.get(self.kind, f"unknown baseline {self.kind!r}")

    @property
    def sequence(self) -> bool:
        return self.kind in ("tdnn", "gru")

    def _context(self):
        if self.kind == "mlp_large":
            return 5, 5
        if self.kind == "tdnn":
            return 0, 0  # the network's own time delays give the context (±4 frames)
        return self.context_back, self.context_forward

    def _make(self, n_in, n_out, seed):
        if self.kind == "vq":
            return VQRegressor(64, seed)
        if self.kind == "linear":
            return Ridge(alpha=1.0)
        if self.kind == "gmm_regression":
            return GMMRegressor(8, seed)
        if self.kind == "mlp_large":
            return NetRegressor(MLP(n_in, 600, n_out), self.train, seed)
        if self.kind == "tdnn":
            return NetRegressor(TDNN(n_in, 48, n_out, layers=2, width=2), self.train, seed)
        return NetRegressor(GRUNet(n_in, 64, n_out), self.train, seed)

    def fit(self, data: list, masks: list) -> "Baseline":
        if self.kind not in BASELINES:
            raise ParameterError(f"unknown baseline {self.kind!r}; allowed: {', '.join(BASELINES)}")
        check_context(self.context_back, self.context_forward)
        check_cmvn(self.cmvn, self.cmvn_warmup_frames)
        check_seed(self.random_state)
        self.context_ = ContextFeatures(*self._context(), self.cmvn,
                                        self.cmvn_warmup_frames).fit([d.features for d in data],
                                                                     masks)
        self.models_, frame_nets = {}, []
        for j, e in enumerate(sorted({d.expression for d in data})):
            idx = [i for i, d in enumerate(data) if d.expression == e and masks[i].any()]
            if not idx:
                continue
            xs = [self.context_.transform(data[i].features) for i in idx]
            ys = [data[i].mups for i in idx]
            model = self._make(xs[0].shape[1], ys[0].shape[1], self.random_state + 1009 * j)
            if self.sequence:
                X, Y, M = _pad(xs, ys, [masks[i] for i in idx])
                model.fit(X, Y, M)
            else:
                x = np.concatenate([x[masks[i]] for x, i in zip(xs, idx)])
                y = np.concatenate([y[masks[i]] for y, i in zip(ys, idx)])
                if isinstance(model, NetRegressor):  # trained below, every expression at once
                    frame_nets.append((model, x, y))
                else:
                    model.fit(x, y)
            self.models_[e] = model
        if frame_nets:
            fit_many(*map(list, zip(*frame_nets)))
        return self

    def predict(self, features: np.ndarray, expression: str = "neutral") -> np.ndarray:
        if not hasattr(self, "models_"):
            raise NotFittedError(f"baseline {self.kind} is not trained yet: call fit() first")
        if expression not in self.models_:
            raise ParameterError(f"expression {expression!r} was not trained; allowed: "
                                 f"{', '.join(sorted(self.models_))}")
        X = self.context_.transform(features)
        if self.sequence:
            return np.asarray(self.models_[expression].predict(X[None])[0], dtype=np.float32)
        return self.predict_stacked(X, expression)

    def predict_stacked(self, X: np.ndarray, expression: str = "neutral") -> np.ndarray:
        """MUPs from normalised, context-stacked frames, each on its own (frame models only)."""
        if self.sequence:
            raise ParameterError(f"baseline {self.kind} is a sequence model: it estimates whole "
                                 "utterances, not single frames")
        if expression not in self.models_:
            raise ParameterError(f"expression {expression!r} was not trained; allowed: "
                                 f"{', '.join(sorted(self.models_))}")
        return np.asarray(self.models_[expression].predict(X), dtype=np.float32)

    # -- persistence (see mapping.state) -----------------------------------------------------
    def to_arrays(self) -> tuple[dict, dict]:
        """The trained baseline as data: ``context/`` (the
        :class:`~mapping.features.ContextFeatures`) and ``models/<expression>/`` (that
        expression's regressor: :class:`VQRegressor`, ``Ridge``, :class:`GMMRegressor` or a
        :class:`~mapping.nets.NetRegressor`); parameters: the constructor's, ``context``,
        ``expressions`` in training order and their regressors' parameters (``models``)."""
        if not hasattr(self, "models_"):
            raise NotFittedError(f"baseline {self.kind} is not trained yet: call fit() first")
        arrays, context = self.context_.to_arrays()
        arrays = nest("context", arrays)
        models = []
        for e, model in self.models_.items():
            a, p = ridge_to_arrays(model) if self.kind == "linear" else model.to_arrays()
            arrays.update(nest(f"models/{part_name(e)}", a))
            models.append(p)
        params = {"kind": self.kind, "context_back": self.context_back,
                  "context_forward": self.context_forward, "cmvn": self.cmvn,
                  "cmvn_warmup_frames": int(self.cmvn_warmup_frames),
                  "train": settings_to_params(self.train), "random_state": self.random_state,
                  "context": context, "expressions": list(self.models_), "models": models}
        return arrays, params

    @classmethod
    def from_arrays(cls, arrays, params: dict) -> "Baseline":
        """The trained baseline of :meth:`to_arrays`."""
        g = ArrayGroup.of(arrays)
        kind = params["kind"]
        if kind not in BASELINES:
            raise ParameterError(f"unknown baseline {kind!r}; allowed: {', '.join(BASELINES)}")
        b = cls(kind, context_back=params["context_back"],
                context_forward=params["context_forward"], cmvn=params.get("cmvn", "none"),
                cmvn_warmup_frames=params.get("cmvn_warmup_frames", 30),
                train=settings_from_params(params["train"]), random_state=params["random_state"])
        check_context(b.context_back, b.context_forward)
        check_seed(b.random_state)
        b.context_ = ContextFeatures.from_arrays(g.group("context"), params["context"])
        if (b.context_.back, b.context_.forward) != b._context():
            raise ParameterError(f"baseline {kind}: context window ({b.context_.back}, "
                                 f"{b.context_.forward}), expected {b._context()}")
        if (b.context_.cmvn, b.context_.cmvn_warmup_frames) != (b.cmvn, b.cmvn_warmup_frames):
            raise ParameterError(f"baseline {kind}: the features' CMVN ({b.context_.cmvn}, "
                                 f"{b.context_.cmvn_warmup_frames}) differs from the "
                                 f"hyper-parameters ({b.cmvn}, {b.cmvn_warmup_frames})")
        expressions, models = params["expressions"], params["models"]
        if len(expressions) != len(models):
            raise ParameterError(f"{len(expressions)} expressions but {len(models)} models")
        b.models_ = {}
        for e, p in zip(expressions, models):
            part = g.group("models").group(e)
            if kind == "vq":
                b.models_[e] = VQRegressor.from_arrays(part, p)
            elif kind == "linear":
                b.models_[e] = ridge_from_arrays(part, p)
            elif kind == "gmm_regression":
                b.models_[e] = GMMRegressor.from_arrays(part, p)
            else:
                if p.get("module") != NETWORK_OF[kind]:
                    raise ParameterError(f"baseline {kind} uses a {NETWORK_OF[kind]} network, "
                                         f"got {p.get('module')!r}")
                b.models_[e] = NetRegressor.from_arrays(part, p)
        return b


def _pad(xs, ys, masks):
    """Pad utterances to one length: (n_utt, T, ·) arrays and the mask of real training frames."""
    T = max(len(x) for x in xs)
    X = np.zeros((len(xs), T, xs[0].shape[1]), np.float32)
    Y = np.zeros((len(xs), T, ys[0].shape[1]), np.float32)
    M = np.zeros((len(xs), T), bool)
    for i, (x, y, m) in enumerate(zip(xs, ys, masks)):
        X[i, :len(x)], Y[i, :len(y)], M[i, :len(m)] = x, y, m
        X[i, len(x):] = x[-1]  # edge padding keeps the convolution's right edge sensible
    return X, Y, M
