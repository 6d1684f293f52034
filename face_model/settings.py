"""Helpers for the config dataclasses each package owns (``data_synth.config``,
``face_model.config``, ``mapping.config``, ``study.config``).

A config is a frozen dataclass whose defaults are the paper's values. A string setting with a
closed set of values is declared with :func:`choice`; ``talkingface.config`` reads the allowed
values from the field's metadata when it loads a YAML file or a ``--set`` override.
"""
from __future__ import annotations

from dataclasses import Field, field


def choice(default: str, *others: str) -> Field:
    """A string field whose value must be ``default`` or one of ``others``."""
    return field(default=default, metadata={"choices": (default, *others)})


def choices_of(f: Field) -> tuple | None:
    """The allowed values of a field declared with :func:`choice` (None: any value)."""
    return f.metadata.get("choices")
