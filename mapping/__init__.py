"""The audio-to-MUP mapping (paper §VI). Present so far: the MFCC features and context window
(``mapping.features``); the phone-class gate, MLP bank, expression cascade, baselines and the
streaming animator belong to the mapping stage and are not in the package yet."""
from mapping.features import MFCC_SETTINGS, FeatureNormalizer, mfcc, stack_context

__all__ = ["MFCC_SETTINGS", "FeatureNormalizer", "mfcc", "stack_context"]
