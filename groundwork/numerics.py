"""Linear algebra that gives the same answer on every processor and BLAS thread count.

The project's matrices are small (158 marker coordinates, tens of features), where BLAS threads
buy nothing measurable but cost reproducibility: on AMD EPYC processors, numpy's bundled OpenBLAS
(0.3.30, Haswell kernels) with two threads fails ``gesdd`` ("SVD did not converge") on finite,
well-conditioned matrices that converge with one thread. So:

* every fit that must be reproducible runs inside :func:`one_blas_thread` (a context manager and
  a decorator, via ``threadpoolctl``; it limits numpy's and scipy's OpenBLAS alike), and
* :func:`svd`, :func:`pinv` and :func:`lstsq` fall back to scipy's ``gesvd`` / ``gelsy`` drivers
  when the divide-and-conquer LAPACK call does not converge.

Nothing here reads or sets environment variables: a user's ``OPENBLAS_NUM_THREADS`` still
governs code outside these fits.
"""
from __future__ import annotations

import functools
from contextlib import contextmanager

import numpy as np
import scipy.linalg
from threadpoolctl import ThreadpoolController

_CONTROLLER: ThreadpoolController | None = None


def _controller() -> ThreadpoolController:
    # Built once, after numpy and scipy.linalg are imported, so both OpenBLAS copies are seen;
    # building one costs ~1 ms, entering its limit ~20 µs.
    global _CONTROLLER
    if _CONTROLLER is None:
        _CONTROLLER = ThreadpoolController()
    return _CONTROLLER


@contextmanager
def one_blas_thread():
    """Run the block with every loaded BLAS (numpy's and scipy's OpenBLAS) on one thread."""
    with _controller().limit(limits=1, user_api="blas"):
        yield


def single_threaded(func):
    """Decorator form of :func:`one_blas_thread` (for ``fit`` methods and stage functions)."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with one_blas_thread():
            return func(*args, **kwargs)

    return wrapper


@single_threaded
def svd(a, *, full_matrices: bool = False, compute_uv: bool = True):
    """``numpy.linalg.svd`` on one BLAS thread, with ``gesvd`` when ``gesdd`` does not converge.

    The two drivers agree to rounding (~1e-15 relative), so callers that fix signs get the
    same axes.

    Parameters
    ----------
    a : array_like, shape (M, N)
        The matrix.
    full_matrices : bool
        ``u`` (M, M) and ``vh`` (N, N) instead of the reduced (M, K) and (K, N),
        K = min(M, N).
    compute_uv : bool
        Return ``u`` and ``vh`` too; otherwise the singular values alone.

    Returns
    -------
    u : ndarray, shape (M, K) or (M, M)
    s : ndarray, shape (K,)
        Singular values, descending.
    vh : ndarray, shape (K, N) or (N, N)
        As ``numpy.linalg.svd`` returns them (``s`` alone when not ``compute_uv``).
    """
    a = np.asarray(a)
    try:
        return np.linalg.svd(a, full_matrices=full_matrices, compute_uv=compute_uv)
    except np.linalg.LinAlgError:
        return scipy.linalg.svd(a, full_matrices=full_matrices, compute_uv=compute_uv,
                                lapack_driver="gesvd", check_finite=False)


def pinv(a, *, rtol: float | None = None) -> np.ndarray:
    """Moore–Penrose pseudo-inverse through :func:`svd`.

    Parameters
    ----------
    a : array_like, shape (M, N)
        The matrix (converted to float64).
    rtol : float, optional
        Singular values at or below ``rtol`` times the largest are treated as zero; default
        numpy's ``max(M, N) · eps``.

    Returns
    -------
    ndarray, shape (N, M)
        Computed in ``numpy.linalg.pinv``'s order of operations (zeros for an empty ``a``).
    """
    a = np.asarray(a, dtype=np.float64)
    if a.size == 0:
        return np.zeros(a.shape[::-1])
    u, s, vt = svd(a, full_matrices=False)
    cut = (max(a.shape) * np.finfo(np.float64).eps if rtol is None else rtol) * s.max()
    inv = np.divide(1.0, s, out=np.zeros_like(s), where=s > cut)
    return np.matmul(vt.T, inv[:, None] * u.T)  # numpy.linalg.pinv's order of operations


@single_threaded
def lstsq(a, b) -> np.ndarray:
    """Least-squares solution of ``a x = b`` (``numpy.linalg.lstsq(a, b, rcond=None)[0]``) on
    one BLAS thread, with scipy's QR-based ``gelsy`` when the SVD-based ``gelsd`` fails.

    Parameters
    ----------
    a : array_like, shape (M, N)
        The design matrix.
    b : array_like, shape (M,) or (M, K)
        The right-hand side(s).

    Returns
    -------
    ndarray, shape (N,) or (N, K)
        The minimum-norm least-squares solution.
    """
    try:
        return np.linalg.lstsq(a, b, rcond=None)[0]
    except np.linalg.LinAlgError:
        return scipy.linalg.lstsq(a, b, lapack_driver="gelsy", check_finite=False)[0]
