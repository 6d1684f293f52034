"""Sentences to read: the built-in set (written for this project) or a user's text file."""
from __future__ import annotations

import unicodedata
from importlib import resources
from pathlib import Path

from groundwork.errors import ParameterError


def builtin_sentences() -> list[str]:
    """The 360 built-in sentences, in file order (the first 100 cover all 44 phone classes)."""
    text = resources.files("data_synth").joinpath("sentences.txt").read_text(encoding="utf-8")
    return [s.strip() for s in text.splitlines() if s.strip()]


def read_sentences(path) -> list[str]:
    """One sentence per non-empty line of a UTF-8 text file; ``#`` starts a comment line."""
    p = Path(path)
    if not p.is_file():
        raise ParameterError(f"--text file {p} not found")
    try:
        lines = p.read_text(encoding="utf-8").splitlines()
    except UnicodeDecodeError as exc:
        raise ParameterError(f"--text file {p} is not UTF-8 text ({exc})") from exc
    out = [ln.strip() for ln in lines if ln.strip() and not ln.lstrip().startswith("#")]
    if not out:
        raise ParameterError(f"--text file {p} holds no sentences")
    return out


def select_sentences(n: int, text_file: str = "") -> list[str]:
    """The first ``n`` sentences of the chosen source (all of them if n <= 0)."""
    pool = read_sentences(text_file) if text_file else builtin_sentences()
    if n > len(pool):
        src = text_file or "the built-in set"
        raise ParameterError(f"synth.n_sentences={n}, but {src} has only {len(pool)} sentences")
    return pool if n <= 0 else pool[:n]


# Typographic characters that NFKD leaves alone, spelled as the ASCII a speech engine reads.
_ASCII_SPELLING = {"\u2018": "'", "\u2019": "'", "\u201a": "'", "\u201b": "'", "\u201c": '"',
                   "\u201d": '"', "\u201e": '"', "\u2013": ", ", "\u2014": ", ", "\u2026": "...",
                   "\u00a0": " ", "\u00df": "ss", "\u00e6": "ae", "\u00c6": "Ae", "\u0153": "oe",
                   "\u0152": "Oe", "\u00f8": "o", "\u00d8": "O", "\u0142": "l", "\u0141": "L",
                   "\u00f0": "d", "\u00d0": "D", "\u00fe": "th", "\u00de": "Th"}


def to_ascii(text: str) -> str:
    """``text`` as plain ASCII for engines that mis-read anything else (flite, festival).

    Accents are dropped (``café`` → ``cafe``, ``naïve`` → ``naive``), typographic quotes and
    dashes become their ASCII forms, control characters become spaces, and any other
    non-ASCII character is removed. ASCII text is returned unchanged.
    """
    if text.isascii() and text.isprintable():
        return text
    spelled = "".join(_ASCII_SPELLING.get(c, c) for c in text)
    out = []
    for c in unicodedata.normalize("NFKD", spelled):
        if unicodedata.combining(c):
            continue
        if c.isascii():
            out.append(c if c.isprintable() else " ")
    return "".join(out)


def is_speakable(text: str) -> bool:
    """Whether ``text`` holds a letter or a digit (festival's diphone voices crash on text
    without either, e.g. ``""`` or ``"..."``)."""
    return any(c.isalnum() for c in text)
