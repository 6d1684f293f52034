"""A word's phones and their relative durations as espeak-ng speaks it alone: the in-word timing
the real-speech set's independent labels use inside a word span given by the source (GRID's
word alignment, ``tools/grid_speech_labels.py``; an FSDD file, ``tools/fsdd_speech_labels.py``).

espeak-ng is the project's backend (:mod:`data_synth.espeak`, the default voice of
:class:`data_synth.speech.SynthRequest`). Its silence before and after the word is dropped
(before a word-initial stop it is the stop's closure); a phone espeak names with no duration of
its own (the final /l/ of the letter "l", merged into its vowel) takes the second half of the
phone before it. :func:`scale_into` spreads the phones over a span in proportion.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from data_synth.espeak import EspeakBackend
from data_synth.speech import SynthRequest, phone_segments
from groundwork.errors import ParameterError


def _word_phones(word: str, result, backend) -> list[tuple[str, float]]:
    """``[(phone, seconds)]`` of one word spoken alone, silence handled as the module says."""
    segs = phone_segments(result, backend, text=word, lead_samples=0,
                          total_samples=len(result.audio))
    while segs and segs[0].phone == "sil":
        segs = segs[1:]
    while segs and segs[-1].phone == "sil":
        segs = segs[:-1]
    if not segs or any(s.phone == "sil" for s in segs):
        raise ParameterError(f"espeak-ng spoke {word!r} as {[s.phone for s in segs]}; a word "
                             "needs phones and no pause inside")
    timed = [[s.phone, s.end_s - s.start_s] for s in segs]
    spoken = [p for p in (backend.to_class(ph.mnemonic, text=word) for ph in result.phones)
              if p != "sil"]
    out, k = [], 0
    for phone in spoken:  # the phones espeak names, some without a duration of their own
        if k < len(timed) and timed[k][0] == phone:
            out.append(timed[k])
            k += 1
        elif out:
            out[-1][1] /= 2
            out.append([phone, out[-1][1]])
        else:
            raise ParameterError(f"espeak-ng gave the first phone of {word!r} no duration")
    assert k == len(timed), (word, spoken, timed)
    return [(p, d) for p, d in out]


def word_phones(words, *, workers: int | None = None) -> dict[str, list[tuple[str, float]]]:
    """Each word's espeak-ng phones and durations (s), the word spoken alone, default voice.

    Parameters
    ----------
    words : iterable of str
        Words (duplicates are spoken once).
    workers : int, optional
        espeak-ng processes in parallel (default: up to 8, at most the cores).

    Returns
    -------
    dict
        word → ``[(phone, seconds)]``, phones in the 44 classes, no ``sil``.
    """
    words = sorted(set(words))
    backend = EspeakBackend()
    results = backend.synthesize_many([SynthRequest(text=w) for w in words],
                                      workers=workers or min(8, os.cpu_count() or 1))
    return {w: _word_phones(w, r, backend) for w, r in zip(words, results)}


def scale_into(parts, start_s: float, end_s: float) -> list[tuple[float, float, str]]:
    """``(start_s, end_s, phone)`` of ``parts`` (``[(phone, seconds)]``) spread over
    ``[start_s, end_s]`` in proportion to their durations."""
    cum = np.concatenate([[0.0], np.cumsum([d for _, d in parts])])
    bounds = start_s + (end_s - start_s) * cum / cum[-1]
    return [(bounds[i], bounds[i + 1], p) for i, (p, _) in enumerate(parts)]


def file_differences(set_dir, subdir: str, files: dict) -> list[str]:
    """The files (relative to the set at ``set_dir``) that differ from ``files`` (relative path
    → bytes), and any file in ``subdir`` that ``files`` does not hold."""
    set_dir = Path(set_dir)
    differ = [rel for rel, data in files.items()
              if not (set_dir / rel).is_file() or (set_dir / rel).read_bytes() != data]
    extra = [f"{subdir}/{p.name}" for p in sorted((set_dir / subdir).glob("*"))
             if f"{subdir}/{p.name}" not in files]
    return differ + [f"{rel} (not made by the tool)" for rel in extra]


def write_or_check(set_dir, subdir: str, files: dict, *, check: bool) -> int:
    """A label tool's last step: with ``check``, name every file that differs from ``files``
    (exit status 1 when one does); else write them all. Returns the exit status."""
    set_dir = Path(set_dir)
    if check:
        differ = file_differences(set_dir, subdir, files)
        for rel in differ:
            print(f"{set_dir / rel}: differs from what the tool makes", file=sys.stderr)
        print(f"{len(files)} files checked, {len(differ)} differ")
        return 1 if differ else 0
    (set_dir / subdir).mkdir(exist_ok=True)
    for rel, data in files.items():
        (set_dir / rel).write_bytes(data)
    print(f"{len(files)} files written under {set_dir}")
    return 0
