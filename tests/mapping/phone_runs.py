"""Synthetic mapping data shared by the mapping tests: utterances of phone runs, each phone with
its own feature cluster; true MUPs a known nonlinear function of the current frame's features
(utterance part) plus an expression offset and a share of the utterance part (expression part).
"""
from __future__ import annotations

import numpy as np

from face_model.phones import PHONES
from mapping.dataset import UttData

A0, AK, N_FEAT = 3, 2, 4
SPOKEN = ("iy", "aa", "m", "sil")
OFFSET = {"smile": np.array([1.5, -1.0]), "sad": np.array([-1.2, 0.8])}


def phone_run_data(seed: int = 0, *, n_utt: int, n_seg: int, seg_len: int,
                   expressions=("neutral", "smile")) -> list:
    """``n_utt`` utterances per expression of ``n_seg`` runs of ``seg_len`` frames."""
    rng = np.random.default_rng(seed)
    centres = np.random.default_rng(99).normal(0, 3, (len(SPOKEN), N_FEAT))
    W = np.random.default_rng(98).normal(0, 0.6, (N_FEAT, A0))
    data = []
    for e in expressions:
        for i in range(n_utt):
            k = np.repeat(rng.integers(len(SPOKEN), size=n_seg), seg_len)
            feats = centres[k] + rng.standard_normal((len(k), N_FEAT))
            c0 = np.tanh(feats @ W)
            ck = np.zeros((len(k), AK)) if e == "neutral" else OFFSET[e] + 0.5 * c0[:, :AK]
            data.append(UttData(f"s0_{e}_{i}", "s0", e, f"sentence {i}", feats.astype(np.float32),
                                np.concatenate([c0, ck], 1).astype(np.float32),
                                np.array([PHONES.index(SPOKEN[j]) for j in k])))
    return data
