"""The audio-to-MUP mapping (paper §VI): MFCC features and context, the phone-class gate, the MLP
bank with the expression cascade, and the baselines of the related work.

Every mapping method has one interface: ``fit(data, masks)`` on a list of
:class:`~mapping.dataset.UttData` with per-utterance training-frame masks, and
``predict(features, expression)`` from one utterance's raw features to its MUPs (n_frames, A0+Ak).
"""
from mapping.baselines import BASELINES, Baseline
from mapping.dataset import SPLITS, UttData, build_dataset, split_masks
from mapping.features import (MFCC_SETTINGS, ContextFeatures, FeatureNormalizer, audio_features,
                              mfcc, stack_context)
from mapping.gated import GatedMLP

METHODS = ("gated_mlp", *BASELINES)


def make_mapper(method: str, mcfg, *, n_utterance: int = 7, seed: int = 0):
    """A fresh, untrained mapping method by name (one of :data:`METHODS`)."""
    from face_model.errors import ParameterError

    if method == "gated_mlp":
        return GatedMLP(mcfg, n_utterance=n_utterance, seed=seed)
    if method in BASELINES:
        return Baseline(method, mcfg, seed=seed)
    raise ParameterError(f"unknown mapping method {method!r}; allowed: {', '.join(METHODS)}")


__all__ = ["BASELINES", "METHODS", "MFCC_SETTINGS", "SPLITS", "Baseline", "ContextFeatures",
           "FeatureNormalizer", "GatedMLP", "UttData", "audio_features", "build_dataset",
           "make_mapper", "mfcc", "split_masks", "stack_context"]
