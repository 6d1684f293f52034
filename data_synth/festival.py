"""Speech synthesis with Debian's ``festival`` (Festival 2.5), many utterances per process.

Festival takes ~0.7 s to start and load a voice, so a batch of requests is written into one
Scheme script and run by ``festival -b script.scm`` (one process per chunk of the batch, chunks
run in parallel). For every utterance the script sets the controls, synthesises, saves a 16-bit
RIFF WAV (never ``SayText`` or ``utt.play``: no audio device is touched), and writes each
``Segment`` with its END time in seconds; a segment starts where the previous one ended, the
first at 0. The audio is resampled to 22050 Hz (a 30 fps frame is exactly 735 samples).
Festival is deterministic: the same request gives byte-identical audio, whichever utterances
share its process (checked across and within processes).

The voices (:data:`FESTIVAL_VOICES`), each its own Debian package:

=========================  ====================  ======  ==========================================
voice                      Debian package        native  built from
=========================  ====================  ======  ==========================================
``kal_diphone``            festvox-kallpc16k     16 kHz  KAL diphones (Kevin A. Lenzo, US male)
``ked_diphone``            festvox-kdlpc16k      16 kHz  KED diphones (Kurt, a second US male)
``cmu_us_slt_arctic_hts``  festvox-us-slt-hts    32 kHz  CMU ARCTIC speaker slt (US female), HTS
=========================  ====================  ======  ==========================================

kal and ked share festival's front end and duration model (they differ mainly in timbre; ked
often adds an ``r`` after ``er``); festival's slt and flite's slt are the same speaker.

Request fields (espeak's scale; 165 wpm and pitch 50 are each voice's own defaults):

* diphone voices: ``rate_wpm`` → ``(Parameter.set 'Duration_Stretch (1.1 * 165 / rate_wpm))``
  (1.1 is their default stretch); ``pitch`` → ``int_lr_params`` ``target_f0_mean = 105 Hz *
  (0.5 + pitch / 100)``; ``pitch_range`` → ``target_f0_std = sd * pitch_range / 50`` (sd: kal
  14 Hz, ked 15 Hz). The defaults are the voices' own ``int_lr_params``.
* HTS voice: ``rate_wpm`` → hts_engine's speed ratio ``-r = rate_wpm / 165`` (``Duration_Stretch``
  has no effect on it); no pitch control works in festival 2.5 (``-fm``, ``-a``, ``-jf`` and
  ``hts_f0_mean`` leave the audio byte-identical), so ``pitch`` and ``pitch_range`` are ignored.
* ``voice`` of the request and ``word_gap`` are ignored: a backend speaks with the voice it was
  made with.

Texts are transliterated to ASCII (:func:`data_synth.text.to_ascii`; festival mis-reads the
rest), and a text with no letter or digit is not sent to festival at all (the diphone voices
crash on it, taking the whole batch down): it gives empty audio and no phones.

All three voices use festival's ``radio`` phone set, lowercase ARPAbet plus ``ax`` and ``pau``
(and ``axr dx el em en hv nx h# brth``, not emitted for plain text): the same symbols as flite,
mapped by :data:`data_synth.flite.FLITE_TO_CLASS`.
"""
from __future__ import annotations

import functools
import re
import shutil
import tempfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from data_synth.flite import FLITE_TO_CLASS
from data_synth.speech import (RawPhone, SpeechBackend, SynthRequest, SynthResult,
                               run_program)
from data_synth.text import is_speakable, to_ascii
from groundwork.audio import read_wav, resample, seconds_to_samples
from groundwork.errors import ParameterError

FESTIVAL = "festival"
DEBIAN_PACKAGE = "festival"
OUTPUT_SAMPLE_RATE = 22050
NOMINAL_RATE_WPM = 165


@dataclass(frozen=True)
class FestivalVoice:
    """A festival voice: its Debian package, native sample rate (Hz), kind (``diphone`` or
    ``hts``), default F0 (Hz; None: no pitch control) and the real speaker it was built from
    (``source``: an id of :func:`data_synth.backends.voice_speakers`)."""

    name: str
    package: str
    sample_rate: int
    kind: str
    f0_mean_hz: float | None
    f0_std_hz: float | None
    source: str
    description: str


FESTIVAL_VOICES = {v.name: v for v in (
    FestivalVoice("kal_diphone", "festvox-kallpc16k", 16000, "diphone", 105.0, 14.0, "festvox-kal",
                  "KAL diphones (Kevin A. Lenzo, US male), residual-excited LPC"),
    FestivalVoice("ked_diphone", "festvox-kdlpc16k", 16000, "diphone", 105.0, 15.0, "festvox-ked",
                  "KED diphones (Kurt, US male, recorded 1997), residual-excited LPC"),
    FestivalVoice("cmu_us_slt_arctic_hts", "festvox-us-slt-hts", 32000, "hts", None, None,
                  "arctic-slt", "CMU ARCTIC slt (US female), HTS; no pitch control"),
)}
DIPHONE_DURATION_STRETCH = 1.1  # the diphone voices' default Duration_Stretch


def _program() -> str:
    path = shutil.which(FESTIVAL)
    if path is None:
        raise ParameterError(f"the festival voices need the {FESTIVAL!r} program, which is not "
                             f"on PATH; install the Debian package: apt-get install "
                             f"{DEBIAN_PACKAGE} (and a voice, e.g. festvox-kallpc16k)")
    return path


@functools.lru_cache(maxsize=8)
def _listed_voices(program: str) -> tuple[str, ...]:
    with tempfile.TemporaryDirectory(prefix="talkingface-festival-") as tmp:
        script = Path(tmp) / "voices.scm"
        script.write_text("(print (voice.list))\n")
        proc = run_program([program, "-b", str(script)], what=f"{program} (voice list)",
                           cwd=tmp)
    m = re.search(r"\(([^()]*)\)", proc.stdout)
    return tuple(m.group(1).split()) if m else ()


def installed_voices() -> tuple[str, ...]:
    """The voices festival finds (``(voice.list)``), e.g. ``("cmu_us_slt_arctic_hts",
    "ked_diphone", "kal_diphone")``.

    Raises
    ------
    ParameterError
        If the ``festival`` program is not on PATH, naming the Debian package to install.
    """
    return _listed_voices(_program())


def check_voice(voice: str) -> FestivalVoice:
    """The catalogue entry of a usable, installed festival voice.

    Raises
    ------
    ParameterError
        For a voice outside :data:`FESTIVAL_VOICES` (listing them), a missing ``festival``
        program, or a voice whose package is not installed (naming the Debian package).
    """
    if voice not in FESTIVAL_VOICES:
        raise ParameterError(f"festival voice {voice!r} is unknown; allowed: "
                             f"{', '.join(FESTIVAL_VOICES)}")
    entry = FESTIVAL_VOICES[voice]
    if voice not in installed_voices():
        raise ParameterError(f"festival voice {voice!r} is not installed; install the Debian "
                             f"package: apt-get install {entry.package}")
    return entry


def festival_controls(req: SynthRequest, voice: str) -> dict[str, float]:
    """The festival settings for a request spoken by ``voice`` (see the module docstring).

    Returns
    -------
    dict
        Diphone voices: ``Duration_Stretch``, ``target_f0_mean`` and ``target_f0_std`` (Hz);
        the HTS voice: ``hts_speed`` (hts_engine's ``-r``, > 1 is faster).
    """
    if not req.rate_wpm > 0:
        raise ParameterError(f"festival: rate_wpm must be > 0 words per minute, got "
                             f"{req.rate_wpm}")
    for field in ("pitch", "pitch_range"):
        value = getattr(req, field)
        if not 0 <= value <= 100:
            raise ParameterError(f"festival: {field} must be in [0, 100], got {value}")
    v = FESTIVAL_VOICES[voice]
    if v.kind == "hts":
        return {"hts_speed": req.rate_wpm / NOMINAL_RATE_WPM}
    return {"Duration_Stretch": DIPHONE_DURATION_STRETCH * NOMINAL_RATE_WPM / req.rate_wpm,
            "target_f0_mean": v.f0_mean_hz * (0.5 + req.pitch / 100.0),
            "target_f0_std": v.f0_std_hz * req.pitch_range / 50.0}


def _q(s: str) -> str:
    """A Scheme string literal (SIOD escapes backslash and double quote)."""
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def build_script(voice: str, jobs) -> str:
    """The Scheme batch: ``jobs`` are ``(text, controls, wav_path, seg_path)``."""
    kind = FESTIVAL_VOICES[voice].kind
    lines = [f"(voice_{voice})",
             "(define (tf_set params key value) "
             "(cons (list key value) (remove (assoc key params) params)))"]
    lines.append("(set! tf_base hts_engine_params)" if kind == "hts"
                 else "(set! tf_base int_lr_params)")
    for text, ctl, wav, seg in jobs:
        if kind == "hts":  # appended to the voice's own list each time: the first entry wins
            lines.append(f"(set! hts_engine_params (append tf_base (list (list \"-r\" "
                         f"{ctl['hts_speed']:.6f}))))")
        else:
            lines.append(f"(Parameter.set 'Duration_Stretch {ctl['Duration_Stretch']:.6f})")
            lines.append(f"(set! int_lr_params (tf_set (tf_set tf_base 'target_f0_mean "
                         f"{ctl['target_f0_mean']:.4f}) 'target_f0_std "
                         f"{ctl['target_f0_std']:.4f}))")
        lines.append(f"(set! utt (utt.synth (Utterance Text {_q(text)})))")
        lines.append(f"(utt.save.wave utt {_q(str(wav))} 'riff)")
        lines.append(f"(set! fd (fopen {_q(str(seg))} \"w\"))")
        lines.append("(mapcar (lambda (s) (format fd \"%s %f\\n\" (item.name s) "
                     "(item.feat s \"end\"))) (utt.relation.items utt 'Segment))")
        lines.append("(fclose fd)")
    return "\n".join(lines) + "\n"


def _to_result(wav: Path, seg: Path, voice: str, text: str) -> SynthResult:
    y, sr = read_wav(wav)
    expected = FESTIVAL_VOICES[voice].sample_rate
    if sr != expected:
        raise ParameterError(f"festival voice {voice!r} wrote {sr} Hz audio, expected "
                             f"{expected} Hz")
    y = resample(y, sr_in=sr, sr_out=OUTPUT_SAMPLE_RATE)
    audio = np.clip(np.round(y.astype(np.float64) * 32768.0), -32768, 32767).astype(np.int16)
    phones, start = [], 0
    for line in seg.read_text().splitlines():
        sym, _, end = line.strip().partition(" ")
        try:
            end_s = float(end)
        except ValueError:
            raise ParameterError(f"festival: unreadable segment line {line!r} for "
                                 f"{text!r}; expected 'symbol end_seconds'") from None
        phones.append(RawPhone(start, sym))
        start = max(start, seconds_to_samples(end_s, OUTPUT_SAMPLE_RATE))
    return SynthResult(audio=audio, sample_rate=OUTPUT_SAMPLE_RATE, phones=phones)


def _run_chunk(voice: str, chunk, tmp: Path) -> list[SynthResult]:
    """One ``festival -b`` process for ``chunk``: ``(index, text, controls)`` triples."""
    jobs = [(text, ctl, tmp / f"{i:06d}.wav", tmp / f"{i:06d}.seg") for i, text, ctl in chunk]
    script = tmp / f"batch{chunk[0][0]:06d}.scm"
    script.write_text(build_script(voice, jobs))
    proc = run_program([FESTIVAL, "-b", str(script)], what=f"festival ({voice})",
                       utterances=len(jobs), cwd=tmp)
    out = []
    for text, _, wav, seg in jobs:
        if proc.returncode != 0 or not wav.is_file() or not seg.is_file():
            why = (f"exit status {proc.returncode}" if proc.returncode
                   else "no WAV or segment file written")
            raise ParameterError(f"festival ({voice}) failed ({why}) on text {text!r}: "
                                 f"{proc.stderr.strip()[-1500:] or '(no stderr)'}")
        out.append(_to_result(wav, seg, voice, text))
    return out


class FestivalBackend(SpeechBackend):
    """Festival (Debian's ``festival`` program) speaking with one voice, resampled to 22050 Hz.

    Parameters
    ----------
    voice : str
        A name of :data:`FESTIVAL_VOICES` (default ``kal_diphone``). Only the name is checked
        here; :func:`check_voice` also checks that the voice's package is installed.
    """

    name = "festival"
    sample_rate = OUTPUT_SAMPLE_RATE
    phone_map = FLITE_TO_CLASS

    def __init__(self, voice: str = "kal_diphone"):
        if voice not in FESTIVAL_VOICES:
            raise ParameterError(f"festival voice {voice!r} is unknown; allowed: "
                                 f"{', '.join(FESTIVAL_VOICES)}")
        self.voice = voice

    def version(self) -> str:
        """E.g. ``"festival 2.5.0 (voice kal_diphone)"``, from ``festival --version``."""
        proc = run_program([FESTIVAL, "--version"], what="festival --version")
        m = re.search(r"System: (\d+(?:\.\d+)*)", proc.stdout + proc.stderr)
        return f"festival {m.group(1) if m else 'unknown'} (voice {self.voice})"

    def synthesize_many(self, requests, *, workers: int, progress=None) -> list[SynthResult]:
        """Synthesise every request; ``workers`` festival processes share the batch.

        Parameters
        ----------
        requests : sequence of SynthRequest
        workers : int
            Number of ``festival -b`` processes, each given a contiguous chunk of the batch
            (the audio does not depend on the chunking).
        progress : callable, optional
            Called with 1 for each finished request (a chunk's all at once).

        Returns
        -------
        list of SynthResult
            In request order; int16 audio at 22050 Hz and phones in festival's symbols. A text
            without letters or digits gives empty audio and no phones.
        """
        requests = list(requests)
        if workers < 1:
            raise ParameterError(f"festival: workers must be >= 1, got {workers}")
        results: list = [None] * len(requests)
        todo = []
        for i, req in enumerate(requests):
            ctl = festival_controls(req, self.voice)
            text = to_ascii(req.text)
            if is_speakable(text):
                todo.append((i, text, ctl))
            else:
                results[i] = SynthResult(audio=np.zeros(0, np.int16),
                                         sample_rate=OUTPUT_SAMPLE_RATE, phones=[])
                if progress is not None:
                    progress(1)
        if not todo:
            return results
        n = min(workers, len(todo))
        bounds = np.linspace(0, len(todo), n + 1).round().astype(int)
        chunks = [todo[a:b] for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
        with tempfile.TemporaryDirectory(prefix="talkingface-festival-") as tmp, \
                ThreadPoolExecutor(max_workers=n) as pool:
            futures = [(chunk, pool.submit(_run_chunk, self.voice, chunk, Path(tmp)))
                       for chunk in chunks]
            try:
                for chunk, fut in futures:
                    for (i, _, _), res in zip(chunk, fut.result()):
                        results[i] = res
                        if progress is not None:
                            progress(1)
            except BaseException:
                pool.shutdown(wait=True, cancel_futures=True)
                raise
        return results
