"""The mapping's settings (paper §VI) and its evaluation's (§VII-A), owned by ``mapping``.

``MappingConfig`` is the ``mapping`` section of the run config; the optimisation settings every
network shares are nested in it as ``mapping.train`` (:class:`TrainSettings`).
:func:`mapping.experiment.make_mapper` turns a section into the estimators' explicit
hyper-parameters, so no estimator reads a config object.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from face_model.settings import choice


@dataclass(frozen=True)
class TrainSettings:
    """Optimisation settings shared by every network (Adam, early stopping)."""

    validation_fraction: float = 0.15
    max_epochs: int = 600
    patience: int = 40
    learning_rate: float = 0.01
    weight_decay: float = 1e-4
    batch_size: int = 0  # 0: full batch


@dataclass(frozen=True)
class MappingConfig:
    """The audio-to-MUP mapping (paper §VI) and its evaluation (§VII-A)."""

    method: str = "gated_mlp"  # the mapping trained and logged as the model (or a baseline)
    baselines: tuple = ("vq", "linear", "gmm_regression", "mlp_large", "tdnn", "gru")
    splits: tuple = ("random_frames", "utterance")
    train_fraction: float = 0.8
    # features
    n_mfcc: int = 10
    deltas: bool = False
    context_back: int = 3
    context_forward: int = 3
    # gate: one Gaussian mixture per phone class
    n_classes: int = 44  # 44 phone classes | 8 viseme groups | 1 (a single MLP)
    gate_components: int = 4
    gate_covariance: str = choice("diag", "full", "tied", "spherical")
    min_class_frames: int = 40  # smaller classes merge into their viseme group (mapping.gate)
    # MLP bank: hidden units grow with the subset size, between these bounds
    hidden_min: int = 15
    hidden_max: int = 25
    # expressions: cascade (Υ_k on the bank's estimates) or a bank retrained per expression
    expression_model: str = choice("cascade", "bank")
    cascade_hidden: int = 30
    # the MUPs the mapping learns: from the corpus markers, or from the MU-constrained tracker
    # run on the corpus rendered as marker video (§V: how the paper collected its data)
    visual_source: str = choice("markers", "tracked")
    # optimisation of every network
    train: TrainSettings = field(default_factory=TrainSettings)
