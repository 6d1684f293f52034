"""Causal cepstral mean (and variance) normalisation against speaker and channel (issue 12).

One definition serves the offline path and the streaming animator, so their frames are equal
bit for bit. Per utterance, frame t (0-based) is normalised with running statistics of frames
0 … t, blended with a prior — the training frames' mean μ0 and variance σ0², saved in the model —
that weighs as ``n0 = warmup_frames`` frames:

    m_t = (n0·μ0 + Σ_{s≤t} x_s) / (n0 + t + 1)
    v_t = (n0·(σ0² + μ0²) + Σ_{s≤t} x_s²) / (n0 + t + 1) − m_t²
    mean:     y_t = x_t − m_t
    meanvar:  y_t = (x_t − m_t) / sqrt(max(v_t, floor))

So the first frames lean on the prior (at frame t the prior still holds n0 / (n0 + t + 1) of the
weight: half after n0 frames) and a long utterance converges to its own mean and variance.
Nothing looks ahead: the streaming form adds no latency. The sums are running sums in float64
taken in frame order (``np.cumsum`` continued from the previous sums), so pushing frames one at
a time or all at once gives the same numbers.
"""
from __future__ import annotations

import numpy as np

from groundwork.errors import NotFittedError, ParameterError
from mapping.state import ArrayGroup

CMVN_MODES = ("none", "mean", "meanvar")
VAR_FLOOR = 1e-6  # × the prior variance: a floor for v_t (never reached with n0 >= 1)


def check_cmvn(mode, warmup_frames) -> None:
    """A CMVN mode of :data:`CMVN_MODES` and a warm-up of >= 1 frames."""
    if mode not in CMVN_MODES:
        raise ParameterError(f"cmvn must be one of {', '.join(CMVN_MODES)}, got {mode!r}")
    if isinstance(warmup_frames, bool) or not isinstance(warmup_frames, (int, np.integer)) \
            or warmup_frames < 1:
        raise ParameterError(f"cmvn_warmup_frames must be an integer >= 1, got "
                             f"{warmup_frames!r}")


class CepstralNormalizer:
    """Causal per-utterance CMVN with a prior fitted on training frames (see the module).

    Parameters
    ----------
    mode : {"mean", "meanvar"}
    warmup_frames : int
        n0: the weight of the prior, in frames (30 = 1 s at 30 fps).
    """

    def __init__(self, mode: str = "meanvar", warmup_frames: int = 30):
        self.mode = mode
        self.warmup_frames = warmup_frames

    def fit(self, X: np.ndarray) -> "CepstralNormalizer":
        """Prior mean and variance of the training frames ``X`` (n_frames, n_features)."""
        check_cmvn(self.mode, self.warmup_frames)
        if self.mode == "none":
            raise ParameterError("CepstralNormalizer needs mode 'mean' or 'meanvar'")
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 2 or len(X) < 2 or not np.all(np.isfinite(X)):
            raise ParameterError(f"CMVN needs finite (n_frames >= 2, n_features) training data, "
                                 f"got shape {X.shape}")
        self.prior_mean_ = X.mean(0)
        self.prior_var_ = np.maximum(X.var(0), 1e-12)
        return self._derive()

    def _derive(self) -> "CepstralNormalizer":
        n0 = float(self.warmup_frames)
        self._prior_sum = n0 * self.prior_mean_
        self._prior_sq = n0 * (self.prior_var_ + self.prior_mean_ ** 2)
        self._floor = VAR_FLOOR * self.prior_var_
        return self

    def start(self) -> "CMVNStream":
        """The running state of one new utterance (or stream)."""
        if not hasattr(self, "prior_mean_"):
            raise NotFittedError("CepstralNormalizer is not fitted yet: call fit() first")
        return CMVNStream(self)

    def transform(self, X: np.ndarray) -> np.ndarray:
        """One whole utterance (n_frames, n_features) → normalised float64, frame by frame."""
        return self.start().push(X)

    def to_arrays(self) -> tuple[dict, dict]:
        """``({"mean", "var"}: the prior (n_features,), {"mode", "warmup_frames"})``."""
        if not hasattr(self, "prior_mean_"):
            raise NotFittedError("CepstralNormalizer is not fitted yet: call fit() first")
        return ({"mean": self.prior_mean_, "var": self.prior_var_},
                {"mode": self.mode, "warmup_frames": int(self.warmup_frames)})

    @classmethod
    def from_arrays(cls, arrays, params: dict) -> "CepstralNormalizer":
        """The fitted normaliser of :meth:`to_arrays`."""
        check_cmvn(params.get("mode"), params.get("warmup_frames"))
        g = ArrayGroup.of(arrays)
        norm = cls(params["mode"], params["warmup_frames"])
        norm.prior_mean_ = g.take("mean", (None,))
        norm.prior_var_ = g.take("var", norm.prior_mean_.shape)
        if not (np.all(np.isfinite(norm.prior_mean_)) and np.all(norm.prior_var_ > 0)):
            raise ParameterError("the CMVN prior must be finite with positive variances")
        return norm._derive()


class CMVNStream:
    """Running sums of one utterance; :meth:`push` normalises the next frames in order."""

    def __init__(self, norm: CepstralNormalizer):
        self.norm = norm
        d = len(norm.prior_mean_)
        self._sum = np.zeros(d)
        self._sq = np.zeros(d)
        self.n_frames = 0

    def push(self, X: np.ndarray) -> np.ndarray:
        """The next frames (n, n_features) → normalised (n, n_features) float64."""
        X = np.asarray(X, dtype=np.float64)
        n_feat = len(self._sum)
        if X.ndim != 2 or X.shape[1] != n_feat:
            raise ParameterError(f"features must be (n_frames, {n_feat}), got {X.shape}")
        if len(X) == 0:
            return X.copy()
        # sequential sums continued from the previous ones: the same additions in the same
        # order whatever the block sizes
        s = np.cumsum(np.vstack([self._sum, X]), axis=0)[1:]
        q = np.cumsum(np.vstack([self._sq, X * X]), axis=0)[1:]
        self._sum, self._sq = s[-1].copy(), q[-1].copy()
        t = np.arange(self.n_frames, self.n_frames + len(X), dtype=np.float64)[:, None]
        self.n_frames += len(X)
        norm = self.norm
        w = norm.warmup_frames + t + 1.0
        m = (norm._prior_sum + s) / w
        if norm.mode == "mean":
            return X - m
        v = (norm._prior_sq + q) / w - m * m
        return (X - m) / np.sqrt(np.maximum(v, norm._floor))
