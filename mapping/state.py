"""A fitted estimator as plain data: named numpy arrays and JSON-able parameters.

Every estimator of the mapping has a pair ``to_arrays() -> (arrays, params)`` and
``from_arrays(arrays, params)``: ``arrays`` maps names to numeric ndarrays, ``params`` holds its
hyper-parameters, architecture and other fitted values as JSON types (numbers, strings, lists,
dicts). An estimator that owns others stores their arrays under a prefix (``"context/"`` +
the names of its :class:`~mapping.features.ContextFeatures`) and their parameters under a key.
:mod:`mapping.checkpoint` writes both into one ``.npz`` file; nothing in it is Python code.

On the way back, :class:`ArrayGroup` hands each estimator its own arrays, checks their shape and
kind, and names the full array in a :class:`~groundwork.errors.ParameterError` when one is
missing or does not fit.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from groundwork.errors import ParameterError
from mapping.config import TrainSettings

SEP = "/"
NUMERIC_KINDS = "biuf"  # bool, signed and unsigned integers, floats


def nest(prefix: str, arrays: dict) -> dict:
    """The arrays of a part under ``prefix``: ``{"mean": a}`` → ``{"prefix/mean": a}``."""
    return {f"{prefix}{SEP}{name}": a for name, a in arrays.items()}


def part_name(name) -> str:
    """``name`` (an expression, a class) as one part of an array name: no separator in it."""
    text = str(name)
    if not text or SEP in text:
        raise ParameterError(f"{name!r} cannot name arrays of a saved model: it must be "
                             f"non-empty and hold no {SEP!r}")
    return text


def settings_to_params(settings: TrainSettings) -> dict:
    """A :class:`TrainSettings` as a JSON-able dict."""
    return dataclasses.asdict(settings)


def settings_from_params(params: dict) -> TrainSettings:
    """The :class:`TrainSettings` of :func:`settings_to_params` (unknown fields refused)."""
    known = {f.name for f in dataclasses.fields(TrainSettings)}
    if not isinstance(params, dict) or set(params) - known:
        raise ParameterError(f"training settings must be a record with fields from "
                             f"{sorted(known)}, got {params!r}")
    return TrainSettings(**params)


class ArrayGroup:
    """The arrays of one estimator inside a saved model, names relative to ``prefix``.

    Parameters
    ----------
    arrays : mapping str → ndarray
        Every array of the model, by full name.
    prefix : str
        The full-name prefix of this estimator's arrays (``""`` for the model itself).

    The groups of one model share a record of the arrays read, so :meth:`unused` lists the
    arrays no estimator asked for.
    """

    def __init__(self, arrays, prefix: str = "", _used: set | None = None):
        self._arrays = arrays
        self.prefix = prefix
        self._used = set() if _used is None else _used

    @classmethod
    def of(cls, arrays) -> "ArrayGroup":
        """``arrays`` as a group (a plain dict of arrays, or a group already)."""
        return arrays if isinstance(arrays, ArrayGroup) else cls(dict(arrays))

    def group(self, name) -> "ArrayGroup":
        """The arrays of the part stored under ``name``."""
        return ArrayGroup(self._arrays, f"{self.prefix}{part_name(name)}{SEP}", self._used)

    def take(self, name: str, shape: tuple | None = None, *, dtype=None,
             kinds: str = NUMERIC_KINDS) -> np.ndarray:
        """The array ``name``, checked.

        shape : tuple, optional
            The expected shape; ``None`` entries accept any length on that axis.
        dtype : optional
            The exact dtype expected (e.g. ``np.float32`` for torch weights).
        kinds : str
            Accepted ``dtype.kind`` values (numbers only by default).
        """
        full = self.prefix + name
        if full not in self._arrays:
            raise ParameterError(f"array {full!r} is missing")
        a = self._arrays[full]
        if not isinstance(a, np.ndarray) or a.dtype.kind not in kinds:
            raise ParameterError(f"array {full!r} must hold numbers, got "
                                 f"{getattr(a, 'dtype', type(a))}")
        if dtype is not None and a.dtype != np.dtype(dtype):
            raise ParameterError(f"array {full!r} must be {np.dtype(dtype)}, got {a.dtype}")
        if shape is not None and (a.ndim != len(shape) or any(
                s is not None and s != n for s, n in zip(shape, a.shape))):
            want = "(" + ", ".join("·" if s is None else str(s) for s in shape) + \
                   ("," if len(shape) == 1 else "") + ")"
            raise ParameterError(f"array {full!r} must have shape {want}, got {a.shape}")
        self._used.add(full)
        return a

    def unused(self) -> list[str]:
        """Full names of the arrays no estimator has read."""
        return sorted(set(self._arrays) - self._used)
