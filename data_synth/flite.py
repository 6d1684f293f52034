"""Speech synthesis with Debian's ``flite`` program (CMU Flite 2.2), one subprocess per utterance.

Each request runs ``flite -voice <voice> ... -psdur -o <tmp.wav> -t <text>``. With ``-psdur`` flite
prints every phone with its END time in seconds on one stdout line (``pau:0.184 dh:0.236 ...``,
1 ms resolution, always starting and ending with ``pau``); a phone starts where the previous one
ended, the first at 0. The audio is resampled to 22050 Hz so that a 30 fps frame is exactly
735 samples. Flite is deterministic: the same request gives byte-identical audio.

The voices (:data:`FLITE_VOICES`; all built into Debian's ``libflite1``, which ``flite`` pulls in):

========  ========  ===================================================================
voice     native    built from
========  ========  ===================================================================
``kal``   8000 Hz   diphones of KAL (Kevin A. Lenzo, US male); LPC diphone synthesis;
                    it never emits ``ah`` (its post-lexical rule turns ``ah`` into ``aa``)
``kal16`` 16000 Hz  the same KAL diphones at 16 kHz
``awb``   16000 Hz  CMU ARCTIC speaker awb (Scottish-accented English male), clustergen
``rms``   16000 Hz  CMU ARCTIC speaker rms (US male), clustergen; ignores the pitch controls
``slt``   16000 Hz  CMU ARCTIC speaker slt (US female), clustergen; the legacy default
========  ========  ===================================================================

``awb_time`` (a limited-domain clock voice) is left out: for general text it speaks only its
in-domain words. Flite silently falls back to ``kal`` for an unknown voice, so the voice is
checked against ``flite -lv`` (:func:`installed_voices`) and the sample rate of every WAV against
the voice's own.

Request fields: ``rate_wpm`` sets ``duration_stretch = d0 * 165 / rate_wpm`` (165 wpm = the
voice's own rate, ``d0`` its default stretch: 1.1 for kal and kal16, 1.0 for the rest);
``pitch`` and ``pitch_range`` (0–100, espeak's scale) scale the voice's F0 mean and standard
deviation linearly, 50 giving the voice's defaults (see :func:`flite_features`). The defaults
(``d0``, F0 mean, F0 standard deviation) are the values at which flite's output is
byte-identical to leaving the feature unset (checked on flite 2.2-5). ``voice`` of the request
(an espeak voice name) and ``word_gap`` have no flite counterpart and are ignored: a backend
speaks with the voice it was made with.

Flite's US English phone set is lowercase ARPAbet plus ``ax`` and ``pau``; over the 360 built-in
sentences it emits exactly those 41 symbols. :data:`FLITE_TO_CLASS` also maps the rest of its
phone set (``axr dx el em en hv nx h# brth``), which it does not emit for plain text.
"""
from __future__ import annotations

import functools
import re
import shutil
import tempfile
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from data_synth.speech import (RawPhone, SpeechBackend, SynthRequest, SynthResult,
                               run_program)
from data_synth.text import to_ascii
from groundwork.audio import read_wav, resample, seconds_to_samples
from groundwork.errors import ParameterError

FLITE = "flite"
DEBIAN_PACKAGE = "flite"
OUTPUT_SAMPLE_RATE = 22050
NOMINAL_RATE_WPM = 165


@dataclass(frozen=True)
class FliteVoice:
    """A flite voice: native sample rate (Hz), default controls, and the real speaker it was
    built from (``source``: an id of :func:`data_synth.backends.voice_speakers`)."""

    name: str
    sample_rate: int
    duration_stretch: float  # flite's default for the voice
    f0_mean_hz: float | None  # None: the voice ignores the pitch controls
    f0_stddev_hz: float | None
    source: str
    description: str


FLITE_VOICES = {v.name: v for v in (
    FliteVoice("kal", 8000, 1.1, 95.0, 11.0, "festvox-kal",
               "KAL diphones (Kevin A. Lenzo, US male), 8 kHz LPC diphone synthesis"),
    FliteVoice("kal16", 16000, 1.1, 95.0, 11.0, "festvox-kal",
               "KAL diphones (Kevin A. Lenzo, US male), 16 kHz LPC diphone synthesis"),
    FliteVoice("awb", 16000, 1.0, 132.0, 25.0, "arctic-awb",
               "CMU ARCTIC awb (Scottish-accented English male), clustergen"),
    FliteVoice("rms", 16000, 1.0, None, None, "arctic-rms",
               "CMU ARCTIC rms (US male), clustergen; no pitch control"),
    FliteVoice("slt", 16000, 1.0, 172.0, 27.0, "arctic-slt",
               "CMU ARCTIC slt (US female), clustergen"),
)}
VOICE = "slt"  # the voice of ``backend: flite`` (and of FliteBackend())
VOICE_SAMPLE_RATE = FLITE_VOICES[VOICE].sample_rate
VOICE_F0_MEAN_HZ = FLITE_VOICES[VOICE].f0_mean_hz  # cmu_us_slt_cg_db.f0_mean
VOICE_F0_STDDEV_HZ = FLITE_VOICES[VOICE].f0_stddev_hz  # cmu_us_slt_cg_db.f0_stddev

_ARPABET = ("aa ae ah ao aw ay b ch d dh eh er ey f g hh ih iy jh k l m n ng ow oy p r s sh t th "
            "uh uw v w y z zh").split()
# flite (cmu_us phone set) → the 44 classes.
FLITE_TO_CLASS = {**{p: p for p in _ARPABET},
                  "ax": "ax", "dx": "dx", "el": "el", "en": "en", "axr": "er", "em": "m",
                  "hv": "hh", "nx": "n", "pau": "sil", "h#": "sil", "brth": "sil"}


@functools.lru_cache(maxsize=8)
def _listed_voices(program: str) -> tuple[str, ...]:
    proc = run_program([program, "-lv"], what=f"{program} -lv")
    _, _, names = (proc.stdout + proc.stderr).partition("Voices available:")
    return tuple(names.split())


def installed_voices() -> tuple[str, ...]:
    """The voices ``flite -lv`` lists, e.g. ``("kal", "awb_time", "kal16", "awb", "rms", "slt")``.

    Raises
    ------
    ParameterError
        If the ``flite`` program is not on PATH, naming the Debian package to install.
    """
    path = shutil.which(FLITE)
    if path is None:
        raise ParameterError(f"the flite voices need the {FLITE!r} program, which is not on "
                             f"PATH; install the Debian package: apt-get install "
                             f"{DEBIAN_PACKAGE}")
    return _listed_voices(path)


def check_voice(voice: str) -> FliteVoice:
    """The catalogue entry of a usable, installed flite voice.

    Raises
    ------
    ParameterError
        For a voice outside :data:`FLITE_VOICES` (listing them), a missing ``flite`` program, or a
        voice this flite does not list (each naming the Debian package).
    """
    if voice not in FLITE_VOICES:
        raise ParameterError(f"flite voice {voice!r} is unknown; allowed: "
                             f"{', '.join(FLITE_VOICES)}")
    listed = installed_voices()
    if voice not in listed:
        raise ParameterError(f"flite voice {voice!r} is not in this flite (it lists: "
                             f"{' '.join(listed) or 'nothing'}); it is built into Debian's "
                             f"libflite1: apt-get install {DEBIAN_PACKAGE}")
    return FLITE_VOICES[voice]


def flite_features(req: SynthRequest, voice: str = VOICE) -> dict[str, float]:
    """Flite float features for a request spoken by ``voice``.

    Parameters
    ----------
    req : SynthRequest
        ``rate_wpm`` > 0; ``pitch`` and ``pitch_range`` in [0, 100].
    voice : str
        A name of :data:`FLITE_VOICES`.

    Returns
    -------
    dict
        ``duration_stretch = d0 * 165 / rate_wpm`` (``d0``: the voice's default stretch);
        ``int_f0_target_mean = f0 * (0.5 + pitch / 100)`` (``f0``: the voice's F0 mean, e.g.
        slt 172 Hz: 0 → 86 Hz, 50 → 172 Hz, 100 → 258 Hz);
        ``int_f0_target_stddev = sd * pitch_range / 50`` (``sd``: the voice's F0 standard
        deviation; 0 → monotone). The pitch features are left out for a voice that ignores
        them (``rms``).
    """
    if not req.rate_wpm > 0:
        raise ParameterError(f"flite: rate_wpm must be > 0 words per minute, got {req.rate_wpm}")
    for field in ("pitch", "pitch_range"):
        value = getattr(req, field)
        if not 0 <= value <= 100:
            raise ParameterError(f"flite: {field} must be in [0, 100], got {value}")
    v = FLITE_VOICES[voice]
    out = {"duration_stretch": v.duration_stretch * NOMINAL_RATE_WPM / req.rate_wpm}
    if v.f0_mean_hz is not None:
        out["int_f0_target_mean"] = v.f0_mean_hz * (0.5 + req.pitch / 100.0)
        out["int_f0_target_stddev"] = v.f0_stddev_hz * req.pitch_range / 50.0
    return out


def parse_psdur(stdout: str, *, text: str) -> list[tuple[str, float]]:
    """``(symbol, end_s)`` pairs from flite's ``-psdur`` line(s), e.g. ``pau:0.184 dh:0.236``."""
    out = []
    for tok in stdout.split():
        sym, sep, end = tok.rpartition(":")
        try:
            out.append((sym, float(end)))
        except ValueError:
            sep = ""
        if not sep or not sym:
            raise ParameterError(f"flite: unreadable phone entry {tok!r} for {text!r}; "
                                 "expected symbol:end_seconds")
    return out


def _synthesize_one(req: SynthRequest, wav: Path, voice: str) -> SynthResult:
    cmd = [FLITE, "-voice", voice]
    for name, value in flite_features(req, voice).items():
        cmd += ["--setf", f"{name}={value:.6g}"]
    cmd += ["-psdur", "-o", str(wav), "-t", to_ascii(req.text)]
    proc = run_program(cmd, what=f"flite ({voice})")
    if proc.returncode != 0 or not wav.is_file():
        why = f"exit status {proc.returncode}" if proc.returncode else "no WAV written"
        raise ParameterError(f"flite failed ({why}) on text {req.text!r}: "
                             f"{proc.stderr.strip() or '(no stderr)'}")
    y, sr = read_wav(wav)
    expected = FLITE_VOICES[voice].sample_rate
    if sr != expected:  # flite falls back to kal (8 kHz) on a voice it does not have
        raise ParameterError(f"flite voice {voice!r} wrote {sr} Hz audio, expected "
                             f"{expected} Hz (flite replaces a voice it lacks by kal)")
    y = resample(y, sr_in=sr, sr_out=OUTPUT_SAMPLE_RATE)
    audio = np.clip(np.round(y.astype(np.float64) * 32768.0), -32768, 32767).astype(np.int16)
    phones, start = [], 0
    for sym, end_s in parse_psdur(proc.stdout, text=req.text):
        phones.append(RawPhone(start, sym))
        start = max(start, seconds_to_samples(end_s, OUTPUT_SAMPLE_RATE))
    return SynthResult(audio=audio, sample_rate=OUTPUT_SAMPLE_RATE, phones=phones)


class FliteBackend(SpeechBackend):
    """CMU Flite (Debian's ``flite`` program) speaking with one voice, resampled to 22050 Hz.

    Parameters
    ----------
    voice : str
        A name of :data:`FLITE_VOICES` (default :data:`VOICE`, ``slt``). Only the name is
        checked here; :func:`check_voice` also checks that flite has it.
    """

    name = "flite"
    sample_rate = OUTPUT_SAMPLE_RATE
    phone_map = FLITE_TO_CLASS

    def __init__(self, voice: str = VOICE):
        if voice not in FLITE_VOICES:
            raise ParameterError(f"flite voice {voice!r} is unknown; allowed: "
                                 f"{', '.join(FLITE_VOICES)}")
        self.voice = voice

    def version(self) -> str:
        """E.g. ``"flite 2.2 (voice slt)"``, from ``flite --version`` (which exits with 1)."""
        proc = run_program([FLITE, "--version"], what="flite --version")
        m = re.search(r"flite-(\d+(?:\.\d+)*)", proc.stdout + proc.stderr)
        return f"flite {m.group(1) if m else 'unknown'} (voice {self.voice})"

    def synthesize_many(self, requests, *, workers: int, progress=None) -> list[SynthResult]:
        """Synthesise every request with one flite process each.

        Parameters
        ----------
        requests : sequence of SynthRequest
        workers : int
            Number of flite processes run at once (threads of a ``ThreadPoolExecutor``).
        progress : callable, optional
            Called with 1 after each finished request.

        Returns
        -------
        list of SynthResult
            In request order; int16 audio at 22050 Hz and phones in flite's symbols.
        """
        requests = list(requests)
        if workers < 1:
            raise ParameterError(f"flite: workers must be >= 1, got {workers}")
        results: list = [None] * len(requests)
        with tempfile.TemporaryDirectory(prefix="talkingface-flite-") as tmp, \
                ThreadPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(_synthesize_one, req, Path(tmp) / f"{i:06d}.wav",
                                   self.voice): i
                       for i, req in enumerate(requests)}
            try:
                for fut in as_completed(futures):
                    results[futures[fut]] = fut.result()
                    if progress is not None:
                        progress(1)
            except BaseException:
                pool.shutdown(wait=True, cancel_futures=True)
                raise
        return results
