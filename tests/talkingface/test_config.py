"""The config tree: paper defaults, YAML mirror, overrides and their errors."""
from pathlib import Path

import pytest
import yaml

from face_model.errors import ParameterError
from talkingface.config import Config, apply_overrides, flatten, load_config, parse_set, to_dict

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
    ("nosection.key=1", r"unknown config section 'nosection'; allowed: seed, synth"),
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
