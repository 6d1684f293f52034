"""Identifiers that become file and folder names (participant ids, stimulus ids, run names).

One rule for all of them: the **whole** value must match the pattern (``re.fullmatch``). With
``re.match`` and a ``$`` anchor, ``"P03\\n"`` passes, because ``$`` also matches before a final
newline; such a value then names a folder ``sub-P03\\n/`` beside ``sub-P03/`` and is written
into every data row. Each package keeps its own pattern and wording beside the identifier it
owns (``study.design``, ``talkingface.paths``) and checks it here.
"""
from __future__ import annotations

import re

from groundwork.errors import ParameterError


def check_identifier(kind: str, value, pattern: str | re.Pattern, allowed_text: str) -> str:
    """``value`` unchanged if it is a ``str`` that ``pattern`` matches in full.

    Parameters
    ----------
    kind : str
        What the value is, for the message (``"participant id"``, ``"run name"``).
    value : object
        The value received.
    pattern : str or re.Pattern
        The allowed values; matched with ``re.fullmatch`` (anchors are not needed, and a
        trailing newline never passes).
    allowed_text : str
        What is allowed, in words, for the message.

    Returns
    -------
    str
        ``value``, unchanged.

    Raises
    ------
    ParameterError
        ``"<kind> <repr(value)> is not allowed: <allowed_text>"``.
    """
    if not isinstance(value, str) or re.fullmatch(pattern, value) is None:
        raise ParameterError(f"{kind} {value!r} is not allowed: {allowed_text}")
    return value
