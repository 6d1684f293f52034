"""The audio-visual training database of the mapping (paper §VI-A, §VII-A) and its splits.

One :class:`UttData` per utterance: raw audio features per frame, the true MUPs of the same
frames (the tracked MUP sequence of the paper), and the phone class of each frame (the gate's
labels). Splits give, per utterance, a boolean mask of its training frames:

* ``random_frames`` — the paper's split: ``train_fraction`` of all frames drawn at random, so
  neighbouring frames of one sentence fall on both sides;
* ``utterance`` — by sentence: ``train_fraction`` of the distinct sentence texts are training
  sentences, and every utterance of a sentence (in every expression and by every speaker) is on
  the side of its sentence, so no sentence is on both sides.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from face_model.alignment import corpus_deformations
from face_model.errors import ParameterError
from mapping.features import audio_features

SPLITS = ("random_frames", "utterance")


@dataclass
class UttData:
    """One utterance of the database; arrays are frame-major and of one length."""

    utt_id: str
    speaker: str
    expression: str
    text: str
    features: np.ndarray = field(repr=False)  # (n_frames, n_features) raw MFCC (+ deltas)
    mups: np.ndarray = field(repr=False)  # (n_frames, A0 + Ak) true MUPs
    phones: np.ndarray = field(repr=False)  # (n_frames,) phone-class indices

    def __post_init__(self):
        n = len(self.features)
        if len(self.mups) != n or len(self.phones) != n:
            raise ParameterError(
                f"utterance {self.utt_id}: features ({n} frames), MUPs ({len(self.mups)} frames) "
                f"and phone labels ({len(self.phones)} frames) must have the same length")
        if not np.all(np.isfinite(self.features)):
            raise ParameterError(f"utterance {self.utt_id}: features hold NaN or inf values")
        if not np.all(np.isfinite(self.mups)):
            raise ParameterError(f"utterance {self.utt_id}: MUPs hold NaN or inf values")

    @property
    def n_frames(self) -> int:
        return len(self.features)


def build_dataset(corpus, units, *, n_mfcc: int = 10, deltas: bool = False,
                  alignment: str | None = None) -> list[UttData]:
    """Features, true MUPs and phone labels of every utterance of ``corpus``.

    The MUPs are the Motion Units' projection of the aligned deformations (the alignment model
    recorded in the units' metadata unless given).
    """
    alignment = alignment or units.metadata_.get("alignment", "similarity")
    defs = corpus_deformations(corpus, model=alignment)
    out = []
    for u in corpus.utterances:
        feats = audio_features(u.audio, sr=u.sample_rate, fps=u.fps, n_mfcc=n_mfcc,
                               deltas=deltas, n_frames=u.n_frames)
        out.append(UttData(u.utt_id, u.speaker, u.expression, u.text, feats,
                           units.transform(defs[u.utt_id], u.expression).astype(np.float32),
                           u.phone_per_frame()))
    return out


def split_masks(data: list[UttData], split: str, *, train_fraction: float = 0.8,
                seed: int = 0) -> list[np.ndarray]:
    """Per utterance, the boolean mask of its training frames (the rest are test frames)."""
    if split not in SPLITS:
        raise ParameterError(f"unknown split {split!r}; allowed: {', '.join(SPLITS)}")
    if not 0 < train_fraction < 1:
        raise ParameterError(f"train_fraction must be in (0, 1), got {train_fraction}")
    rng = np.random.default_rng(seed)
    lengths = [d.n_frames for d in data]
    if split == "random_frames":
        total = sum(lengths)
        n_train = int(round(train_fraction * total))
        if not 0 < n_train < total:
            raise ParameterError(f"{total} frames cannot be split {train_fraction:.0%} / rest")
        flat = np.zeros(total, bool)
        flat[rng.permutation(total)[:n_train]] = True
        return np.split(flat, np.cumsum(lengths)[:-1])
    texts = sorted({d.text for d in data})
    n_train = int(round(train_fraction * len(texts)))
    if not 0 < n_train < len(texts):
        raise ParameterError(f"{len(texts)} distinct sentences cannot be split "
                             f"{train_fraction:.0%} / rest by sentence; need at least 2 on each "
                             "side's scale (use more sentences or the random_frames split)")
    train_texts = set(np.array(texts)[rng.permutation(len(texts))[:n_train]])
    return [np.full(d.n_frames, d.text in train_texts) for d in data]
