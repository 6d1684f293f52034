"""The speech-synthesis backends by name: ``espeak`` (always available) and ``flite``.

The backends implement :class:`data_synth.speech.SpeechBackend`; this module sits above them and
above :mod:`data_synth.speech`, so the interface never imports an implementation.
"""
from __future__ import annotations

import shutil

from data_synth.espeak import EspeakBackend
from data_synth.flite import FLITE, FliteBackend
from data_synth.speech import SpeechBackend
from face_model.errors import ParameterError

BACKENDS = ("espeak", "flite")


def get_backend(name: str) -> SpeechBackend:
    """A new backend: ``espeak`` or ``espeak-ng`` (from the ``espeakng-loader`` wheel, always
    available) or ``flite`` (needs Debian's ``flite`` on PATH).

    Raises
    ------
    ParameterError
        For an unknown name, or ``flite`` without the ``flite`` program.
    """
    if name in ("espeak", "espeak-ng"):
        return EspeakBackend()
    if name == "flite":
        if shutil.which(FLITE) is None:
            raise ParameterError("synth.backend 'flite' needs the flite program "
                                 "(apt-get install flite); allowed: espeak, flite")
        return FliteBackend()
    raise ParameterError(f"synth.backend {name!r} is unknown; allowed: {', '.join(BACKENDS)}")
