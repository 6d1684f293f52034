"""The config tree: paper defaults, YAML mirror, overrides and their errors; every section's
checks of its own values; YAML 1.2 numbers and unreadable config files."""
import dataclasses
import math
import re
from pathlib import Path

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from groundwork.errors import ParameterError
from groundwork.settings import Interval, SettingError, rule_of
from talkingface.config import (Config, apply_overrides, flatten, load_config, parse_set,
                                parse_yaml, to_dict)

REPO = Path(__file__).resolve().parents[2]


def test_defaults_are_the_papers_values():
    cfg = Config()
    assert (cfg.units.n_utterance, cfg.units.n_expression) == (7, 2)  # §IV-A: A0 = 7, A_k = 2
    assert cfg.synth.n_sentences == 100  # §VII-A: 100 sentences
    assert cfg.synth.expressions == ("neutral", "smile", "sad")


def test_paper_yaml_mirrors_the_defaults():
    tree = yaml.safe_load((REPO / "configs" / "paper.yaml").read_text())
    assert tree == to_dict(Config())
    assert load_config(REPO / "configs" / "paper.yaml") == Config()


def test_set_overrides_parse_yaml_scalars():
    cfg = load_config(None, ["synth.speakers=3", "seed=7", "synth.marker_noise_px=0.5",
                             "units.alignment=affine", "mlflow.enabled=false"])
    assert cfg.synth.speakers == 3 and cfg.seed == 7
    assert cfg.synth.marker_noise_px == 0.5 and cfg.units.alignment == "affine"
    assert cfg.mlflow.enabled is False
    # untouched values keep the defaults
    assert cfg.synth.n_sentences == Config().synth.n_sentences


@pytest.mark.parametrize("assignment, message", [
    ("synth.no_such_key=1", r"unknown config key synth\.no_such_key; allowed in synth: .*speakers"),
    ("nosection.key=1", r"unknown config section 'nosection'; allowed: seed, corpus, real_speaker, synth"),
    ("synth.speakers=two", r"synth\.speakers must be an integer, got 'two'"),
    ("synth.speakers", r"--set expects section\.key=value, got 'synth\.speakers'"),
    ("synth.speakers.x=1", r"synth\.speakers must be an integer, got \{'x': 1\}"),
    ("mapping.train.bogus=1", r"unknown config key mapping\.train\.bogus; allowed in "
                              r"mapping\.train: validation_fraction, max_epochs"),
    ("tracker.init=magic", r"tracker\.init is 'magic'; allowed: image, corners, markers"),
    ("mapping..x=1", r"must be 'key', 'section\.key' or 'section\.sub\.key'"),
])
def test_bad_overrides_are_refused(assignment, message):
    with pytest.raises(ParameterError, match=message):
        load_config(None, [assignment])


def test_nested_training_settings_are_set_like_any_key():
    cfg = load_config(None, ["mapping.train.max_epochs=5", "mapping.train.learning_rate=0.1"])
    assert (cfg.mapping.train.max_epochs, cfg.mapping.train.learning_rate) == (5, 0.1)
    assert cfg.mapping.train.patience == Config().mapping.train.patience
    assert flatten(cfg)["mapping.train.max_epochs"] == 5


def test_each_package_owns_its_section():
    from data_synth.config import SynthConfig
    from face_model.config import TrackerConfig, UnitsConfig
    from mapping.config import MappingConfig, TrainSettings
    from study.config import StudyConfig

    cfg = Config()
    assert (type(cfg.synth), type(cfg.units), type(cfg.tracker), type(cfg.mapping),
            type(cfg.mapping.train), type(cfg.study)) == (SynthConfig, UnitsConfig, TrackerConfig,
                                                          MappingConfig, TrainSettings, StudyConfig)


def test_unknown_key_in_a_yaml_file_is_refused(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("synth:\n  speekers: 2\n")
    with pytest.raises(ParameterError, match=r"unknown config key synth\.speekers"):
        load_config(p)
    with pytest.raises(ParameterError, match=r"config file .*missing\.yaml not found"):
        load_config(tmp_path / "missing.yaml")


def test_round_trip_through_yaml_and_flatten():
    cfg = apply_overrides(Config(), parse_set(["synth.expressions=[neutral, sad]"]))
    assert cfg.synth.expressions == ("neutral", "sad")
    again = apply_overrides(Config(), yaml.safe_load(yaml.safe_dump(to_dict(cfg))))
    assert again == cfg
    flat = flatten(cfg)
    assert flat["synth.expressions"] == ["neutral", "sad"] and flat["seed"] == cfg.seed


# -- every section checks its own values ------------------------------------------------------
# (assignment as typed, the value as the message shows it): one or more per section and rule
BAD_VALUES = [
    ("seed=-1", "-1"),
    ("seed=4294967296", "4294967296"),
    ("synth.n_sentences=-1", "-1"),
    ("synth.expressions=[neutral, angry]", "['neutral', 'angry']"),
    ("synth.expressions=[]", "[]"),
    ("synth.expressions=[sad, sad]", "['sad', 'sad']"),
    ("synth.expressions=[[neutral]]", "[['neutral']]"),
    ("synth.speakers=0", "0"),
    ("synth.backend=festival", "'festival'"),  # festival voices come through synth.voices
    ("synth.workers=-2", "-2"),
    ("synth.rate_wpm=-100", "-100"),
    ("synth.rate_wpm=0", "0"),
    ("synth.pitch=101", "101"),
    ("synth.pitch_range=-1", "-1"),
    ("synth.lead_silence_s=-0.1", "-0.1"),
    ("synth.trail_silence_s=.inf", "inf"),
    ("synth.audio_noise_dbfs=3", "3.0"),
    ("synth.audio_noise_dbfs=-.inf", "-inf"),
    ("synth.smile_pitch_delta=150", "150"),
    ("synth.sad_rate_delta=-165", "-165"),
    ("synth.smile_rate_delta=-200", "-200"),
    ("synth.theta_anticipation=0", "0.0"),
    ("synth.theta_carryover=-25", "-25.0"),
    ("synth.dominance_power=.nan", "nan"),
    ("synth.jaw_px=-10", "-10.0"),
    ("synth.brow_px=.inf", "inf"),
    ("synth.expression_onset_s=[0.5, 0.25]", "[0.5, 0.25]"),
    ("synth.expression_onset_s=[0, 0.5]", "[0, 0.5]"),
    ("synth.expression_offset_s=[0.3]", "[0.3]"),
    ("synth.expression_offset_s=[0.3, .nan]", "[0.3, nan]"),
    ("synth.expression_intensity=[-0.1, 1.0]", "[-0.1, 1.0]"),
    ("synth.smile_rounding_damping=1.5", "1.5"),
    ("synth.smile_widening=-0.3", "-0.3"),
    ("synth.sad_jaw_reduction=-0.01", "-0.01"),
    ("synth.speaker_scale_sd=-0.04", "-0.04"),
    ("synth.speaker_rate_sd=.nan", "nan"),
    ("synth.head_rotation_deg=-2", "-2.0"),
    ("synth.head_scale=-0.02", "-0.02"),
    ("synth.head_translation_px=.inf", "inf"),
    ("synth.marker_noise_px=-0.15", "-0.15"),
    ("synth.marker_noise_px=.nan", "nan"),
    ("units.n_utterance=0", "0"),
    ("units.n_expression=159", "159"),
    ("units.alignment=rigid", "'rigid'"),
    ("tracker.n_utterances=0", "0"),
    ("tracker.noise_levels=[]", "[]"),
    ("tracker.noise_levels=[0, -10]", "[0, -10]"),
    ("tracker.noise_levels=[0, .nan]", "[0, nan]"),
    ("tracker.init=nose", "'nose'"),
    ("tracker.corpus_noise_sd=-1", "-1.0"),
    ("tracker.workers=-1", "-1"),
    ("mapping.method=svm", "'svm'"),
    ("mapping.baselines=[vq, svm]", "['vq', 'svm']"),
    ("mapping.baselines=[gru, gru]", "['gru', 'gru']"),
    ("mapping.splits=[]", "[]"),
    ("mapping.splits=[by_speaker]", "['by_speaker']"),
    ("mapping.train_fraction=1", "1.0"),
    ("mapping.train_fraction=0", "0.0"),
    ("mapping.n_mfcc=0", "0"),
    ("mapping.n_mfcc=26", "26"),
    ("mapping.context_back=-1", "-1"),
    ("mapping.context_forward=-3", "-3"),
    ("mapping.n_classes=7", "7"),
    ("mapping.gate_components=0", "0"),
    ("mapping.gate_covariance=diagonal", "'diagonal'"),
    ("mapping.min_class_frames=0", "0"),
    ("mapping.hidden_min=0", "0"),
    ("mapping.hidden_min=30", "30"),
    ("mapping.hidden_max=10", "10"),
    ("mapping.expression_model=mixture", "'mixture'"),
    ("mapping.cascade_hidden=0", "0"),
    ("mapping.visual_source=video", "'video'"),
    ("mapping.train.validation_fraction=0", "0.0"),
    ("mapping.train.validation_fraction=1.5", "1.5"),
    ("mapping.train.max_epochs=0", "0"),
    ("mapping.train.patience=0", "0"),
    ("mapping.train.learning_rate=0", "0.0"),
    ("mapping.train.learning_rate=-1e-3", "-0.001"),
    ("mapping.train.learning_rate=.nan", "nan"),
    ("mapping.train.weight_decay=-1e-4", "-0.0001"),
    ("mapping.train.batch_size=-1", "-1"),
    ("mapping.cmvn=median", "'median'"),
    ("mapping.vtlp_range=[1.1, 0.9]", "[1.1, 0.9]"),
    ("mapping.augment.copies=-1", "-1"),
    ("mapping.augment.noise_prob=2", "2.0"),
    ("study.n_participants=1", "1"),
    ("study.keys=[n, h, s]", "['n', 'h', 's']"),
    ("study.keys=[n, n, s, u]", "['n', 'n', 's', 'u']"),
    ("study.keys=[n, h, s, space]", "['n', 'h', 's', 'space']"),
    ("study.keys=[N, h, s, u]", "['N', 'h', 's', 'u']"),
    ("study.keys=[[n], h, s, u]", "[['n'], 'h', 's', 'u']"),
    ("study.fixation_s=-0.5", "-0.5"),
    ("study.iti_s=11", "11.0"),
    ("study.iti_s=.nan", "nan"),
    ("study.audio_backend=pulse", "'pulse'"),
    ("ablations.workers=-1", "-1"),
    ("voices.workers=-1", "-1"),
    ("ceiling.workers=-2", "-2"),
    ("ablations.seeds=0", "0"),
    ("ceiling.seeds=101", "101"),
    ("real_steps.seeds=0", "0"),
    ("real_steps.workers=-1", "-1"),
    ("front_end.corpora=[run, others]", "['run', 'others']"),
    ("front_end.copies=-1", "-1"),
    ("front_end.voices=[nope:x]", "'nope:x'"),
    ("front_end.train.lookahead_ms=150", "150"),
    ("front_end.train.lookahead_ms=15", "15"),
    ("front_end.train.hidden=0", "0"),
    ("mapping.front_model=x.npz", "'x.npz'"),
    ("targets.stream_latency_p99_ms=0", "0.0"),
    ("cluster.scheduler=dask", "'dask'"),
    ("cluster.scheduler=tcp://host", "'tcp://host'"),
    ("cluster.scheduler=http://host:8786", "'http://host:8786'"),
    ("cluster.scheduler=tcp://host:0", "'tcp://host:0'"),
    ("cluster.scheduler=tcp://host:65536", "'tcp://host:65536'"),
    ("cluster.scheduler=tcp://a host:8786", "'tcp://a host:8786'"),
    ("seed=2147483000", "2147483000"),  # its third replicate's seed would pass 2**31 - 1
    ('corpus.source=" my corpus"', "' my corpus'"),
    ('corpus.source="a\\nb"', "'a\\nb'"),
    ('real_speaker.corpus=" grid"', "' grid'"),
    ('real_faces.dev_corpus=" grid-s26"', "' grid-s26'"),
    ("synth.articulation=grid-s99", "'grid-s99'"),
    ("targets.viseme_accuracy=1.5", "1.5"),
    ("targets.frame_cost_p99_ms=0", "0.0"),
    ("speech_set.per_speaker=-1", "-1"),
]


@pytest.mark.parametrize("assignment, shown", BAD_VALUES)
def test_each_bad_value_is_refused_with_its_key_and_value(assignment, shown):
    key = assignment.split("=", 1)[0]
    with pytest.raises(ParameterError) as info:
        load_config(None, [assignment])
    assert str(info.value).startswith(f"{key} is {shown}; allowed: "), str(info.value)


def test_a_given_corpus_has_no_tracked_copy():
    """A given corpus's markers were found in its own video; the tracked corpus draws them as
    the synthetic marker face, so the two are refused together, in either order."""
    for order in (["corpus.source=c", "mapping.visual_source=tracked"],
                  ["mapping.visual_source=tracked", "corpus.source=c"]):
        with pytest.raises(ParameterError, match=r"^mapping\.visual_source is 'tracked'; "
                                                 r"allowed: markers when corpus\.source"):
            load_config(None, order)
    assert load_config(None, ["corpus.source=c"]).corpus.source == "c"


def test_every_section_has_a_bad_value_in_the_table():
    tested = {a.split("=")[0].rsplit(".", 1)[0] for a, _ in BAD_VALUES if "." in a}
    nested = {f"{section}.{f.name}" for section in ("mapping", "front_end")
              for f in dataclasses.fields(getattr(Config(), section))
              if dataclasses.is_dataclass(getattr(getattr(Config(), section), f.name))}
    ruled = {f.name for f in dataclasses.fields(Config()) if f.name not in ("seed", "mlflow")}
    assert tested == ruled | nested


@pytest.mark.parametrize("assignment, message", [
    ("synth.rate_wpm=-100", "synth.rate_wpm is -100; allowed: an integer > 0"),
    ("synth.marker_noise_px=-1", "synth.marker_noise_px is -1.0; allowed: a finite number in [0, 50]"),
    ("mapping.train_fraction=1", "mapping.train_fraction is 1.0; allowed: a finite number in "
                                 "(0, 1)"),
    ("mapping.hidden_min=30", "mapping.hidden_min is 30; allowed: at most mapping.hidden_max "
                              "(25)"),
    ("mapping.hidden_max=10", "mapping.hidden_max is 10; allowed: at least mapping.hidden_min "
                              "(15)"),
    ("synth.sad_rate_delta=-200", "synth.sad_rate_delta is -200; allowed: an integer > "
                                  "-synth.rate_wpm (-165)"),
    ("synth.expression_onset_s=[0.5, 0.25]",
     "synth.expression_onset_s is [0.5, 0.25]; allowed: two finite numbers [lo, hi] with "
     "lo <= hi, each > 0"),
    ("synth.expressions=[neutral, angry]", "synth.expressions is ['neutral', 'angry']; allowed: "
                                           "a non-empty list of distinct values from neutral, "
                                           "smile, sad"),
    ("mapping.n_classes=7", "mapping.n_classes is 7; allowed: 44, 8, 1"),
    ("study.keys=[n, n, s, u]", "study.keys is ['n', 'n', 's', 'u']; allowed: 4 distinct keys, "
                                "each one lower-case letter or digit"),
    ("mapping.train.patience=0", "mapping.train.patience is 0; allowed: an integer >= 1"),
])
def test_the_message_says_what_is_allowed(assignment, message):
    with pytest.raises(ParameterError, match=f"^{re.escape(message)}$"):
        load_config(None, [assignment])


def test_values_are_checked_however_the_config_is_made():
    """Construction and dataclasses.replace check too (the key is then the field's name)."""
    from data_synth.config import SynthConfig
    from mapping.config import MappingConfig, TrainSettings

    with pytest.raises(SettingError, match=r"^rate_wpm is -1; allowed: an integer > 0$"):
        SynthConfig(rate_wpm=-1)
    with pytest.raises(SettingError, match=r"^learning_rate is nan"):
        dataclasses.replace(TrainSettings(), learning_rate=math.nan)
    with pytest.raises(SettingError, match=r"^speakers is True"):  # a bool is not an integer
        SynthConfig(speakers=True)
    with pytest.raises(SettingError, match=r"^hidden_max is 10; allowed: at least hidden_min"):
        MappingConfig(hidden_max=10)
    # both bounds moved together (as an ablation grid entry does) are accepted
    assert MappingConfig(hidden_min=40, hidden_max=60).hidden_min == 40


def test_paired_settings_change_together():
    cfg = load_config(None, ["mapping.hidden_min=40", "mapping.hidden_max=60",
                             "synth.rate_wpm=20", "synth.sad_rate_delta=-19"])
    assert (cfg.mapping.hidden_min, cfg.mapping.hidden_max) == (40, 60)
    assert cfg.synth.rate_wpm + cfg.synth.sad_rate_delta == 1


def test_a_bad_value_in_a_file_names_the_file_and_the_key(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("synth:\n  rate_wpm: -100\n")
    with pytest.raises(ParameterError, match=rf"^config file {re.escape(str(p))}: "
                                             r"synth\.rate_wpm is -100; allowed: an integer > 0$"):
        load_config(p)


def test_the_ablation_grid_of_the_project_is_valid():
    from talkingface.stages.grid_files import load_grid

    assert len(load_grid(REPO / "configs" / "ablations.yaml", Config())) > 10


def test_method_and_split_names_are_those_of_the_mapping_package():
    from mapping import MFCC_SETTINGS
    from mapping.config import MAX_MFCC, METHOD_NAMES, SPLIT_NAMES, MappingConfig
    from mapping.dataset import SPLITS
    from mapping.experiment import METHODS
    from mapping.phone_gate import N_CLASS_CHOICES

    assert METHOD_NAMES == METHODS and SPLIT_NAMES == SPLITS
    assert MAX_MFCC == MFCC_SETTINGS["n_mels"] - 1
    n_classes = next(f for f in dataclasses.fields(MappingConfig) if f.name == "n_classes")
    assert sorted(rule_of(n_classes).values) == sorted(N_CLASS_CHOICES)


def test_study_and_synth_names_are_those_of_their_packages():
    from data_synth.backends import BACKENDS
    from data_synth.config import SynthConfig
    from study.config import StudyConfig
    from study.design import RESPONSES
    from study.session import AUDIO_BACKENDS

    study = {f.name: f for f in dataclasses.fields(StudyConfig)}
    assert rule_of(study["audio_backend"]).values == AUDIO_BACKENDS
    assert rule_of(study["keys"]).n == len(RESPONSES)
    synth = {f.name: f for f in dataclasses.fields(SynthConfig)}
    assert set(BACKENDS) <= set(rule_of(synth["backend"]).values)


# -- property tests over every numeric setting -------------------------------------------------
def _interval_settings():
    """``(section path, field name, Interval)`` of every numeric setting of the tree."""
    out = []

    def walk(node, path):
        for f in dataclasses.fields(node):
            value = getattr(node, f.name)
            if dataclasses.is_dataclass(value):
                walk(value, (*path, f.name))
            elif isinstance(rule_of(f), Interval):
                out.append((path, f.name, rule_of(f)))

    walk(Config(), ())
    return out


NUMERIC = _interval_settings()
# settings with a rule between fields, tested on their own above
PAIRED = {"synth.rate_wpm", "synth.smile_rate_delta", "synth.sad_rate_delta",
          "mapping.hidden_min", "mapping.hidden_max"}
SINGLE = [s for s in NUMERIC if ".".join((*s[0], s[1])) not in PAIRED]


def _tree(path, name, value):
    tree = {name: value}
    for part in reversed(path):
        tree = {part: tree}
    return tree


def _inside(rule: Interval):
    if rule.integer:
        lo = -10**9 if rule.lo is None else int(rule.lo) + rule.lo_open
        hi = lo + 10**9 if rule.hi is None else int(rule.hi) - rule.hi_open
        return st.integers(lo, hi)
    return st.floats(rule.lo, rule.hi, exclude_min=rule.lo_open and rule.lo is not None,
                     exclude_max=rule.hi_open and rule.hi is not None, allow_nan=False,
                     allow_infinity=False)


def _outside(rule: Interval):
    options = []
    if rule.integer:
        if rule.lo is not None:
            options.append(st.integers(max_value=int(rule.lo) - (not rule.lo_open)))
        if rule.hi is not None:
            options.append(st.integers(min_value=int(rule.hi) + (not rule.hi_open)))
        return st.one_of(options) if options else st.nothing()
    options.append(st.sampled_from([math.nan, math.inf, -math.inf]))
    if rule.lo is not None:
        options.append(st.floats(max_value=rule.lo, exclude_max=not rule.lo_open,
                                 allow_nan=False, allow_infinity=False))
    if rule.hi is not None:
        options.append(st.floats(min_value=rule.hi, exclude_min=not rule.hi_open,
                                 allow_nan=False, allow_infinity=False))
    return st.one_of(options)


@given(st.data())
def test_any_value_in_range_is_accepted_and_round_trips_through_yaml(data):
    path, name, rule = data.draw(st.sampled_from(SINGLE), label="setting")
    value = data.draw(_inside(rule), label="value")
    cfg = apply_overrides(Config(), _tree(path, name, value))
    node = cfg
    for part in path:
        node = getattr(node, part)
    assert getattr(node, name) == value
    text = yaml.safe_dump(to_dict(cfg), sort_keys=False)
    assert apply_overrides(Config(), parse_yaml(text)) == cfg
    key = ".".join((*path, name))
    assert load_config(None, [f"{key}={value!r}"]) == cfg  # --set reads what repr writes


@given(st.data())
def test_any_value_out_of_range_is_refused_with_its_key(data):
    path, name, rule = data.draw(st.sampled_from(
        [s for s in NUMERIC if not (s[2].integer and s[2].lo is None and s[2].hi is None)]),
        label="setting")
    value = data.draw(_outside(rule), label="value")
    key = ".".join((*path, name))
    with pytest.raises(ParameterError, match=rf"^{re.escape(key)} is {re.escape(repr(value))}; "
                                             r"allowed: "):
        apply_overrides(Config(), _tree(path, name, value))


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_every_float_written_by_repr_or_yaml_is_read_back_as_that_float(x):
    assert parse_yaml(repr(x)) == x and isinstance(parse_yaml(repr(x)), float)
    assert parse_yaml(yaml.safe_dump(x)) == x


@given(st.floats(0.001, 10.0), st.floats(0.0, 10.0))
def test_any_ordered_span_is_accepted_and_a_reversed_one_refused(lo, width):
    hi = lo + width
    cfg = load_config(None, [f"synth.expression_onset_s=[{lo!r}, {hi!r}]"])
    assert cfg.synth.expression_onset_s == (lo, hi)
    if hi > lo:
        with pytest.raises(ParameterError, match=r"^synth\.expression_onset_s is "):
            load_config(None, [f"synth.expression_onset_s=[{hi!r}, {lo!r}]"])


# -- YAML scalars and files --------------------------------------------------------------------
@pytest.mark.parametrize("raw, value", [
    ("1e-3", 0.001), ("1E5", 100000.0), (".5", 0.5), ("-.5", -0.5), ("+1.5e+2", 150.0),
    ("1.0e-3", 0.001), ("2.", 2.0), ("1_000.5", 1000.5), (".inf", math.inf),
    ("10", 10), ("-3", -3), ("0x10", 16), ("1e3x", "1e3x"), ("e5", "e5"), ("1.2.3", "1.2.3"),
])
def test_yaml_numbers_follow_yaml_1_2(raw, value):
    got = parse_set([f"mapping.x={raw}"])["mapping"]["x"]
    assert got == value and type(got) is type(value)


def test_exponent_numbers_set_float_settings(tmp_path):
    cfg = load_config(None, ["mapping.train.learning_rate=1e-3", "mapping.train.weight_decay=0"])
    assert cfg.mapping.train.learning_rate == 0.001 and cfg.mapping.train.weight_decay == 0.0
    p = tmp_path / "c.yaml"
    p.write_text("mapping:\n  train:\n    learning_rate: 5E-4\nsynth:\n  jaw_px: 1e1\n")
    cfg = load_config(p)
    assert cfg.mapping.train.learning_rate == 5e-4 and cfg.synth.jaw_px == 10.0
    # an integer setting given in exponent notation is a float: refused, not truncated
    with pytest.raises(ParameterError, match=r"mapping\.train\.max_epochs must be an integer, "
                                             r"got 1000\.0"):
        load_config(None, ["mapping.train.max_epochs=1e3"])


@pytest.mark.parametrize("content, message", [
    (b"synth:\n  speakers: 2\n  rate_wpm: [1, 2\n",
     r"is not valid YAML: line 4, column 1: expected ',' or ']'"),
    (b"synth:\n  speakers: 2\n rate_wpm: 3\n", r"is not valid YAML: line 3, column \d+: "),
    (b"synth: {speakers: 2\n", r"is not valid YAML: line 2, column 1: "),
    (b"synth:\n  speakers: 2\n  speakers: 3\n",
     r"is not valid YAML: line 3, column 3: key 'speakers' is given twice"),
    (b"\t- synth\n", r"is not valid YAML: line 1, column 1: found character '\\t'"),
    ("synth:\n  speakers: 2\n".encode("utf-16"), r"is UTF-16 text \(it starts with a UTF-16 "
                                                 r"byte-order mark\); save it as UTF-8"),
    ("synth:\n  speakers: 2\n".encode("utf-16-le"), r"is not UTF-8 text \(it holds NUL bytes"),
    ("synth:\n  voice: é\n".encode("latin-1"), r"is not UTF-8 text \(byte 16: b'\\xe9'\)"),
    (b"- synth\n- units\n", r"must be a mapping of sections \(seed, corpus, real_speaker, synth, .*\), got list "
                            r"\['synth', 'units'\]"),
    (b"42\n", r"must be a mapping of sections .*, got int 42"),
    (b"synth: 3\n", r"config section 'synth' must be a mapping, got 3"),
])
def test_a_bad_config_file_gives_one_error_naming_the_file(tmp_path, content, message):
    p = tmp_path / "bad.yaml"
    p.write_bytes(content)
    with pytest.raises(ParameterError, match=re.escape(str(p)) + r".*" + message) as info:
        load_config(p)
    assert "\n" not in str(info.value)


def test_empty_and_utf8_bom_files_are_read(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("")
    assert load_config(p) == Config()
    p.write_bytes("\ufeffsynth:\n  speakers: 2\n".encode("utf-8"))
    assert load_config(p).synth.speakers == 2


def test_a_folder_or_an_unreadable_file_is_refused(tmp_path, monkeypatch):
    with pytest.raises(ParameterError, match=rf"^config file {re.escape(str(tmp_path))} is a "
                                             r"folder, not a file$"):
        load_config(tmp_path)
    p = tmp_path / "locked.yaml"
    p.write_text("seed: 3\n")

    def denied(self):  # as chmod 0 would (chmod does not stop root, who may run the tests)
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(Path, "read_bytes", denied)
    with pytest.raises(ParameterError, match=rf"^config file {re.escape(str(p))} cannot be "
                                             r"read: Permission denied$"):
        load_config(p)


def test_a_set_value_that_is_not_yaml_is_refused():
    with pytest.raises(ParameterError, match=r"^--set 'synth\.expressions=\[neutral': the value "
                                             r"is not valid YAML \(line 1, column 9: "):
        parse_set(["synth.expressions=[neutral"])
