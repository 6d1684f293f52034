"""Settings owned by ``face_model``: the Motion Units (``units``) and the MU-constrained
tracker's evaluation (``tracker``). ``talkingface.config`` composes them with the other sections.
"""
from __future__ import annotations

from dataclasses import dataclass

from face_model.settings import choice


@dataclass(frozen=True)
class UnitsConfig:
    """Motion Units (paper §IV-A)."""

    n_utterance: int = 7  # A0
    n_expression: int = 2  # A_k
    alignment: str = choice("similarity", "affine")  # by the three glasses markers


@dataclass(frozen=True)
class TrackerConfig:
    """The MU-constrained tracker's evaluation on rendered marker video (paper §V)."""

    n_utterances: int = 6  # a subset of the corpus, spread over the expressions
    noise_levels: tuple = (0.0, 10.0, 20.0, 40.0)  # image noise sd, grey levels
    # first-frame placement: image (mouth corners found in the image, then refined on the dots) |
    # corners (the true mouth corners, the paper's manual selection) | markers (true markers)
    init: str = choice("image", "corners", "markers")
    # --visual-source tracked: the whole corpus rendered at this image noise and tracked
    corpus_noise_sd: float = 10.0
    workers: int = 0  # processes for tracking the corpus (0: all cores)
