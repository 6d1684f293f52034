"""espeak-ng speech synthesis with phone timing, through ctypes and the ``espeakng-loader`` wheel.

The wheel ships ``libespeak-ng.so`` and its data folder, so no system package is needed. The
library is initialised once in the parent process; every utterance is synthesised in a forked
child (``maxtasksperchild=1``), because inside one process only the first synthesis is
reproducible. This also spreads the work over all cores. espeak's own noise generator (breath
noise of variants such as ``f2``–``f5``) is seeded from the clock by the library: it is re-seeded
with :data:`RAND_SEED` before every utterance, so those variants are reproducible across runs.

Phone events carry the sample position of each phoneme; their mnemonics are mapped to the 44
classes by :data:`ESPEAK_TO_CLASS`.

Voices are ``<accent>[+<variant>]`` (e.g. ``en-us+m3``): the English accents of
:data:`ESPEAK_ACCENTS` (espeak-ng's own names; ``en-gb`` is not one of them, ``en`` is British
English) and the variants of the wheel's ``voices/!v`` folder (:func:`espeak_variants`:
``f1``–``f5``, ``m1``–``m8``, ``klatt``, ``whisper``, …). Variants change the voice quality,
never the phones. All are formant synthesis at 22050 Hz, built from no real speaker (source id
``espeak``).
"""
from __future__ import annotations

import ctypes
import multiprocessing as mp
import os
from importlib import metadata

import espeakng_loader
import numpy as np

from data_synth.speech import RawPhone, SpeechBackend, SynthRequest, SynthResult
from groundwork.errors import ParameterError

# espeak-ng constants (speak_lib.h)
_AUDIO_OUTPUT_SYNCHRONOUS = 2
_INIT_PHONEME_EVENTS = 0x0001
_INIT_DONT_EXIT = 0x8000
_POS_CHARACTER = 1
_CHARS_UTF8 = 1
_EV_LIST_TERMINATED, _EV_WORD, _EV_PHONEME = 0, 1, 7
_P_RATE, _P_PITCH, _P_RANGE, _P_WORDGAP = 1, 3, 4, 7
RAND_SEED = 2002  # espeak's noise generator, re-seeded before every utterance

# en-us mnemonics (stress marks stripped) → the 44 classes.
ESPEAK_TO_CLASS = {
    "p": "p", "b": "b", "t": "t", "d": "d", "k": "k", "g": "g", "m": "m", "n": "n", "N": "ng",
    "f": "f", "v": "v", "T": "th", "D": "dh", "s": "s", "z": "z", "S": "sh", "Z": "zh",
    "tS": "ch", "dZ": "jh", "h": "hh", "l": "l", "r": "r", "r-": "r", "w": "w", "j": "y",
    "t#": "dx", "d#": "dx", "*": "dx", "@L": "el", "n-": "en", "m-": "m", "l-": "el",
    "i": "iy", "i:": "iy", "I": "ih", "I2": "ih", "I#": "ih", "e": "eh", "E": "eh", "eI": "ey",
    "a": "ae", "aa": "ae", "A:": "aa", "A": "aa", "0": "aa", "V": "ah", "O:": "ao", "O": "ao",
    "U": "uh", "u:": "uw", "u": "uw", "aU": "aw", "OI": "oy", "aI": "ay", "oU": "ow",
    "3": "er", "3:": "er", "@": "ax", "@2": "ax", "@5": "ax", "a#": "ax", "@-": "ax",
    "A@": "aa", "e@": "eh", "i@": "ih", "i@3": "ih", "U@": "uh", "O@": "ao", "o@": "ao", "O2": "ao", "t2": "t", ";": "y",
    "aI@": "ay", "aI3": "ay", "aU@": "aw", "IR": "ih", "VR": "ah", "ER": "eh",
    "_": "sil", "_:": "sil", "_!": "sil", "_^_": "sil", "?": "sil", "_;_": "sil", "||": "sil",
    # other English accents: en-gb-scotland's "by" (aI2) and voiceless "wh" (w#); en-029's
    # dental stops, which stand for "th"/"dh" (th-stopping: "three" = [t[ri:]). The classes have
    # no dental stop; th/dh share its place of articulation (tongue tip at the upper teeth),
    # which is what the face shows, while t/d are alveolar.
    "aI2": "ay", "w#": "w", "t[": "th", "d[": "dh",
}
# The English accents espeak-ng 1.52 accepts by name (espeak_SetVoiceByName).
ESPEAK_ACCENTS = ("en-us", "en-us-nyc", "en", "en-gb-x-rp", "en-gb-scotland", "en-gb-x-gbclan",
                  "en-gb-x-gbcwmd", "en-029")


def espeak_variants() -> tuple[str, ...]:
    """The voice variants of the wheel's data folder (``voices/!v``), sorted: ``f1``…``m8``,
    ``klatt``, ``whisper``, ... (104 in espeakng-loader 0.2.4)."""
    folder = os.path.join(espeakng_loader.get_data_path(), "voices", "!v")
    return tuple(sorted(os.listdir(folder))) if os.path.isdir(folder) else ()


def check_voice(voice: str) -> str:
    """``voice`` if it is ``<accent>[+<variant>]`` with a known accent and variant.

    Raises
    ------
    ParameterError
        Naming the voice and listing the accents (and, for a bad variant, the variants).
    """
    accent, plus, variant = voice.partition("+")
    if accent not in ESPEAK_ACCENTS:
        raise ParameterError(f"espeak voice {voice!r}: unknown accent {accent!r}; allowed: "
                             f"{', '.join(ESPEAK_ACCENTS)}, each optionally with +variant "
                             "(e.g. en-us+f3)")
    if plus and variant not in espeak_variants():
        raise ParameterError(f"espeak voice {voice!r}: unknown variant {variant!r}; allowed: "
                             f"{', '.join(espeak_variants())}")
    return voice


class _Event(ctypes.Structure):
    class _Id(ctypes.Union):
        _fields_ = [("number", ctypes.c_int), ("name", ctypes.c_char_p),
                    ("string", ctypes.c_char * 8)]

    _fields_ = [("type", ctypes.c_int), ("unique_identifier", ctypes.c_uint),
                ("text_position", ctypes.c_int), ("length", ctypes.c_int),
                ("audio_position", ctypes.c_int), ("sample", ctypes.c_int),
                ("user_data", ctypes.c_void_p), ("id", _Id)]


_CALLBACK = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_short), ctypes.c_int,
                             ctypes.POINTER(_Event))

# Per-process state: the library handle and the buffers the callback fills. A forked child
# inherits the initialised library and starts with empty buffers.
_LIB = None
_SR = 0
_CHUNKS: list = []
_EVENTS: list = []


@_CALLBACK
def _on_synth(wav, n, events):
    if n > 0:
        _CHUNKS.append(np.ctypeslib.as_array(wav, shape=(n,)).copy())
    i = 0
    while events[i].type != _EV_LIST_TERMINATED:
        ev = events[i]
        if ev.type == _EV_PHONEME:
            _EVENTS.append((ev.sample, ev.id.string.decode("ascii", "replace")))
        i += 1
    return 0


def _initialise() -> int:
    global _LIB, _SR
    if _LIB is not None:
        return _SR
    lib = ctypes.CDLL(espeakng_loader.get_library_path())
    lib.espeak_Initialize.restype = ctypes.c_int
    lib.espeak_Initialize.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_char_p, ctypes.c_int]
    sr = lib.espeak_Initialize(_AUDIO_OUTPUT_SYNCHRONOUS, 0,
                               espeakng_loader.get_data_path().encode(),
                               _INIT_PHONEME_EVENTS | _INIT_DONT_EXIT)
    if sr <= 0:
        raise RuntimeError(f"espeak_Initialize failed (returned {sr})")
    lib.espeak_SetSynthCallback(_on_synth)
    lib.espeak_ng_SetRandSeed.argtypes = [ctypes.c_long]
    lib.espeak_ng_SetRandSeed.restype = None
    lib.espeak_SetVoiceByName.argtypes = [ctypes.c_char_p]
    lib.espeak_SetParameter.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int]
    lib.espeak_Synth.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_uint, ctypes.c_int,
                                 ctypes.c_uint, ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p]
    _LIB, _SR = lib, sr
    return sr


def _strip_stress(mnemonic: str) -> str:
    return mnemonic.replace("'", "").replace(",", "").strip()


def _synth_in_child(req: SynthRequest) -> SynthResult:
    """Runs in a forked child: synthesise one request with the inherited library."""
    lib = _LIB
    _CHUNKS.clear()
    _EVENTS.clear()
    # Variants with breath noise (f2, f3, ...) draw from espeak's own generator, which
    # espeak_Initialize seeds from the clock: fix it so they are reproducible across runs.
    # (Voices without noise, like en-us+m3, never draw from it: their audio is unchanged.)
    lib.espeak_ng_SetRandSeed(RAND_SEED)
    if lib.espeak_SetVoiceByName(req.voice.encode()) != 0:
        raise ParameterError(f"espeak-ng has no voice {req.voice!r}; allowed: an accent "
                             f"({', '.join(ESPEAK_ACCENTS)}) with an optional +variant "
                             "(e.g. 'en-us+m3')")
    lib.espeak_SetParameter(_P_RATE, int(req.rate_wpm), 0)
    lib.espeak_SetParameter(_P_PITCH, int(req.pitch), 0)
    lib.espeak_SetParameter(_P_RANGE, int(req.pitch_range), 0)
    lib.espeak_SetParameter(_P_WORDGAP, int(req.word_gap), 0)
    text = req.text.encode("utf-8") + b"\0"
    lib.espeak_Synth(text, len(text), 0, _POS_CHARACTER, 0, _CHARS_UTF8, None, None)
    lib.espeak_Synchronize()
    audio = np.concatenate(_CHUNKS) if _CHUNKS else np.zeros(0, np.int16)
    phones = [RawPhone(int(s), _strip_stress(m)) for s, m in _EVENTS]
    return SynthResult(audio=audio.astype(np.int16), sample_rate=_SR, phones=phones)


class EspeakBackend(SpeechBackend):
    """espeak-ng from the ``espeakng-loader`` wheel (always available)."""

    name = "espeak-ng"
    phone_map = ESPEAK_TO_CLASS

    def __init__(self):
        self.sample_rate = _initialise()

    def version(self) -> str:
        return f"espeak-ng (espeakng-loader {metadata.version('espeakng-loader')}, " \
               f"{os.path.basename(espeakng_loader.get_library_path())})"

    def synthesize_many(self, requests, *, workers, progress=None):
        ctx = mp.get_context("fork")
        results = [None] * len(requests)
        with ctx.Pool(processes=workers, maxtasksperchild=1) as pool:
            for i, res in enumerate(pool.imap(_synth_in_child, requests, chunksize=1)):
                results[i] = res
                if progress is not None:
                    progress(1)
        return results
