"""The speech-synthesis interface: text in, 16-bit audio and timed phones (44 classes) out.

A backend synthesises a batch of :class:`SynthRequest` and reports each phone with the sample
at which it starts. :func:`phone_segments` turns those events into contiguous
``(start_s, end_s, phone)`` segments in the 44-class set, with the silence padding the corpus adds
around every utterance. The backends (espeak-ng from a wheel, always available; Debian's flite
and festival when installed) live in their own modules and are looked up by name, or by
``"engine:voice"``, in :mod:`data_synth.backends`.
"""
from __future__ import annotations

import subprocess
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from face_model.corpus import PhoneSegment
from face_model.phones import PHONE_INDEX
from groundwork.errors import ParameterError


@dataclass(frozen=True)
class SynthRequest:
    """One utterance to synthesise. Units: words per minute; pitch and range 0–100.

    ``voice`` is an espeak voice (``en-us+m3``); the flite and festival backends speak with the
    voice they were made with and map rate and pitch onto their own controls.
    """

    text: str
    voice: str = "en-us+m3"
    rate_wpm: int = 165
    pitch: int = 45
    pitch_range: int = 50
    word_gap: int = 0


@dataclass(frozen=True)
class RawPhone:
    sample: int  # first sample of the phone in the backend's audio
    mnemonic: str  # the backend's own symbol


@dataclass
class SynthResult:
    audio: np.ndarray  # int16, (n_samples,)
    sample_rate: int
    phones: list  # list[RawPhone], in time order


# The longest a speech program may take per utterance it speaks (a hung program is an error,
# not a wait without end); a query (version, voice list) gets one utterance's time.
PROGRAM_TIMEOUT_S = 120


def run_program(cmd: list, *, what: str, utterances: int = 1, **kwargs):
    """``subprocess.run(cmd)`` (output captured as text, no stdin) bounded in time:
    :data:`PROGRAM_TIMEOUT_S` per utterance; a program that does not finish is killed and is
    one line (``what``: the program, for the message)."""
    timeout = PROGRAM_TIMEOUT_S * max(1, int(utterances))
    try:
        return subprocess.run(cmd, capture_output=True, text=True, stdin=subprocess.DEVNULL,
                              timeout=timeout, **kwargs)
    except subprocess.TimeoutExpired:
        raise ParameterError(f"{what} did not finish within {timeout} s ({utterances} "
                             f"utterance{'s' if utterances != 1 else ''}); it was stopped: "
                             "is the program stuck waiting for a sound device?") from None


class SpeechBackend(ABC):
    """Base class: ``synthesize_many`` must be deterministic for identical requests."""

    name = "base"
    sample_rate = 0
    phone_map: dict = {}

    @abstractmethod
    def synthesize_many(self, requests, *, workers: int, progress=None) -> list[SynthResult]:
        """Synthesise every request (in order); call ``progress(1)`` after each."""

    def version(self) -> str:
        return self.name

    def to_class(self, mnemonic: str, *, text: str) -> str:
        try:
            cls = self.phone_map[mnemonic]
        except KeyError:
            raise ParameterError(
                f"{self.name} produced phone {mnemonic!r} (in {text!r}) that has no mapping to the "
                f"44 classes; known: {' '.join(sorted(self.phone_map))}") from None
        assert cls in PHONE_INDEX, cls
        return cls


def phone_segments(result: SynthResult, backend: SpeechBackend, *, text: str,
                   lead_samples: int, total_samples: int) -> list[PhoneSegment]:
    """Contiguous 44-class segments covering ``[0, total_samples)`` of the padded audio.

    The backend's phone ``i`` runs from its start sample to the next phone's start (the last one
    to the end of the backend's audio); ``lead_samples`` of silence were prepended. Adjacent
    segments of the same class (e.g. two pauses) are merged, and zero-length events dropped.
    """
    sr = result.sample_rate
    n_speech = len(result.audio)
    bounds = []
    for i, ph in enumerate(result.phones):
        start = min(max(ph.sample, 0), n_speech)
        end = result.phones[i + 1].sample if i + 1 < len(result.phones) else n_speech
        end = min(max(end, start), n_speech)
        if end > start:
            bounds.append((start + lead_samples, end + lead_samples,
                           backend.to_class(ph.mnemonic, text=text)))
    segs: list[tuple[int, int, str]] = []
    cursor = 0
    for s, e, p in bounds:
        if s > cursor:
            segs.append((cursor, s, "sil"))
        segs.append((max(s, cursor), e, p))
        cursor = e
    if cursor < total_samples:
        segs.append((cursor, total_samples, "sil"))
    merged: list[list] = []
    for s, e, p in segs:
        if merged and merged[-1][2] == p == "sil":
            merged[-1][1] = e
        elif e > s:
            merged.append([s, e, p])
    return [PhoneSegment(s / sr, e / sr, p) for s, e, p in merged]
