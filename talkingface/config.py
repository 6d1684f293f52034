"""One tree of frozen dataclasses; the defaults are the paper's values.

``configs/paper.yaml`` mirrors the defaults. A YAML file may set any subset of keys; ``--set
section.key=value`` overrides single values (parsed as YAML scalars). An unknown section or key is
an error naming the key and what is allowed. The resolved config is written beside every output.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, fields
from pathlib import Path

import yaml

from face_model.errors import ParameterError


@dataclass(frozen=True)
class SynthConfig:
    """The synthetic audio-visual corpus (paper §IV-A, §VII-A). Units: seconds, pixels, wpm."""

    n_sentences: int = 100
    expressions: tuple = ("neutral", "smile", "sad")
    speakers: int = 1
    text_file: str = ""  # empty: the built-in sentences
    backend: str = "espeak"
    workers: int = 0  # 0: all cores
    # speech
    voice: str = "en-us+m3"
    rate_wpm: int = 165
    pitch: int = 45
    pitch_range: int = 50
    lead_silence_s: float = 0.20
    trail_silence_s: float = 0.20
    audio_noise_dbfs: float = -66.0  # a recording-room noise floor
    # expression prosody (added to the speaker's voice)
    smile_pitch_delta: int = 6
    smile_rate_delta: int = 5
    sad_pitch_delta: int = -8
    sad_rate_delta: int = -15
    # coarticulation (Cohen & Massaro 1993)
    theta_anticipation: float = 16.0  # 1/s
    theta_carryover: float = 25.0  # 1/s
    dominance_power: float = 1.0
    # articulation → marker displacement gains, pixels at parameter value 1
    jaw_px: float = 10.0
    aperture_px: float = 6.0
    spread_px: float = 7.0
    protrusion_px: float = 8.0
    upper_raise_px: float = 4.0
    lower_tuck_px: float = 6.0
    brow_px: float = 2.5
    # expressions: envelope and interaction with speech
    expression_onset_s: tuple = (0.25, 0.5)
    expression_offset_s: tuple = (0.3, 0.6)
    expression_intensity: tuple = (0.7, 1.0)
    smile_rounding_damping: float = 0.6
    smile_widening: float = 0.3
    sad_jaw_reduction: float = 0.35
    # speaker variation (standard deviations)
    speaker_scale_sd: float = 0.04
    speaker_shape_sd_px: float = 1.5
    speaker_gain_sd: float = 0.10
    speaker_rate_sd: float = 12.0
    speaker_pitch_sd: float = 8.0
    # nuisances
    head_rotation_deg: float = 2.0
    head_scale: float = 0.02
    head_translation_px: float = 6.0
    marker_noise_px: float = 0.15  # sub-pixel marker localisation


@dataclass(frozen=True)
class UnitsConfig:
    """Motion Units (paper §IV-A)."""

    n_utterance: int = 7  # A0
    n_expression: int = 2  # A_k
    alignment: str = "similarity"  # similarity | affine (by the three glasses markers)


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
    gate_covariance: str = "diag"
    min_class_frames: int = 40  # smaller classes merge into their viseme group (see mapping.classes)
    # MLP bank: hidden units grow with the subset size, between these bounds
    hidden_min: int = 15
    hidden_max: int = 25
    # expressions: cascade (Υ_k on the bank's estimates) or a bank retrained per expression
    expression_model: str = "cascade"
    cascade_hidden: int = 30
    # the MUPs the mapping learns: from the corpus markers, or from the MU-constrained tracker
    # run on the corpus rendered as marker video (§V: how the paper collected its data)
    visual_source: str = "markers"
    # training of every network
    validation_fraction: float = 0.15
    max_epochs: int = 600
    patience: int = 40
    learning_rate: float = 0.01
    weight_decay: float = 1e-4


@dataclass(frozen=True)
class TrackerConfig:
    """The MU-constrained tracker's evaluation on rendered marker video (paper §V)."""

    n_utterances: int = 6  # a subset of the corpus, spread over the expressions
    noise_levels: tuple = (0.0, 10.0, 20.0, 40.0)  # image noise sd, grey levels
    # first-frame placement: image (mouth corners found in the image, then refined on the dots) |
    # corners (the true mouth corners, the paper's manual selection) | markers (true markers)
    init: str = "image"
    # --visual-source tracked: the whole corpus rendered at this image noise and tracked
    corpus_noise_sd: float = 10.0
    workers: int = 0  # processes for tracking the corpus (0: all cores)


@dataclass(frozen=True)
class StudyConfig:
    """The perception study (paper §VII-C); its seed is derived from the run seed."""

    n_participants: int = 20  # slots of the allocation list (two groups of ten)
    keys: tuple = ("n", "h", "s", "u")  # neutral, happy, sad, not sure
    practice: bool = True  # one practice trial (not in the data) before the blocks
    fixation_s: float = 0.5
    iti_s: float = 0.5
    fullscreen: bool = False
    audio_backend: str = "sounddevice"  # sounddevice | ptb | none (no sound: tests only)


@dataclass(frozen=True)
class TrackingConfig:
    """Experiment tracking (MLflow). Empty uri: $MLFLOW_TRACKING_URI, else ./mlflow.db."""

    uri: str = ""
    experiment: str = "talkingface"
    enabled: bool = True


@dataclass(frozen=True)
class Config:
    seed: int = 2002
    synth: SynthConfig = field(default_factory=SynthConfig)
    units: UnitsConfig = field(default_factory=UnitsConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    study: StudyConfig = field(default_factory=StudyConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)


def _section_names(cfg) -> dict:
    return {f.name: f for f in fields(cfg)}


# string settings with a closed set of values (checked when a config is read)
CHOICES = {
    ("units", "alignment"): ("similarity", "affine"),
    ("mapping", "visual_source"): ("markers", "tracked"),
    ("mapping", "expression_model"): ("cascade", "bank"),
    ("mapping", "gate_covariance"): ("diag", "full", "tied", "spherical"),
    ("tracker", "init"): ("image", "corners", "markers"),
    ("study", "audio_backend"): ("sounddevice", "ptb", "none"),
}


def _coerce(section: str, key: str, current, value):
    where = f"{section}.{key}" if section else key
    allowed = CHOICES.get((section, key))
    if allowed is not None and value not in allowed:
        raise ParameterError(f"{where} is {value!r}; allowed: {', '.join(allowed)}")
    if isinstance(current, bool):
        if not isinstance(value, bool):
            raise ParameterError(f"{where} must be true or false, got {value!r}")
        return value
    if isinstance(current, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParameterError(f"{where} must be an integer, got {value!r}")
        return value
    if isinstance(current, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParameterError(f"{where} must be a number, got {value!r}")
        return float(value)
    if isinstance(current, tuple):
        if not isinstance(value, (list, tuple)):
            raise ParameterError(f"{where} must be a list, got {value!r}")
        return tuple(value)
    if isinstance(current, str):
        if value is None:
            return ""
        if not isinstance(value, (str, int, float)):
            raise ParameterError(f"{where} must be a string, got {value!r}")
        return str(value)
    raise ParameterError(f"{where}: cannot set a value of type {type(current).__name__}")


def apply_overrides(cfg: Config, tree: dict) -> Config:
    """Return ``cfg`` with the nested mapping ``tree`` applied; unknown keys raise."""
    if not isinstance(tree, dict):
        raise ParameterError(f"a config must be a mapping of sections, got {type(tree).__name__}")
    top = _section_names(cfg)
    changes = {}
    for name, value in tree.items():
        if name not in top:
            raise ParameterError(f"unknown config section {name!r}; allowed: {', '.join(top)}")
        current = getattr(cfg, name)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise ParameterError(f"config section {name!r} must be a mapping, got {value!r}")
            sub = _section_names(current)
            sub_changes = {}
            for key, v in value.items():
                if key not in sub:
                    raise ParameterError(f"unknown config key {name}.{key}; allowed in {name}: "
                                         f"{', '.join(sub)}")
                sub_changes[key] = _coerce(name, key, getattr(current, key), v)
            changes[name] = dataclasses.replace(current, **sub_changes)
        else:
            changes[name] = _coerce("", name, current, value)
    return dataclasses.replace(cfg, **changes)


def parse_set(assignments: list[str]) -> dict:
    """``["synth.speakers=2", "seed=7"]`` → nested mapping; values are parsed as YAML scalars."""
    tree: dict = {}
    for a in assignments or []:
        if "=" not in a:
            raise ParameterError(f"--set expects section.key=value, got {a!r}")
        key, raw = a.split("=", 1)
        value = yaml.safe_load(raw) if raw.strip() else ""
        parts = key.strip().split(".")
        if len(parts) == 1:
            tree[parts[0]] = value
        elif len(parts) == 2:
            tree.setdefault(parts[0], {})[parts[1]] = value
        else:
            raise ParameterError(f"--set key {key!r} must be 'key' or 'section.key'")
    return tree


def load_config(path=None, overrides: list[str] | None = None) -> Config:
    """Defaults ← YAML file (optional) ← ``--set`` overrides."""
    cfg = Config()
    if path:
        p = Path(path)
        if not p.is_file():
            raise ParameterError(f"config file {p} not found")
        tree = yaml.safe_load(p.read_text()) or {}
        cfg = apply_overrides(cfg, tree)
    return apply_overrides(cfg, parse_set(overrides or []))


def to_dict(cfg) -> dict:
    """Plain nested dict (tuples as lists), for YAML/JSON and MLflow params."""
    def conv(v):
        if isinstance(v, tuple):
            return [conv(x) for x in v]
        return v

    return {k: ({kk: conv(vv) for kk, vv in v.items()} if isinstance(v, dict) else conv(v))
            for k, v in dataclasses.asdict(cfg).items()}


def dump_config(cfg, path) -> None:
    Path(path).write_text(yaml.safe_dump(to_dict(cfg), sort_keys=False))


def flatten(cfg) -> dict:
    """``{"synth.speakers": 1, ...}`` for MLflow params."""
    out = {}
    for k, v in to_dict(cfg).items():
        if isinstance(v, dict):
            out.update({f"{k}.{kk}": vv for kk, vv in v.items()})
        else:
            out[k] = v
    return out
