"""The run config: the packages' own sections composed into one tree; defaults = the paper's.

Each package owns the dataclass of its settings — ``synth`` (:mod:`data_synth.config`),
``units`` and ``tracker`` (:mod:`face_model.config`), ``mapping`` with its nested ``train``
settings (:mod:`mapping.config`), ``study`` (:mod:`study.config`) — and this module adds the two
that belong to the command line: ``mlflow`` (where runs are logged) and ``ablations`` (the grid
``replicate`` trains as child runs). It composes, loads, validates and dumps them.

``configs/paper.yaml`` mirrors the defaults. A YAML file may set any subset of keys;
``--set section.key=value`` (or ``section.sub.key=value`` for a nested section) overrides single
values, parsed as YAML scalars. An unknown section or key is an error naming the key and what is
allowed; a setting declared with :func:`face_model.settings.choice` must take one of its values.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, fields
from pathlib import Path

import yaml

from data_synth.config import SynthConfig
from face_model.config import TrackerConfig, UnitsConfig
from face_model.errors import ParameterError
from face_model.settings import choices_of
from mapping.config import MappingConfig
from study.config import StudyConfig


@dataclass(frozen=True)
class MlflowConfig:
    """Experiment tracking (MLflow). Empty uri: $MLFLOW_TRACKING_URI, else ./mlflow.db."""

    uri: str = ""
    experiment: str = "talkingface"
    enabled: bool = True


@dataclass(frozen=True)
class AblationConfig:
    """The ablation grid ``replicate`` trains as MLflow child runs (``talkingface ablate``
    takes its grid on the command line)."""

    grid: str = "default"  # default: configs/ablations.yaml of the project | none | a file
    workers: int = 0  # processes (0: all cores)


@dataclass(frozen=True)
class Config:
    seed: int = 2002
    synth: SynthConfig = field(default_factory=SynthConfig)
    units: UnitsConfig = field(default_factory=UnitsConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    study: StudyConfig = field(default_factory=StudyConfig)
    mlflow: MlflowConfig = field(default_factory=MlflowConfig)
    ablations: AblationConfig = field(default_factory=AblationConfig)


def _coerce(where: str, f: dataclasses.Field, current, value):
    allowed = choices_of(f)
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


def _apply(node, tree, prefix: str):
    """``node`` (a config dataclass) with the nested mapping ``tree`` applied."""
    known = {f.name: f for f in fields(node)}
    changes = {}
    for name, value in tree.items():
        where = f"{prefix}{name}"
        if name not in known:
            if not prefix:
                raise ParameterError(f"unknown config section {name!r}; allowed: "
                                     f"{', '.join(known)}")
            raise ParameterError(f"unknown config key {where}; allowed in {prefix[:-1]}: "
                                 f"{', '.join(known)}")
        current = getattr(node, name)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise ParameterError(f"config section {where!r} must be a mapping, got "
                                     f"{value!r}")
            changes[name] = _apply(current, value, f"{where}.")
        else:
            changes[name] = _coerce(where, known[name], current, value)
    return dataclasses.replace(node, **changes)


def apply_overrides(cfg: Config, tree: dict) -> Config:
    """Return ``cfg`` with the nested mapping ``tree`` applied; unknown keys raise."""
    if not isinstance(tree, dict):
        raise ParameterError(f"a config must be a mapping of sections, got {type(tree).__name__}")
    return _apply(cfg, tree, "")


def parse_set(assignments: list[str]) -> dict:
    """``["synth.speakers=2", "seed=7", "mapping.train.max_epochs=5"]`` → nested mapping;
    values are parsed as YAML scalars."""
    tree: dict = {}
    for a in assignments or []:
        if "=" not in a:
            raise ParameterError(f"--set expects section.key=value, got {a!r}")
        key, raw = a.split("=", 1)
        value = yaml.safe_load(raw) if raw.strip() else ""
        parts = key.strip().split(".")
        if not all(parts):
            raise ParameterError(f"--set key {key!r} must be 'key', 'section.key' or "
                                 "'section.sub.key'")
        node = tree
        for i, part in enumerate(parts[:-1]):
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ParameterError(f"--set {a!r}: {'.'.join(parts[:i + 1])} is given both a "
                                     "value and keys")
        node[parts[-1]] = value
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


def _plain(v):
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (tuple, list)):
        return [_plain(x) for x in v]
    return v


def to_dict(cfg) -> dict:
    """Plain nested dict (tuples as lists), for YAML/JSON and MLflow params."""
    return _plain(dataclasses.asdict(cfg))


def dump_config(cfg, path) -> None:
    Path(path).write_text(yaml.safe_dump(to_dict(cfg), sort_keys=False))


def flatten(cfg) -> dict:
    """``{"synth.speakers": 1, "mapping.train.max_epochs": 600, ...}`` for MLflow params."""
    out = {}

    def walk(prefix: str, node: dict) -> None:
        for k, v in node.items():
            if isinstance(v, dict):
                walk(f"{prefix}{k}.", v)
            else:
                out[f"{prefix}{k}"] = v

    walk("", to_dict(cfg))
    return out


def select(tree: dict, key: str):
    """The value at a dotted ``key`` of a config dict (``"synth"``, ``"tracker.init"``)."""
    node = tree
    for part in key.split("."):
        node = node[part]
    return node
