"""Helpers for the config dataclasses each package owns (``data_synth.config``,
``face_model.config``, ``mapping.config``, ``study.config``).

A config is a frozen dataclass whose defaults are the paper's values. Each field says what it
accepts through the constructor that declares it (:func:`number`, :func:`integer`,
:func:`fraction`, :func:`span`, :func:`numbers`, :func:`choice`, :func:`subset`,
:func:`distinct_keys`), and the dataclass's ``__post_init__`` calls :func:`check_fields` (plus
:func:`check_order` or :func:`require` for rules between fields), so a config is checked however
it is made: by its constructor, ``dataclasses.replace``, a YAML file or ``--set``.

A refused value raises :class:`SettingError` (a :class:`~groundwork.errors.ParameterError`),
``"<key> is <value>; allowed: <what>"``. The dataclass does not know the section it sits in:
``talkingface.config`` prefixes the section with :meth:`SettingError.within`.
"""
from __future__ import annotations

import math
import re
from dataclasses import Field, dataclass, field, fields
from numbers import Integral, Real

from groundwork.errors import ParameterError


class SettingError(ParameterError):
    """A config value outside what its field allows: ``"<key> is <value>; allowed: <allowed>"``.

    Parameters
    ----------
    key : str
        The field's name within its section (``n_utterance``), or ``section.key`` once
        :meth:`within` has prefixed it.
    value : object
        The value refused (a tuple is shown as a list, as YAML writes it).
    allowed : str
        What the field accepts, in words (``"an integer >= 1"``).
    related : tuple of str
        The sibling fields that ``allowed`` mentions, so :meth:`within` can prefix them too.
    """

    def __init__(self, key: str, value, allowed: str, related: tuple = ()):
        self.key, self.value, self.allowed, self.related = key, value, allowed, tuple(related)
        shown = list(value) if isinstance(value, tuple) else value  # as YAML lists are typed
        super().__init__(f"{key} is {shown!r}; allowed: {allowed}")

    def __reduce__(self):  # picklable across worker processes
        return SettingError, (self.key, self.value, self.allowed, self.related)

    def within(self, section: str) -> "SettingError":
        """The same error with its key (and the fields it mentions) as ``section.key``.

        Parameters
        ----------
        section : str
            The config section the dataclass sits in (``units``, ``mapping``).

        Returns
        -------
        SettingError
            A new error; this one is unchanged.
        """
        allowed = self.allowed
        for name in self.related:
            allowed = re.sub(rf"(?<![\w.]){re.escape(name)}\b", f"{section}.{name}", allowed)
        return SettingError(f"{section}.{self.key}", self.value, allowed,
                            tuple(f"{section}.{n}" for n in self.related))


# -- the rules ------------------------------------------------------------------------------
def _is_int(v) -> bool:
    return isinstance(v, Integral) and not isinstance(v, bool)


def _is_real(v) -> bool:
    return isinstance(v, Real) and not isinstance(v, bool) and math.isfinite(v)


def _is_seq(v) -> bool:
    return isinstance(v, (tuple, list))


@dataclass(frozen=True)
class Interval:
    """Finite numbers (or integers) between optional bounds.

    Parameters
    ----------
    integer : bool
        Integers only (never a bool); otherwise any finite real number.
    lo, hi : float or None
        The bounds; None: unbounded on that side.
    lo_open, hi_open : bool
        The bound itself is excluded (``>`` / ``<`` rather than ``>=`` / ``<=``).
    """

    integer: bool = False
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def accepts(self, v) -> bool:
        """Whether ``v`` is of the kind and within the bounds."""
        if not (_is_int(v) if self.integer else _is_real(v)):
            return False
        return ((self.lo is None or (v > self.lo if self.lo_open else v >= self.lo))
                and (self.hi is None or (v < self.hi if self.hi_open else v <= self.hi)))

    @property
    def bounds(self) -> str:
        """``"> 0"``, ``"in [0, 100]"``, … (empty: no bound)."""
        if self.lo is not None and self.hi is not None:
            return (f"in {'(' if self.lo_open else '['}{self.lo}, {self.hi}"
                    f"{')' if self.hi_open else ']'}")
        if self.lo is not None:
            return f"{'>' if self.lo_open else '>='} {self.lo}"
        if self.hi is not None:
            return f"{'<' if self.hi_open else '<='} {self.hi}"
        return ""

    @property
    def allowed(self) -> str:
        """What is accepted, in words (``"an integer >= 1"``), for :class:`SettingError`."""
        kind = "an integer" if self.integer else "a finite number"
        return f"{kind} {self.bounds}".rstrip()


@dataclass(frozen=True)
class Span:
    """Two numbers ``(lo, hi)`` with ``lo <= hi``, each in ``each``."""

    each: Interval

    def accepts(self, v) -> bool:
        return (_is_seq(v) and len(v) == 2 and all(map(self.each.accepts, v))
                and v[0] <= v[1])

    @property
    def allowed(self) -> str:
        each = f", each {self.each.bounds}" if self.each.bounds else ""
        return f"two finite numbers [lo, hi] with lo <= hi{each}"


@dataclass(frozen=True)
class Numbers:
    """A non-empty list of numbers, each in ``each``."""

    each: Interval

    def accepts(self, v) -> bool:
        return _is_seq(v) and len(v) > 0 and all(map(self.each.accepts, v))

    @property
    def allowed(self) -> str:
        return f"a non-empty list of finite numbers {self.each.bounds}".rstrip()


def _same_kind(v, c) -> bool:
    if isinstance(c, bool):
        return isinstance(v, bool)
    if isinstance(c, Integral):
        return _is_int(v)
    return isinstance(v, type(c))


@dataclass(frozen=True)
class OneOf:
    """One of ``values`` (strings, or integers)."""

    values: tuple

    def accepts(self, v) -> bool:
        return any(_same_kind(v, c) and v == c for c in self.values)

    @property
    def allowed(self) -> str:
        return ", ".join(map(str, self.values))


@dataclass(frozen=True)
class Subset:
    """A list of distinct values from ``values`` (at least one unless ``empty_ok``)."""

    values: tuple
    empty_ok: bool = False

    def accepts(self, v) -> bool:
        return (_is_seq(v) and (self.empty_ok or len(v) > 0)
                and all(isinstance(x, str) and x in self.values for x in v)
                and len(set(v)) == len(v))

    @property
    def allowed(self) -> str:
        kind = "a list" if self.empty_ok else "a non-empty list"
        return f"{kind} of distinct values from {', '.join(self.values)}"


@dataclass(frozen=True)
class Keys:
    """``n`` distinct keyboard keys, each one lower-case letter or digit."""

    n: int

    def accepts(self, v) -> bool:
        return (_is_seq(v) and len(v) == self.n
                and all(isinstance(k, str) and re.fullmatch(r"[a-z0-9]", k) for k in v)
                and len(set(v)) == self.n)

    @property
    def allowed(self) -> str:
        return f"{self.n} distinct keys, each one lower-case letter or digit"


# -- field constructors ---------------------------------------------------------------------
def _ruled(default, rule, **metadata) -> Field:
    assert rule.accepts(default), f"default {default!r} breaks its own rule: {rule.allowed}"
    return field(default=default, metadata={"rule": rule, **metadata})


def _interval(integer, gt, ge, lt, le) -> Interval:
    return Interval(integer, lo=ge if gt is None else gt, hi=le if lt is None else lt,
                    lo_open=gt is not None, hi_open=lt is not None)


def number(default: float, *, gt=None, ge=None, lt=None, le=None) -> Field:
    """A dataclass field holding a finite number, with optional bounds.

    Parameters
    ----------
    default : float
        The default value (the paper's, where it gives one); it must obey the bounds.
    gt, ge : float, optional
        Lower bound, excluded (``gt``: >) or included (``ge``: >=); give at most one.
    lt, le : float, optional
        Upper bound, excluded (``lt``: <) or included (``le``: <=); give at most one.

    Returns
    -------
    dataclasses.Field
        A field whose rule :func:`check_fields` applies.
    """
    return _ruled(default, _interval(False, gt, ge, lt, le))


def integer(default: int, *, gt=None, ge=None, lt=None, le=None) -> Field:
    """An integer (not a bool), with optional bounds as for :func:`number`."""
    return _ruled(default, _interval(True, gt, ge, lt, le))


def fraction(default: float) -> Field:
    """A number in the open interval (0, 1)."""
    return number(default, gt=0, lt=1)


def span(default: tuple, *, gt=None, ge=None, lt=None, le=None) -> Field:
    """A ``(lo, hi)`` pair of finite numbers with ``lo <= hi``, each within the bounds."""
    return _ruled(default, Span(_interval(False, gt, ge, lt, le)))


def numbers(default: tuple, *, gt=None, ge=None, lt=None, le=None) -> Field:
    """A non-empty tuple of finite numbers, each within the bounds."""
    return _ruled(default, Numbers(_interval(False, gt, ge, lt, le)))


def choice(default, *others) -> Field:
    """A field whose value must be ``default`` or one of ``others`` (strings or integers)."""
    values = (default, *others)
    return _ruled(default, OneOf(values), choices=values)


def subset(default: tuple, values: tuple, *, empty_ok: bool = False) -> Field:
    """A tuple of distinct members of ``values`` (non-empty unless ``empty_ok``).

    Parameters
    ----------
    default : tuple of str
        The default selection.
    values : tuple of str
        Everything that may be selected.
    empty_ok : bool
        Accept an empty selection.
    """
    return _ruled(default, Subset(tuple(values), empty_ok))


def distinct_keys(default: tuple) -> Field:
    """Distinct keyboard keys, as many as ``default`` has, each a lower-case letter or digit."""
    return _ruled(default, Keys(len(default)))


def choices_of(f: Field) -> tuple | None:
    """The allowed values of a field declared with :func:`choice` (None: any value)."""
    return f.metadata.get("choices")


def rule_of(f: Field):
    """The rule a field was declared with (None: any value)."""
    return f.metadata.get("rule")


# -- checking -------------------------------------------------------------------------------
def check_fields(cfg) -> None:
    """Check every field of a config dataclass against the rule it was declared with.

    Parameters
    ----------
    cfg : dataclass instance
        Called from its ``__post_init__``.

    Raises
    ------
    SettingError
        For the first field (in declaration order) whose rule refuses its value.
    """
    for f in fields(cfg):
        rule, value = rule_of(f), getattr(cfg, f.name)
        if rule is not None and not rule.accepts(value):
            raise SettingError(f.name, value, rule.allowed)


def require(cfg, name: str, ok: bool, allowed: str, related: tuple = ()) -> None:
    """A rule between fields: refuse ``cfg.<name>`` unless ``ok``.

    Parameters
    ----------
    cfg : dataclass instance
        The config being checked.
    name : str
        The field blamed in the message.
    ok : bool
        The rule's verdict, computed by the caller.
    allowed : str
        What is allowed, in words, naming the other fields involved.
    related : tuple of str
        The other fields ``allowed`` names (prefixed by :meth:`SettingError.within`).

    Raises
    ------
    SettingError
        When not ``ok``.
    """
    if not ok:
        raise SettingError(name, getattr(cfg, name), allowed, related)


def check_order(cfg, low: str, high: str) -> None:
    """Refuse ``cfg.<low> > cfg.<high>``, naming the field that differs from its default (the
    one the user most likely set).

    Parameters
    ----------
    cfg : dataclass instance
        The config being checked.
    low, high : str
        Names of two numeric fields that must satisfy ``low <= high``.

    Raises
    ------
    SettingError
        Blaming ``high`` (``"at least <low> (<value>)"``) when it was changed or ``low`` was
        not, else ``low`` (``"at most <high> (<value>)"``).
    """
    lo, hi = getattr(cfg, low), getattr(cfg, high)
    if lo <= hi:
        return
    default = {f.name: f.default for f in fields(cfg)}
    if hi != default[high] or lo == default[low]:
        raise SettingError(high, hi, f"at least {low} ({lo})", (low,))
    raise SettingError(low, lo, f"at most {high} ({hi})", (high,))
