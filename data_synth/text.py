"""Sentences to read: the built-in set (written for this project) or a user's text file."""
from __future__ import annotations

from importlib import resources
from pathlib import Path

from face_model.errors import ParameterError


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
