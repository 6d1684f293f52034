"""The paper's numeric evaluation (§VII-A, Eqs. 6–8) and its published Tables I and II.

Displacements (ground truth and estimate, (n_frames, 158) in pixels) are first divided, value by
value, by the maximum absolute ground-truth displacement of that marker coordinate in the whole
database, so that they lie in [−1, 1]. Then

* R   (Eq. 6) = trace(Cov_dd') / sqrt(trace(Cov_dd) · trace(Cov_d'd'))
* ν   (Eq. 7) = mean over the γ = 158 dimensions of the standard deviation, for d and for d'
* MSE (Eq. 8) = E[ ||d − d'||² / γ ]

Covariances are population covariances (divided by n), as the paper's expectations.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from groundwork.errors import ParameterError

# Hong, Wen & Huang (2002), Tables I (training set) and II (testing set).
PAPER_TABLES = {
    "train": {"neutral": (0.980, 0.197, 0.179, 0.0025), "smile": (0.972, 0.205, 0.192, 0.0031),
              "sad": (0.977, 0.209, 0.197, 0.0033)},
    "test": {"neutral": (0.968, 0.196, 0.184, 0.0029), "smile": (0.945, 0.208, 0.202, 0.0034),
             "sad": (0.942, 0.213, 0.208, 0.0037)},
}
METRIC_NAMES = ("R", "nu_d", "nu_d_est", "MSE")


@dataclass(frozen=True)
class PaperMetrics:
    """R (Eq. 6), ν of the ground truth and of the estimate (Eq. 7), and MSE (Eq. 8)."""

    R: float
    nu_d: float
    nu_d_est: float
    MSE: float

    def as_dict(self) -> dict:
        return asdict(self)


def _pair(d, d_est) -> tuple[np.ndarray, np.ndarray]:
    d = np.asarray(d, dtype=np.float64)
    e = np.asarray(d_est, dtype=np.float64)
    if d.ndim != 2 or d.shape != e.shape:
        raise ParameterError(f"ground truth and estimate must be 2-D arrays of one shape "
                             f"(n_frames, n_dims), got {d.shape} and {e.shape}")
    if len(d) < 2:
        raise ParameterError(f"need at least 2 frames to compute covariances, got {len(d)}")
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(e))):
        raise ParameterError("ground truth or estimate holds NaN or inf values")
    return d, e


def normalization_scale(displacements: np.ndarray) -> np.ndarray:
    """Per-dimension maximum absolute displacement over a database, shape (n_dims,).

    Dimensions that never move get scale 1 (they stay 0 after normalisation).
    """
    d = np.asarray(displacements, dtype=np.float64)
    if d.ndim != 2:
        raise ParameterError(f"displacements must be (n_frames, n_dims), got {d.shape}")
    scale = np.abs(d).max(axis=0)
    return np.where(scale > 0, scale, 1.0)


def pearson_r(d, d_est) -> float:
    """Eq. 6: the trace form of the Pearson correlation between two multichannel signals."""
    d, e = _pair(d, d_est)
    dc, ec = d - d.mean(0), e - e.mean(0)
    cross = float((dc * ec).sum())
    denom = np.sqrt(float((dc**2).sum()) * float((ec**2).sum()))
    if denom == 0:
        raise ParameterError("R is undefined: the ground truth or the estimate is constant")
    return cross / denom


def average_std(d) -> float:
    """Eq. 7: the mean over dimensions of each dimension's (population) standard deviation."""
    d = np.asarray(d, dtype=np.float64)
    return float(d.std(axis=0).mean())


def mse(d, d_est) -> float:
    """Eq. 8: the mean over frames of the squared error divided by the dimension γ."""
    d, e = _pair(d, d_est)
    return float(((d - e) ** 2).sum(1).mean() / d.shape[1])


def paper_metrics(d, d_est, scale: np.ndarray | None = None) -> PaperMetrics:
    """All four numbers of Tables I–II for one set, after dividing both by ``scale`` (n_dims,)."""
    d, e = _pair(d, d_est)
    if scale is not None:
        scale = np.asarray(scale, dtype=np.float64)
        if scale.shape != (d.shape[1],) or np.any(scale <= 0):
            raise ParameterError(f"scale must be positive with shape ({d.shape[1]},), "
                                 f"got shape {scale.shape}")
        d, e = d / scale, e / scale
    return PaperMetrics(pearson_r(d, e), average_std(d), average_std(e), mse(d, e))
