"""Alignment by the three glasses markers and facial deformations (paper §IV-A).

The glasses are rigid with the head, so mapping each frame's glasses markers onto a reference
removes the global head motion. ``similarity`` (rotation, isotropic scale, translation — the
global motion T_β of the paper's Eq. 5) is solved in least squares (Umeyama, 1991) and is robust
to marker noise; ``affine`` is determined exactly by the three points, as in the paper's
description, but amplifies noise on the short vertical side of the glasses triangle.

Deformations are aligned positions minus the speaker's neutral face, flattened x/y-interleaved to
158 values per frame.
"""
from __future__ import annotations

import numpy as np

from face_model.layout import GLASSES, N_MARKERS, default_layout
from groundwork.errors import ParameterError

ALIGNMENTS = ("similarity", "affine")


def _check_markers(markers: np.ndarray, name: str = "markers") -> np.ndarray:
    m = np.asarray(markers, dtype=np.float64)
    if m.ndim != 3 or m.shape[1:] != (N_MARKERS, 2):
        raise ParameterError(f"{name} must have shape (n_frames, {N_MARKERS}, 2), got {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ParameterError(f"{name} hold NaN or inf values")
    return m


def similarity_params(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares similarity mapping point sets ``src`` → ``dst``, frame by frame (the
    Umeyama solution, in closed form for 2D).

    Parameters
    ----------
    src, dst : ndarray, shape (n_frames, k, 2)
        Corresponding points, pixels; k >= 2.

    Returns
    -------
    A : ndarray, shape (n_frames, 2, 2)
        Scale · rotation.
    t : ndarray, shape (n_frames, 2)
        Translation, pixels; ``dst ≈ src @ A.T + t``.
    """
    mu_s = src.mean(1, keepdims=True)
    mu_d = dst.mean(1, keepdims=True)
    s, d = src - mu_s, dst - mu_d
    # Closed form for 2D: with complex numbers z' = a z, a = Σ conj(s) d / Σ |s|².
    zs = s[..., 0] + 1j * s[..., 1]
    zd = d[..., 0] + 1j * d[..., 1]
    a = (np.conj(zs) * zd).sum(1) / (np.abs(zs) ** 2).sum(1)
    A = np.stack([np.stack([a.real, -a.imag], -1), np.stack([a.imag, a.real], -1)], -2)
    t = mu_d[:, 0] - np.einsum("nij,nj->ni", A, mu_s[:, 0])
    return A, t


def affine_params(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares (exact for three points) affine map ``src`` → ``dst``, frame by frame.

    Parameters
    ----------
    src, dst : ndarray, shape (n_frames, k, 2)
        Corresponding points, pixels; k >= 3, not collinear.

    Returns
    -------
    A : ndarray, shape (n_frames, 2, 2)
        The linear part.
    t : ndarray, shape (n_frames, 2)
        Translation, pixels; ``dst ≈ src @ A.T + t``.
    """
    n, k, _ = src.shape
    X = np.concatenate([src, np.ones((n, k, 1))], axis=2)  # (n, k, 3)
    sol = np.linalg.solve(np.einsum("nki,nkj->nij", X, X), np.einsum("nki,nkj->nij", X, dst))
    return sol[:, :2, :].transpose(0, 2, 1), sol[:, 2, :]


def align_markers(markers: np.ndarray, *, reference: np.ndarray | None = None,
                  model: str = "similarity") -> np.ndarray:
    """Map every frame so that its glasses markers best match ``reference`` (paper §IV-A:
    the glasses are rigid with the head, so this removes the global head motion).

    Parameters
    ----------
    markers : ndarray, shape (n_frames, 79, 2)
        Marker positions, pixels.
    reference : ndarray, shape (3, 2), optional
        Target glasses positions, pixels; default: the canonical layout's.
    model : {"similarity", "affine"}
        Least-squares similarity, or the affine map the three points determine (see the
        module text).

    Returns
    -------
    ndarray, shape (n_frames, 79, 2)
        Aligned positions, pixels, float64.

    Raises
    ------
    ParameterError
        Markers of another shape or not finite, an unknown ``model``, a ``reference`` not
        (3, 2).
    """
    m = _check_markers(markers)
    if model not in ALIGNMENTS:
        raise ParameterError(f"alignment model {model!r}; allowed: {', '.join(ALIGNMENTS)}")
    ref = default_layout().neutral[list(GLASSES)] if reference is None else np.asarray(reference)
    if ref.shape != (3, 2):
        raise ParameterError(f"reference glasses must have shape (3, 2), got {ref.shape}")
    src = m[:, list(GLASSES)]
    dst = np.broadcast_to(ref, src.shape)
    A, t = (similarity_params if model == "similarity" else affine_params)(src, dst)
    return np.einsum("nij,nmj->nmi", A, m) + t[:, None, :]


def flatten(points: np.ndarray) -> np.ndarray:
    """(n_frames, 79, 2) → (n_frames, 158), x/y interleaved."""
    return np.asarray(points).reshape(len(points), -1)


def unflatten(vectors: np.ndarray) -> np.ndarray:
    """(n_frames, 158) → (n_frames, 79, 2)."""
    return np.asarray(vectors).reshape(len(vectors), N_MARKERS, 2)


def speaker_neutrals(corpus, *, model: str = "similarity") -> dict[str, np.ndarray]:
    """Each speaker's neutral face: the median over its neutral utterances of the aligned
    first frame (the paper's tracker likewise assumes a neutral, frontal first frame, §V).

    Parameters
    ----------
    corpus : Corpus
        A loaded corpus (:func:`face_model.corpus.load_corpus`).
    model : {"similarity", "affine"}
        The alignment (:func:`align_markers`).

    Returns
    -------
    dict of str to ndarray
        Speaker → neutral face, shape (79, 2), pixels in the aligned frame.

    Raises
    ------
    ParameterError
        A speaker has no neutral utterance.
    """
    firsts: dict[str, list] = {}
    for u in corpus.utterances:
        if u.expression == "neutral":
            firsts.setdefault(u.speaker, []).append(u.markers[:1])
    missing = {u.speaker for u in corpus.utterances} - set(firsts)
    if missing:
        raise ParameterError(f"speakers {sorted(missing)} have no neutral utterance; a neutral "
                             "face cannot be estimated")
    return {spk: np.median(align_markers(np.concatenate(f), model=model), axis=0)
            for spk, f in firsts.items()}


def corpus_deformations(corpus, *, model: str = "similarity",
                        neutrals: dict | None = None) -> dict[str, np.ndarray]:
    """The deformations the Motion Units are learned from (paper §IV-A): aligned positions
    minus the speaker's neutral face.

    Parameters
    ----------
    corpus : Corpus
        A loaded corpus.
    model : {"similarity", "affine"}
        The alignment (:func:`align_markers`).
    neutrals : dict of str to ndarray, optional
        Speaker → neutral face (79, 2); default :func:`speaker_neutrals` of ``corpus``.

    Returns
    -------
    dict of str to ndarray
        Utterance id → deformations, shape (n_frames, 158), pixels, x/y interleaved.
    """
    neutrals = neutrals if neutrals is not None else speaker_neutrals(corpus, model=model)
    return {u.utt_id: flatten(align_markers(u.markers, model=model) - neutrals[u.speaker][None])
            for u in corpus.utterances}
