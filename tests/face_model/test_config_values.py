"""The declarative checks of the config dataclasses (groundwork.settings) and face_model's own
sections (units, tracker)."""
import dataclasses
import math
import pickle

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from face_model.config import TrackerConfig, UnitsConfig
from face_model.motion_units import N_DIM
from groundwork.errors import ParameterError
from groundwork.settings import (Interval, SettingError, check_fields, check_order, choice,
                                 distinct_keys, fraction, integer, number, numbers, require,
                                 span, subset)


@dataclasses.dataclass(frozen=True)
class Demo:
    """Every kind of field, with its default."""

    count: int = integer(3, ge=1)
    level: float = number(0.5, ge=0, le=1)
    share: float = fraction(0.2)
    window: tuple = span((0.1, 0.3), gt=0)
    levels: tuple = numbers((0.0, 1.0), ge=0)
    mode: str = choice("a", "b")
    size: int = choice(4, 2)
    names: tuple = subset(("x",), ("x", "y", "z"))
    keys: tuple = distinct_keys(("q", "w"))
    low: int = integer(1)
    high: int = integer(5)

    def __post_init__(self):
        check_fields(self)
        check_order(self, "low", "high")
        require(self, "share", self.share <= self.level, "at most level", ("level",))


def test_the_defaults_pass_their_own_rules():
    Demo(), UnitsConfig(), TrackerConfig()


@pytest.mark.parametrize("changes, message", [
    ({"count": 0}, "count is 0; allowed: an integer >= 1"),
    ({"count": 2.0}, "count is 2.0; allowed: an integer >= 1"),
    ({"count": True}, "count is True; allowed: an integer >= 1"),
    ({"level": 1.5}, "level is 1.5; allowed: a finite number in [0, 1]"),
    ({"level": "0.5"}, "level is '0.5'; allowed: a finite number in [0, 1]"),
    ({"share": 1.0}, "share is 1.0; allowed: a finite number in (0, 1)"),
    ({"window": (0.3, 0.1)}, "window is [0.3, 0.1]; allowed: two finite numbers [lo, hi] with "
                             "lo <= hi, each > 0"),
    ({"window": (0.1, 0.2, 0.3)}, "window is [0.1, 0.2, 0.3]; allowed: two finite numbers"),
    ({"levels": ()}, "levels is []; allowed: a non-empty list of finite numbers >= 0"),
    ({"levels": "01"}, "levels is '01'; allowed: a non-empty list"),
    ({"mode": "c"}, "mode is 'c'; allowed: a, b"),
    ({"size": 3}, "size is 3; allowed: 4, 2"),
    ({"size": "4"}, "size is '4'; allowed: 4, 2"),
    ({"names": ("x", "w")}, "names is ['x', 'w']; allowed: a non-empty list of distinct values "
                            "from x, y, z"),
    ({"names": "x"}, "names is 'x'; allowed: a non-empty list"),
    ({"keys": ("q", "q")}, "keys is ['q', 'q']; allowed: 2 distinct keys, each one lower-case "
                           "letter or digit"),
    ({"keys": ("q", "ww")}, "keys is ['q', 'ww']; allowed: 2 distinct keys"),
    ({"low": 6}, "low is 6; allowed: at most high (5)"),
    ({"high": 0}, "high is 0; allowed: at least low (1)"),
    ({"share": 0.6}, "share is 0.6; allowed: at most level"),
    ({"low": 9, "high": 7}, "high is 7; allowed: at least low (9)"),
])
def test_each_rule_refuses_with_the_key_the_value_and_what_is_allowed(changes, message):
    with pytest.raises(SettingError) as info:
        dataclasses.replace(Demo(), **changes)
    assert str(info.value).startswith(message), str(info.value)
    assert isinstance(info.value, ParameterError)


def test_numpy_numbers_are_numbers():
    d = Demo(count=np.int64(2), level=np.float32(0.25), size=np.int32(2))
    assert d.count == 2 and d.size == 2
    with pytest.raises(SettingError, match=r"^level is np\.float64\(nan\)|^level is nan"):
        Demo(level=np.float64("nan"))


def test_the_section_is_prefixed_to_the_key_and_to_the_fields_it_mentions():
    with pytest.raises(SettingError) as info:
        Demo(low=6)
    err = info.value.within("demo")
    assert str(err) == "demo.low is 6; allowed: at most demo.high (5)"
    assert (err.key, err.value, err.related) == ("demo.low", 6, ("demo.high",))
    assert str(err.within("outer")) == "outer.demo.low is 6; allowed: at most outer.demo.high (5)"


def test_a_mention_inside_a_longer_name_is_left_alone():
    err = SettingError("rate_delta", -200, "an integer > -rate (-165), unlike max_rate",
                       ("rate",))
    assert str(err.within("s")) == ("s.rate_delta is -200; allowed: an integer > -s.rate (-165), "
                                    "unlike max_rate")


def test_setting_errors_survive_pickling():
    """Worker processes send their errors back pickled."""
    err = SettingError("low", 6, "at most high (5)", ("high",)).within("demo")
    again = pickle.loads(pickle.dumps(err))
    assert type(again) is SettingError and str(again) == str(err)
    assert again.related == ("demo.high",)


def test_a_default_that_breaks_its_rule_is_a_programming_error():
    with pytest.raises(AssertionError, match="default -1 breaks its own rule"):
        integer(-1, ge=0)


@given(st.floats(allow_nan=True, allow_infinity=True))
def test_an_interval_accepts_exactly_the_finite_numbers_between_its_bounds(x):
    rule = Interval(lo=0.0, hi=1.0, lo_open=True)
    assert rule.accepts(x) == (math.isfinite(x) and 0.0 < x <= 1.0)


@given(st.integers(), st.integers(), st.integers())
def test_an_integer_interval_accepts_exactly_the_integers_between_its_bounds(lo, hi, x):
    rule = Interval(integer=True, lo=lo, hi=hi)
    assert rule.accepts(x) == (lo <= x <= hi)
    assert not rule.accepts(float(x)) and not rule.accepts(True)


# -- face_model's sections -----------------------------------------------------------------
@pytest.mark.parametrize("cls, changes, key", [
    (UnitsConfig, {"n_utterance": 0}, "n_utterance"),
    (UnitsConfig, {"n_utterance": N_DIM + 1}, "n_utterance"),
    (UnitsConfig, {"n_expression": -2}, "n_expression"),
    (UnitsConfig, {"alignment": "projective"}, "alignment"),
    (TrackerConfig, {"n_utterances": 0}, "n_utterances"),
    (TrackerConfig, {"noise_levels": (10.0, math.inf)}, "noise_levels"),
    (TrackerConfig, {"noise_levels": (-1.0,)}, "noise_levels"),
    (TrackerConfig, {"init": "guess"}, "init"),
    (TrackerConfig, {"corpus_noise_sd": math.nan}, "corpus_noise_sd"),
    (TrackerConfig, {"workers": -1}, "workers"),
])
def test_units_and_tracker_settings_are_checked(cls, changes, key):
    with pytest.raises(SettingError, match=rf"^{key} is "):
        cls(**changes)


@given(st.integers(1, N_DIM), st.integers(1, N_DIM))
def test_any_number_of_motion_units_a_pca_can_give_is_accepted(a0, ak):
    assert UnitsConfig(n_utterance=a0, n_expression=ak).n_utterance == a0


@given(st.lists(st.floats(0, 255), min_size=1, max_size=6))
def test_any_list_of_non_negative_noise_levels_is_accepted(levels):
    assert TrackerConfig(noise_levels=tuple(levels)).noise_levels == tuple(levels)
