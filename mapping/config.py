"""The mapping's settings (paper §VI) and its evaluation's (§VII-A), owned by ``mapping``.

``MappingConfig`` is the ``mapping`` section of the run config; the optimisation settings every
network shares are nested in it as ``mapping.train`` (:class:`TrainSettings`).
:func:`mapping.experiment.make_mapper` turns a section into the estimators' explicit
hyper-parameters, so no estimator reads a config object. Every value is checked when the config
is made (:mod:`face_model.settings`).

The names below are those of :data:`mapping.experiment.METHODS`, :data:`mapping.dataset.SPLITS`,
:data:`mapping.gate.N_CLASS_CHOICES` and ``MFCC_SETTINGS["n_mels"] - 1``, written out so loading
a config imports neither torch nor librosa (a test keeps them equal).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from face_model.settings import (check_fields, check_order, choice, fraction, integer, number,
                                 subset)

METHOD_NAMES = ("gated_mlp", "vq", "linear", "gmm_regression", "mlp_large", "tdnn", "gru")
SPLIT_NAMES = ("random_frames", "utterance")
MAX_MFCC = 25  # MFCCs of 26 mel bands


@dataclass(frozen=True)
class TrainSettings:
    """Optimisation settings shared by every network (Adam, early stopping)."""

    validation_fraction: float = fraction(0.15)
    max_epochs: int = integer(600, ge=1)
    patience: int = integer(40, ge=1)  # epochs without a better validation loss
    learning_rate: float = number(0.01, gt=0)
    weight_decay: float = number(1e-4, ge=0)
    batch_size: int = integer(0, ge=0)  # 0: full batch

    def __post_init__(self):
        check_fields(self)


@dataclass(frozen=True)
class MappingConfig:
    """The audio-to-MUP mapping (paper §VI) and its evaluation (§VII-A)."""

    # the mapping trained and logged as the model (or a baseline)
    method: str = choice(*METHOD_NAMES)
    baselines: tuple = subset(METHOD_NAMES[1:], METHOD_NAMES, empty_ok=True)  # every baseline
    splits: tuple = subset(SPLIT_NAMES, SPLIT_NAMES)
    train_fraction: float = fraction(0.8)
    # features
    n_mfcc: int = integer(10, ge=1, le=MAX_MFCC)
    deltas: bool = False
    context_back: int = integer(3, ge=0)
    context_forward: int = integer(3, ge=0)
    # gate: one Gaussian mixture per phone class
    n_classes: int = choice(44, 8, 1)  # 44 phone classes | 8 viseme groups | 1 (a single MLP)
    gate_components: int = integer(4, ge=1)
    gate_covariance: str = choice("diag", "full", "tied", "spherical")
    # smaller classes merge into their viseme group (mapping.gate)
    min_class_frames: int = integer(40, ge=1)
    # MLP bank: hidden units grow with the subset size, between these bounds
    hidden_min: int = integer(15, ge=1)
    hidden_max: int = integer(25, ge=1)
    # expressions: cascade (Υ_k on the bank's estimates) or a bank retrained per expression
    expression_model: str = choice("cascade", "bank")
    cascade_hidden: int = integer(30, ge=1)
    # the MUPs the mapping learns: from the corpus markers, or from the MU-constrained tracker
    # run on the corpus rendered as marker video (§V: how the paper collected its data)
    visual_source: str = choice("markers", "tracked")
    # optimisation of every network
    train: TrainSettings = field(default_factory=TrainSettings)

    def __post_init__(self):
        check_fields(self)
        check_order(self, "hidden_min", "hidden_max")
