"""Settings owned by ``face_model``: the Motion Units (``units``) and the MU-constrained
tracker's evaluation (``tracker``). ``talkingface.config`` composes them with the other sections.
Every value is checked when the config is made (:mod:`groundwork.settings`).
"""
from __future__ import annotations

from dataclasses import dataclass

from face_model.motion_units import N_DIM  # values per deformation: the most MUs a PCA gives
from groundwork.settings import check_fields, choice, integer, number, numbers


@dataclass(frozen=True)
class UnitsConfig:
    """Motion Units (paper §IV-A).

    Parameters
    ----------
    n_utterance : int
        A_0, the utterance MUs: principal components of the neutral-speech deformations
        (paper: 7), 1 to 158.
    n_expression : int
        A_k, the MUs of each expression: principal components of its residuals of Eq. 1
        (paper: 2), 1 to 158.
    alignment : {"similarity", "affine"}
        How each frame's head motion is removed by the three glasses markers
        (:mod:`face_model.alignment`).
    """

    n_utterance: int = integer(7, ge=1, le=N_DIM)  # A0
    n_expression: int = integer(2, ge=1, le=N_DIM)  # A_k
    alignment: str = choice("similarity", "affine")  # by the three glasses markers

    def __post_init__(self):
        check_fields(self)


@dataclass(frozen=True)
class TrackerConfig:
    """The MU-constrained tracker's evaluation on rendered marker video (paper §V).

    Parameters
    ----------
    n_utterances : int
        Corpus utterances rendered and tracked for the error curve, spread over the
        expressions.
    noise_levels : tuple of float
        Image sensor noise standard deviations of the curve, grey levels (of 0–255).
    init : {"image", "corners", "markers"}
        First-frame placement: the mouth corners found in the image, then refined on the dots;
        the true mouth corners (the paper's manual selection); or the true markers
        (:func:`face_model.marker_video.first_frame_markers`).
    corpus_noise_sd : float
        Image noise, grey levels, of the whole corpus rendered and tracked for
        ``mapping.visual_source: tracked`` (:func:`face_model.tracked_corpus.track_corpus`).
    workers : int
        Processes tracking the corpus (0: all cores).
    """

    n_utterances: int = integer(6, ge=1)  # a subset of the corpus, spread over the expressions
    noise_levels: tuple = numbers((0.0, 10.0, 20.0, 40.0), ge=0)  # image noise sd, grey levels
    # first-frame placement: image (mouth corners found in the image, then refined on the dots) |
    # corners (the true mouth corners, the paper's manual selection) | markers (true markers)
    init: str = choice("image", "corners", "markers")
    # --visual-source tracked: the whole corpus rendered at this image noise and tracked
    corpus_noise_sd: float = number(10.0, ge=0)
    workers: int = integer(0, ge=0)  # processes for tracking the corpus (0: all cores)

    def __post_init__(self):
        check_fields(self)
