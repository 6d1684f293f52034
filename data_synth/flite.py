"""Speech synthesis with Debian's ``flite`` program (CMU Flite 2.2), one subprocess per utterance.

Each request runs ``flite -voice slt ... -psdur -o <tmp.wav> -t <text>``. With ``-psdur`` flite
prints every phone with its END time in seconds on one stdout line (``pau:0.184 dh:0.236 ...``,
1 ms resolution, always starting and ending with ``pau``); a phone starts where the previous one
ended, the first at 0. The voice ``slt`` (clustergen, female, 16 kHz) is resampled to 22050 Hz so
that a 30 fps frame is exactly 735 samples. Flite is deterministic: the same request gives
byte-identical audio.

Request fields: ``rate_wpm`` sets ``duration_stretch = 165 / rate_wpm`` (165 wpm = the voice's
own rate); ``pitch`` and ``pitch_range`` (0–100, espeak's scale) scale the voice's F0 mean and
standard deviation linearly, 50 giving the voice's defaults (see :func:`flite_features`).
``voice`` (an espeak voice name) and ``word_gap`` have no flite counterpart and are ignored.

Flite's US English phone set is lowercase ARPAbet plus ``ax`` and ``pau``; over the 360 built-in
sentences it emits exactly those 41 symbols. :data:`FLITE_TO_CLASS` also maps the rest of its
phone set (``axr dx el em en hv nx h# brth``), which it does not emit for plain text.
"""
from __future__ import annotations

import re
import subprocess
import tempfile
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from data_synth.speech import RawPhone, SpeechBackend, SynthRequest, SynthResult
from face_model.audio import read_wav, resample
from face_model.errors import ParameterError

FLITE = "flite"
VOICE = "slt"  # built-in clustergen voice, 16 kHz
VOICE_SAMPLE_RATE = 16000
VOICE_F0_MEAN_HZ = 172.0  # cmu_us_slt_cg_db.f0_mean: flite's output is unchanged when set to this
VOICE_F0_STDDEV_HZ = 27.0  # cmu_us_slt_cg_db.f0_stddev
OUTPUT_SAMPLE_RATE = 22050
NOMINAL_RATE_WPM = 165

_ARPABET = ("aa ae ah ao aw ay b ch d dh eh er ey f g hh ih iy jh k l m n ng ow oy p r s sh t th "
            "uh uw v w y z zh").split()
# flite (cmu_us phone set) → the 44 classes.
FLITE_TO_CLASS = {**{p: p for p in _ARPABET},
                  "ax": "ax", "dx": "dx", "el": "el", "en": "en", "axr": "er", "em": "m",
                  "hv": "hh", "nx": "n", "pau": "sil", "h#": "sil", "brth": "sil"}


def flite_features(req: SynthRequest) -> dict[str, float]:
    """Flite float features for a request.

    Parameters
    ----------
    req : SynthRequest
        ``rate_wpm`` > 0; ``pitch`` and ``pitch_range`` in [0, 100].

    Returns
    -------
    dict
        ``duration_stretch = 165 / rate_wpm``;
        ``int_f0_target_mean = 172 Hz * (0.5 + pitch / 100)``
        (0 → 86 Hz, 50 → 172 Hz, 100 → 258 Hz);
        ``int_f0_target_stddev = 27 Hz * pitch_range / 50`` (0 → monotone, 50 → 27 Hz).
    """
    if not req.rate_wpm > 0:
        raise ParameterError(f"flite: rate_wpm must be > 0 words per minute, got {req.rate_wpm}")
    for field in ("pitch", "pitch_range"):
        value = getattr(req, field)
        if not 0 <= value <= 100:
            raise ParameterError(f"flite: {field} must be in [0, 100], got {value}")
    return {"duration_stretch": NOMINAL_RATE_WPM / req.rate_wpm,
            "int_f0_target_mean": VOICE_F0_MEAN_HZ * (0.5 + req.pitch / 100.0),
            "int_f0_target_stddev": VOICE_F0_STDDEV_HZ * req.pitch_range / 50.0}


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


def _synthesize_one(req: SynthRequest, wav: Path) -> SynthResult:
    cmd = [FLITE, "-voice", VOICE]
    for name, value in flite_features(req).items():
        cmd += ["--setf", f"{name}={value:.6g}"]
    cmd += ["-psdur", "-o", str(wav), "-t", req.text]
    proc = subprocess.run(cmd, capture_output=True, text=True, stdin=subprocess.DEVNULL)
    if proc.returncode != 0 or not wav.is_file():
        why = f"exit status {proc.returncode}" if proc.returncode else "no WAV written"
        raise ParameterError(f"flite failed ({why}) on text {req.text!r}: "
                             f"{proc.stderr.strip() or '(no stderr)'}")
    y, sr = read_wav(wav)
    if sr != VOICE_SAMPLE_RATE:
        raise ParameterError(f"flite voice {VOICE!r} wrote {sr} Hz audio, expected "
                             f"{VOICE_SAMPLE_RATE} Hz")
    y = resample(y, sr_in=sr, sr_out=OUTPUT_SAMPLE_RATE)
    audio = np.clip(np.round(y.astype(np.float64) * 32768.0), -32768, 32767).astype(np.int16)
    phones, start = [], 0
    for sym, end_s in parse_psdur(proc.stdout, text=req.text):
        phones.append(RawPhone(start, sym))
        start = max(start, int(round(end_s * OUTPUT_SAMPLE_RATE)))
    return SynthResult(audio=audio, sample_rate=OUTPUT_SAMPLE_RATE, phones=phones)


class FliteBackend(SpeechBackend):
    """CMU Flite (Debian's ``flite`` program, voice :data:`VOICE`), resampled to 22050 Hz."""

    name = "flite"
    sample_rate = OUTPUT_SAMPLE_RATE
    phone_map = FLITE_TO_CLASS

    def version(self) -> str:
        """E.g. ``"flite 2.2 (voice slt)"``, from ``flite --version`` (which exits with 1)."""
        proc = subprocess.run([FLITE, "--version"], capture_output=True, text=True,
                              stdin=subprocess.DEVNULL)
        m = re.search(r"flite-(\d+(?:\.\d+)*)", proc.stdout + proc.stderr)
        return f"flite {m.group(1) if m else 'unknown'} (voice {VOICE})"

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
            futures = {pool.submit(_synthesize_one, req, Path(tmp) / f"{i:06d}.wav"): i
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
