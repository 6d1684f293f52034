"""The speech-synthesis backends by name, and the voices a corpus can speak with.

A backend implements :class:`data_synth.speech.SpeechBackend`; this module sits above them and
above :mod:`data_synth.speech`, so the interface never imports an implementation.

Two ways to choose speech:

* ``synth.backend`` (``espeak``, the default, or ``flite``) with ``synth.voice`` and the
  per-speaker espeak variants: the paper's single-speaker design (:func:`get_backend`).
* ``synth.voices``: ``"engine:voice"`` strings, each utterance drawing one
  (:func:`parse_voice`, :func:`check_voices_installed`, :func:`voice_backend`):

  ===========  ==============================================  ===========  ===================
  engine       voices                                          native rate  built from
  ===========  ==============================================  ===========  ===================
  ``espeak``   ``<accent>[+<variant>]``, e.g. ``en-us+f3``     22050 Hz     formant synthesis
               (:data:`~data_synth.espeak.ESPEAK_ACCENTS`)
  ``flite``    ``kal`` (8 kHz), ``kal16``                      16000 Hz     KAL diphones
               ``awb``, ``rms``, ``slt``                       16000 Hz     CMU ARCTIC speakers
  ``festival`` ``kal_diphone``, ``ked_diphone``                16000 Hz     KAL, KED diphones
               ``cmu_us_slt_arctic_hts``                       32000 Hz     CMU ARCTIC slt
  ===========  ==============================================  ===========  ===================

  All are resampled to 22050 Hz. :func:`voice_speakers` names the real speaker behind each, so
  an evaluation can tell seen from unseen speakers. Speaker ids are lowercase
  ``<collection>-<speaker>`` (``arctic-slt``, ``festvox-kal``), the scheme of the real-speech set
  (``analysis/real_speech/README.md``); ``espeak`` has no real speaker.
"""
from __future__ import annotations

import shutil

from data_synth import espeak, festival, flite
from data_synth.espeak import EspeakBackend
from data_synth.festival import FESTIVAL_VOICES, FestivalBackend
from data_synth.flite import FLITE, FLITE_VOICES, FliteBackend
from data_synth.speech import SpeechBackend
from groundwork.errors import ParameterError

BACKENDS = ("espeak", "flite")
ENGINES = ("espeak", "flite", "festival")
ESPEAK_SPEAKER = "espeak"  # the source id of every espeak voice: formant synthesis, no speaker


def get_backend(name: str) -> SpeechBackend:
    """A new backend: ``espeak`` or ``espeak-ng`` (from the ``espeakng-loader`` wheel, always
    available) or ``flite`` (needs Debian's ``flite`` on PATH; voice ``slt``).

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


def allowed_voices() -> str:
    """What a voice may be, for error messages."""
    return (f"'engine:voice' with engine one of {', '.join(ENGINES)}; espeak:<accent>"
            f"[+<variant>] with accent one of {', '.join(espeak.ESPEAK_ACCENTS)} (e.g. "
            f"espeak:en-us+f3); flite: {', '.join(FLITE_VOICES)}; festival: "
            f"{', '.join(FESTIVAL_VOICES)}")


def voice_problem(spec) -> str | None:
    """None if ``spec`` names a known voice, else what is allowed (for the error message)."""
    engine, colon, voice = spec.partition(":") if isinstance(spec, str) else ("", "", "")
    if engine == "espeak-ng":
        engine = "espeak"
    if not colon or engine not in ENGINES or not voice:
        return allowed_voices()
    if engine == "espeak":
        accent, plus, variant = voice.partition("+")
        if accent not in espeak.ESPEAK_ACCENTS:
            return (f"espeak:<accent>[+<variant>] with accent one of "
                    f"{', '.join(espeak.ESPEAK_ACCENTS)} (e.g. espeak:en-us+f3)")
        if plus and variant not in espeak.espeak_variants():
            return (f"an espeak variant of the espeakng-loader data folder: "
                    f"{', '.join(espeak.espeak_variants())}")
    elif engine == "flite" and voice not in FLITE_VOICES:
        return f"flite voices {', '.join(FLITE_VOICES)} (awb_time speaks only clock times)"
    elif engine == "festival" and voice not in FESTIVAL_VOICES:
        return f"festival voices {', '.join(FESTIVAL_VOICES)}"
    return None


def parse_voice(spec: str) -> tuple[str, str]:
    """``"engine:voice"`` → ``(engine, voice)``, checking the name (not the installation).

    ``espeak-ng:`` is another name of ``espeak:``.

    Raises
    ------
    ParameterError
        Naming ``spec`` and listing what is allowed.
    """
    problem = voice_problem(spec)
    if problem is not None:
        raise ParameterError(f"voice {spec!r} is unknown; allowed: {problem}")
    engine, _, voice = spec.partition(":")
    return ("espeak" if engine == "espeak-ng" else engine), voice


def check_voices_installed(specs) -> None:
    """Check that every voice of ``specs`` can be synthesised here, before any work.

    Raises
    ------
    ParameterError
        For an unknown voice, or a missing program or voice package, naming the Debian package
        to install (``flite``; ``festival``, ``festvox-kallpc16k``, ``festvox-kdlpc16k``,
        ``festvox-us-slt-hts``).
    """
    for spec in dict.fromkeys(specs):
        engine, voice = parse_voice(spec)
        try:
            if engine == "flite":
                flite.check_voice(voice)
            elif engine == "festival":
                festival.check_voice(voice)
        except ParameterError as exc:
            raise ParameterError(f"voice {spec!r}: {exc}") from None


def voice_backend(spec: str) -> SpeechBackend:
    """The backend that speaks ``"engine:voice"``.

    An espeak backend takes the voice from each request (``SynthRequest.voice`` must then be
    the espeak voice, e.g. ``en-us+f3``); the flite and festival backends are bound to the voice.
    """
    engine, voice = parse_voice(spec)
    if engine == "espeak":
        return EspeakBackend()
    if engine == "flite":
        return FliteBackend(voice)
    return FestivalBackend(voice)


def voice_sample_rate(spec: str) -> int:
    """The native sample rate (Hz) of a voice, before resampling to 22050 Hz."""
    engine, voice = parse_voice(spec)
    if engine == "flite":
        return FLITE_VOICES[voice].sample_rate
    if engine == "festival":
        return FESTIVAL_VOICES[voice].sample_rate
    return 22050


def voice_speakers() -> dict[str, str]:
    """Each flite and festival voice, and the espeak accents, → the real speaker it was built
    from.

    Returns
    -------
    dict
        ``"engine:voice"`` → ``"arctic-slt"``, ``"arctic-awb"``, ``"arctic-rms"`` (CMU ARCTIC
        speakers), ``"festvox-kal"`` or ``"festvox-ked"`` (the two US male diphone speakers), or
        ``"espeak"`` (formant synthesis, no speaker; one entry per accent; any ``+variant`` of
        an accent is the same). Use :func:`voice_speaker` for any valid voice string.
    """
    out = {f"espeak:{a}": ESPEAK_SPEAKER for a in espeak.ESPEAK_ACCENTS}
    out.update({f"flite:{v.name}": v.source for v in FLITE_VOICES.values()})
    out.update({f"festival:{v.name}": v.source for v in FESTIVAL_VOICES.values()})
    return out


def voice_speaker(spec: str) -> str:
    """The real speaker id of any valid voice string (``espeak:en-us+f3`` → ``espeak``)."""
    engine, voice = parse_voice(spec)
    if engine == "espeak":
        return ESPEAK_SPEAKER
    return voice_speakers()[f"{engine}:{voice}"]
