"""The audio-to-MUP mapping (paper §VI): MFCC features and context, the phone-class gate, the MLP
bank with the expression cascade, the baselines of the related work, and their training.

Every mapping method has one interface: ``fit(data, masks)`` on a list of
:class:`~mapping.dataset.UttData` with per-utterance training-frame masks, and
``predict(features, expression)`` from one utterance's raw features to its MUPs (n_frames, A0+Ak).
Methods take explicit hyper-parameters; :func:`~mapping.experiment.make_mapper` builds them from
the ``mapping`` config section (:class:`~mapping.config.MappingConfig`).
"""
from groundwork.lazy import lazy_exports

_EXPORTS = {
    "mapping.baselines": ["BASELINES", "Baseline"],
    "mapping.config": ["AugmentSettings", "MappingConfig", "TrainSettings"],
    "mapping.dataset": ["SPLITS", "UttData", "build_dataset", "split_masks", "training_copies"],
    "mapping.experiment": ["METHODS", "TrainedMethod", "make_mapper", "run_experiment"],
    "mapping.features": ["MFCC_SETTINGS", "ContextFeatures", "FeatureNormalizer",
                         "audio_features", "mfcc", "stack_context"],
    "mapping.gated_mlp": ["GatedMLP"],
    "mapping.normalize": ["CMVN_MODES", "CepstralNormalizer"],
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = ["BASELINES", "CMVN_MODES", "METHODS", "MFCC_SETTINGS", "SPLITS", "AugmentSettings",
           "Baseline", "CepstralNormalizer", "ContextFeatures", "FeatureNormalizer", "GatedMLP",
           "MappingConfig", "TrainSettings", "TrainedMethod", "UttData", "audio_features",
           "build_dataset", "make_mapper", "mfcc", "run_experiment", "split_masks",
           "stack_context", "training_copies"]
