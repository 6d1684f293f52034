"""The run config: the packages' own sections composed into one tree; defaults = the paper's.

Each package owns the dataclass of its settings — ``synth`` (:mod:`data_synth.config`),
``units`` and ``tracker`` (:mod:`face_model.config`), ``mapping`` with its nested ``train``
settings (:mod:`mapping.config`), ``study`` (:mod:`study.config`) — and this module adds the ones
that belong to the pipeline and the command line: ``corpus`` (a given corpus instead of the
synthetic one), ``mlflow`` (where runs are logged), ``ablations`` (the grid
``replicate`` trains as child runs, and its seeds), ``cluster`` (where grid tasks run),
``ceiling`` (the steps toward the ceiling), ``real_steps`` (the trained steps on the real
speaker's training sentences) and ``voices`` (the grid of voice-robust models);
``targets`` (:mod:`analysis.config`) holds the project's targets on real data, stated once, and
``speech_set`` (:mod:`analysis.config`) the part of the real-speech set the evaluation scores.
It composes, loads, validates and dumps them.

``configs/paper.yaml`` mirrors the defaults. A YAML file may set any subset of keys;
``--set section.key=value`` (or ``section.sub.key=value`` for a nested section) overrides single
values, parsed as YAML scalars (with YAML 1.2's numbers: ``1e-3``, ``1E5`` and ``.5`` are floats,
not strings as in PyYAML's YAML 1.1). An unknown section or key is an error naming the key and
what is allowed. Each section checks its own values when it is made (:mod:`groundwork.settings`);
this module prefixes the section, so a refused value reads
``synth.rate_wpm is -100; allowed: an integer > 0``. A config file that cannot be read, is not
UTF-8 YAML, repeats a key or is not a mapping is refused with its name (and line and column).
"""
from __future__ import annotations

import dataclasses
import re
import reprlib
from dataclasses import dataclass, field, fields
from pathlib import Path

import yaml

from analysis.config import SpeechSetConfig, TargetsConfig
from data_synth.config import SynthConfig, VoicesRule, check_voices
from face_model.config import TrackerConfig, UnitsConfig
from groundwork.errors import ParameterError
from groundwork.settings import (SettingError, check_fields, choice, choices_of, integer, subset,
                                 require)
from mapping.config import FrontSettings, MappingConfig
from study.config import StudyConfig
from talkingface.executor import scheduler_address


@dataclass(frozen=True)
class CorpusConfig:
    """The run's corpus (stage ``corpus``): synthesised by :mod:`data_synth` (``source``
    empty, the default), or a given corpus folder in the corpus contract (DESIGN.md, e.g. a
    real speaker's recordings made from video), validated and copied into the run."""

    source: str = ""  # empty: synthesise (synth.*); else a corpus folder (--corpus DIR)

    def __post_init__(self):
        require(self, "source", not self.source or (
            self.source.strip() == self.source and self.source.isprintable()),
            "empty (synthesise the corpus) or the path of a corpus folder, without leading "
            "or trailing spaces or control characters")


@dataclass(frozen=True)
class RealSpeakerConfig:
    """The paper's pipeline on a real speaker (stage ``real_speaker``), beside the synthetic
    corpus's: ``builtin`` (GRID s1, ``face_model/real_faces/grid-s1``), a corpus folder made
    from video (``talkingface corpus from-video``), or empty (off)."""

    corpus: str = "builtin"
    # the corpus's videos (<utt_id>.<ext>), for the side-by-side of two held-out clips:
    # builtin (two held-out GRID s1 clips, face_model/real_faces/grid-s1-video), a folder, or
    # empty (none)
    videos: str = "builtin"

    def __post_init__(self):
        for key in ("corpus", "videos"):
            value = getattr(self, key)
            require(self, key, value.strip() == value and value.isprintable(),
                    "builtin, empty (off) or the path of a folder, without leading or "
                    "trailing spaces or control characters")


@dataclass(frozen=True)
class RealFacesConfig:
    """Real faces of people no model was trained on (stage ``real_faces``): the development
    part the default model's lips are chosen on (``builtin``: GRID s26,
    ``face_model/real_faces/grid-s26``) and the test part reported once (``builtin``: GRID
    s31, beside the real speaker's held-out sentences); each a corpus folder made by
    ``talkingface corpus from-video``, ``builtin`` or empty (off)."""

    dev_corpus: str = "builtin"
    test_corpus: str = "builtin"

    def __post_init__(self):
        for key in ("dev_corpus", "test_corpus"):
            value = getattr(self, key)
            require(self, key, value.strip() == value and value.isprintable(),
                    "builtin, empty (off) or the path of a corpus folder, without leading or "
                    "trailing spaces or control characters")


@dataclass(frozen=True)
class MlflowConfig:
    """Experiment tracking (MLflow). Empty uri: $MLFLOW_TRACKING_URI, else ./mlflow.db."""

    uri: str = ""
    experiment: str = "talkingface"
    enabled: bool = True

    def __post_init__(self):
        require(self, "uri", not self.uri or self.uri == "databricks"
                or re.match(r"[A-Za-z][A-Za-z0-9+.-]*:", self.uri) is not None,
                "empty ($MLFLOW_TRACKING_URI, else ./mlflow.db) or a tracking URI with its "
                "scheme, e.g. sqlite:///mlflow.db, postgresql://host/db, http://host:5000")
        require(self, "experiment", bool(self.experiment.strip()), "a non-empty name")


@dataclass(frozen=True)
class AblationConfig:
    """The ablation grid ``replicate`` trains as MLflow child runs (``talkingface ablate``
    takes its grid on the command line)."""

    grid: str = "default"  # default: configs/ablations.yaml of the project | none | a file
    workers: int = integer(0, ge=0)  # processes (0: all cores)
    # training seeds per setting: replicate k trains with seed + 1000 k (its split, its model's
    # initialisation and batches, its augmentation); the corpus stays the run's. 5 by default:
    # on the default grid the per-seed R differences from the paper's setting have an SD of
    # ~0.005, and the first of Holm's 31 steps needs a mean difference of 14.4 SD with 3 seeds
    # (~0.07 R: nothing short of a broken model separates) but 3.4 SD with 5 (~0.017 R)
    seeds: int = integer(5, ge=1, le=100)

    def __post_init__(self):
        check_fields(self)


@dataclass(frozen=True)
class ClusterConfig:
    """Where the grid stages' tasks run (:mod:`talkingface.executor`)."""

    # local: a Dask LocalCluster on this machine | processes: a process pool (no Dask) |
    # tcp://HOST:PORT: a running Dask scheduler
    scheduler: str = "local"

    def __post_init__(self):
        check_fields(self)
        scheduler_address(self.scheduler)  # refuses anything else, naming what is allowed


@dataclass(frozen=True)
class CeilingConfig:
    """The steps from our Table II toward the ceiling of any audio model on the corpus that
    ``replicate`` measures (stage ``ceiling``: each nuisance off, all off, the oracle)."""

    grid: str = "default"  # default: configs/ceiling.yaml of the project | none | a file
    workers: int = integer(0, ge=0)  # processes (0: all cores)
    seeds: int = integer(3, ge=1, le=100)  # training seeds per step, as ablations.seeds

    def __post_init__(self):
        check_fields(self)


@dataclass(frozen=True)
class RealStepsConfig:
    """Where the real speaker's R goes (stage ``real_steps``): the trained steps, each a child of
    the grid (the gate's GMMs, the recognisers, the oracle's true phones) trained and scored on
    the real speaker's training sentences only, on both splits."""

    grid: str = "default"  # default: configs/real_steps.yaml of the project | none (off) | a file
    workers: int = integer(0, ge=0)  # processes (0: all cores)
    seeds: int = integer(3, ge=1, le=100)  # training seeds per step, as ceiling.seeds

    def __post_init__(self):
        check_fields(self)


@dataclass(frozen=True)
class VoicesConfig:
    """The voice-robust models ``replicate`` trains and scores on real speech (the grid's
    children; its ``model`` is what ``animate``, ``stream`` and the study's synthetic face use)."""

    grid: str = "default"  # default: configs/voices.yaml of the project | none | a file
    workers: int = integer(0, ge=0)  # processes (0: all cores)
    # a child's corpus and the real speaker (real_speaker.corpus): none (the drawn faces only),
    # alone (the real speaker's training sentences instead) or added (beside the drawn faces);
    # a child that asks for the real speaker is left out of a run without one
    real_face: str = choice("none", "alone", "added")

    def __post_init__(self):
        check_fields(self)


# the many-voice corpus the causal front end learns from: the voices of configs/voices.yaml's
# many-voice children (ARCTIC slt left out: a speaker of the evaluation set)
FRONT_VOICES = ("espeak:en-us+m3", "espeak:en-us+f3", "espeak:en+m5", "espeak:en-gb-scotland+f2",
                "espeak:en-029+m7", "flite:kal16", "flite:awb", "flite:rms",
                "festival:kal_diphone", "festival:ked_diphone")
FRONT_CORPORA = ("run", "voices", "real")


@dataclass(frozen=True)
class FrontEndConfig:
    """The causal phone front end the ``front_end`` stage teaches from hama (issue 40;
    :mod:`talkingface.stages.front_end`): its corpora, the voices of its many-voice corpus, the
    augmented copies of every utterance, and its network and training (``train``)."""

    # run: the run's corpus; voices: a many-voice corpus of the run's sentences; real: the real
    # speaker's training sentences without the evaluation set's recordings (it makes the real
    # speaker a seen speaker of every model that reads the front end)
    corpora: tuple = subset(("run", "voices"), FRONT_CORPORA)
    voices: tuple = field(default=FRONT_VOICES, metadata={"rule": VoicesRule()})
    copies: int = integer(1, ge=0)  # augmented copies per utterance (mapping.augment's settings)
    workers: int = integer(0, ge=0)  # processes of the teacher pass (0: all cores)
    train: FrontSettings = field(default_factory=FrontSettings)

    def __post_init__(self):
        check_fields(self)
        check_voices(self.voices)


MAX_SEED = 2**31 - 1  # derived seeds add offsets; scikit-learn takes seeds < 2**32

# The settings that name data outside the run (a folder or a file). Each is read and checked
# before any stage runs, by the key of the stage that reads it (``Stage.inputs`` or
# ``Stage.files``, called by ``talkingface.stages.preflight``), and refused in one line that
# names the setting; a new one belongs here and there (tests/talkingface/
# test_config.py finds the settings whose names say they name data).
DATA_SETTINGS = ("corpus.source", "real_speaker.corpus", "real_speaker.videos",
                 "real_faces.dev_corpus", "real_faces.test_corpus",
                 "synth.text_file", "ablations.grid", "ceiling.grid", "real_steps.grid",
                 "voices.grid")


@dataclass(frozen=True)
class Config:
    seed: int = integer(2002, ge=0, le=MAX_SEED)
    corpus: CorpusConfig = field(default_factory=CorpusConfig)
    real_speaker: RealSpeakerConfig = field(default_factory=RealSpeakerConfig)
    synth: SynthConfig = field(default_factory=SynthConfig)
    units: UnitsConfig = field(default_factory=UnitsConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    study: StudyConfig = field(default_factory=StudyConfig)
    mlflow: MlflowConfig = field(default_factory=MlflowConfig)
    ablations: AblationConfig = field(default_factory=AblationConfig)
    cluster: ClusterConfig = field(default_factory=ClusterConfig)
    front_end: FrontEndConfig = field(default_factory=FrontEndConfig)
    voices: VoicesConfig = field(default_factory=VoicesConfig)
    ceiling: CeilingConfig = field(default_factory=CeilingConfig)
    real_steps: RealStepsConfig = field(default_factory=RealStepsConfig)
    targets: TargetsConfig = field(default_factory=TargetsConfig)
    speech_set: SpeechSetConfig = field(default_factory=SpeechSetConfig)
    real_faces: RealFacesConfig = field(default_factory=RealFacesConfig)

    def __post_init__(self):
        check_fields(self)
        # replicate k of a grid trains with seed + 1000 k (talkingface.stages.grid)
        top = self.seed + 1000 * (max(self.ablations.seeds, self.ceiling.seeds,
                                      self.real_steps.seeds) - 1)
        require(self, "seed", top <= MAX_SEED,
                f"at most {MAX_SEED} - 1000 x (the largest of ablations.seeds, "
                "ceiling.seeds and real_steps.seeds, minus one): its replicates' seeds must "
                f"stay within 0..{MAX_SEED}", ("ablations.seeds", "ceiling.seeds",
                                              "real_steps.seeds"))
        if self.corpus.source and self.mapping.visual_source == "tracked":
            # the tracked corpus draws the synthetic marker face (talkingface.stages.applies)
            raise SettingError("mapping.visual_source", self.mapping.visual_source,
                               "markers when corpus.source names a given corpus (its markers "
                               "were found in its own video; the tracked corpus draws them as "
                               "the synthetic marker face)", ("corpus.source",))


# -- YAML ------------------------------------------------------------------------------------
_FLOAT = "tag:yaml.org,2002:float"
# YAML 1.1's floats, plus YAML 1.2's exponents without a dot (1e-3, 1E5) and signed .5
_FLOAT_RE = re.compile(r"""^(?:[-+]?[0-9][0-9_]*\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                             |[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+
                             |[-+]?\.[0-9][0-9_]*(?:[eE][-+]?[0-9]+)?
                             |[-+]?[0-9][0-9_]*(?::[0-5]?[0-9])+\.[0-9_]*
                             |[-+]?\.(?:inf|Inf|INF)
                             |\.(?:nan|NaN|NAN))$""", re.X)


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader with YAML 1.2 floats, refusing a key given twice in one mapping."""

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=deep)
            try:
                twice = key in seen
            except TypeError:  # an unhashable key: PyYAML's own construct_mapping refuses it
                continue
            if twice:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {key!r} is given twice", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


_Loader.yaml_implicit_resolvers = {
    ch: [(tag, rx) for tag, rx in resolvers if tag != _FLOAT]
    for ch, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}
_Loader.add_implicit_resolver(_FLOAT, _FLOAT_RE, list("-+0123456789."))


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """``line L, column C: problem`` of a PyYAML error (1-based, as editors count)."""
    mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
    problem = getattr(exc, "problem", None) or str(exc)
    context = getattr(exc, "context", None)
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
    return f"{where}{problem}" + (f" ({context})" if context else "")


def parse_yaml(text: str):
    """YAML text as configs are read: YAML 1.2 floats, and no key given twice in a mapping."""
    return yaml.load(text, Loader=_Loader)


def read_yaml(path, what: str = "config file"):
    """The YAML document of the file at ``path`` (None when empty).

    Raises
    ------
    ParameterError
        Naming ``what`` and the file: missing, a folder, unreadable, not UTF-8 text, or not
        valid YAML (with line and column).
    """
    p = Path(path)
    if not p.exists():
        raise ParameterError(f"{what} {p} not found")
    if p.is_dir():
        raise ParameterError(f"{what} {p} is a folder, not a file")
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise ParameterError(f"{what} {p} cannot be read: {exc.strerror or exc}") from None
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise ParameterError(f"{what} {p} is UTF-16 text (it starts with a UTF-16 byte-order "
                             "mark); save it as UTF-8")
    if b"\x00" in data:
        raise ParameterError(f"{what} {p} is not UTF-8 text (it holds NUL bytes: UTF-16 "
                             "without a byte-order mark, or binary); save it as UTF-8")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ParameterError(f"{what} {p} is not UTF-8 text (byte {exc.start}: "
                             f"{data[exc.start:exc.start + 1]!r}); save it as UTF-8") from None
    try:
        return parse_yaml(text)
    except yaml.YAMLError as exc:
        raise ParameterError(f"{what} {p} is not valid YAML: {_yaml_problem(exc)}") from None


# -- composing ------------------------------------------------------------------------------
def _coerce(where: str, f: dataclasses.Field, current, value):
    allowed = choices_of(f)
    if allowed is not None and value not in allowed:
        raise ParameterError(f"{where} is {value!r}; allowed: {', '.join(map(str, allowed))}")
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
    try:
        return dataclasses.replace(node, **changes)
    except SettingError as exc:  # the section checked its values; say which section it is
        raise (exc.within(prefix[:-1]) if prefix else exc) from None


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
        try:
            value = parse_yaml(raw) if raw.strip() else ""
        except yaml.YAMLError as exc:
            raise ParameterError(f"--set {a!r}: the value is not valid YAML "
                                 f"({_yaml_problem(exc)})") from None
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
        tree = read_yaml(path)
        if tree is not None and not isinstance(tree, dict):
            raise ParameterError(f"config file {path} must be a mapping of sections "
                                 f"({', '.join(f.name for f in fields(Config))}), got "
                                 f"{type(tree).__name__} {reprlib.repr(tree)}")
        try:
            cfg = apply_overrides(cfg, tree or {})
        except ParameterError as exc:
            raise ParameterError(f"config file {path}: {exc}") from None
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
