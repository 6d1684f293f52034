"""A phone recogniser trained on real speech as the gate's front end (issue 12, part 6; issue 29).

Three recognisers sit behind one interface (``mapping.recogniser``, :data:`RECOGNISERS`):
``pocketsphinx`` (this module's :class:`PhoneStream`), ``hama`` (a multilingual CTC phoneme
model, :class:`mapping.hama_front.HamaStream`) and ``causal`` (our own small causal network
taught by hama, :class:`mapping.causal_front.CausalStream`; ``causal`` is the shipped model
file, ``causal:<model file>`` another one, e.g. a run's ``front_end/causal_front.npz``).
:func:`phone_stream` makes any one's stream, :func:`recognise_windows` runs one over a whole
utterance exactly as live, and :func:`recogniser_name` names the model and version (cache
keys, reports). The streams take the same arguments and give the same windows; everything
below is pocketsphinx's.

pocketsphinx's en-US acoustic model (in its PyPI wheel, no download) decodes the audio into
phones with its phone language model (``allphone`` search; FIELD_NOTES "Real speech available
offline": ``lw=2.0``, ``beam=pbeam=1e-20``, no best-path pass). It is the route Rhubarb Lip
Sync takes: the recogniser has heard many real voices, where our MFCC gate has heard only the
corpus's synthetic ones.

:class:`PhoneStream` is the one way the phones are read, offline and live alike, so the two give
the same phones for the same audio:

* the audio (at the mapping's rate) is cut into blocks of one video frame (``sr / fps``
  samples), resampled to 16 kHz by one ``soxr.ResampleStream`` and fed to the decoder block by
  block;
* frame k (time k / fps) is labelled once the audio has reached (k + ``delay_frames``) / fps
  seconds, from the partial hypothesis (``Decoder.seg()``) at that moment: the segment covering
  the decoder's 10-ms frame ⌊100·k / fps⌋, silence when none covers it yet;
* at the end of the audio the frames still open are labelled from the final hypothesis.

With ``back`` > 0 each decision also keeps the *window* the hypothesis holds at that moment:
the phones of frames k − back … k + delay_frames (frames before 0 are silence), the past ones as
revised by then, the future ones as far as the audio so far has been heard. The window is what
the phone-input MLPs read (``mapping.mlp_input = "phones"``): a context of phones that costs no
latency beyond the decision's own look-ahead. Its column ``back`` is the frame's phone.

A live stream runs for hours, and the decoder's hypothesis (and the cost of reading it) grows
with its utterance, so the stream is cut into utterances at pauses: once an utterance is
``MIN_UTTERANCE_S`` long and its hypothesis ends in ``PAUSE_S`` of silence — or, without a
pause, once it is ``MAX_UTTERANCE_S`` long — the utterance ends there (its frames keep their
final phones) and the next starts on the following block. The rule reads only the hypothesis
of the blocks fed, so offline and live cut at the same blocks.

With ``delay_frames`` equal to the mapping's context look-ahead the phones cost no latency: the
MFCC window of frame k + look-ahead reaches further than the audio the decision waits for.
Every stream gets a fresh decoder (pocketsphinx's live cepstral mean carries over from one
utterance to the next in one decoder, which would make a phone depend on what was decoded
before). Phones are the 39 ARPAbet phones plus silence (noise fillers are silence), as indices
of the project's 44 classes (:data:`face_model.phones.PHONE_INDEX`).

Hearing a long recording takes minutes (its cost grows with its length):
:func:`recognise_windows` with ``progress`` (or inside :func:`progress_bars`) prints one line
of the cost measured on the first seconds and a bar of the audio heard, on stderr
(:func:`feed`); the phones are the same with it or without.

What a recogniser heard is kept twice: in memory for the last utterances (``_HEARD``), and,
inside :func:`hearing_cache`, in the content-keyed cache (:mod:`groundwork.cache`, kind
:data:`HEARD_KIND`), one entry per recording keyed by :func:`windows_key` — the SHA-256 of the
audio's float32 bytes and rate (:func:`audio_digest`), the recogniser's name and version, every
setting the windows depend on and :data:`HEARD_VERSION` — so the same audio in two corpora, two
stages or two runs is heard once (:mod:`mapping.hearing` fills the entries on every core).
"""
from __future__ import annotations

import contextlib
import contextvars
import hashlib
import os
import sys
import time

import numpy as np
import soxr
from pocketsphinx import Decoder, get_model_path
from tqdm import tqdm

from face_model.phones import PHONE_INDEX, PHONES
from groundwork.audio import seconds_to_samples
from groundwork.cache import content_key
from groundwork.errors import ParameterError
from mapping import causal_front, front_net, hama_front
from mapping.block_stream import BlockStream

RECOGNISER_RATE = 16000  # Hz, the acoustic model's rate
RECOGNISER_FPS = 100  # the decoder's frames per second
DECODER_SETTINGS = {"lw": 2.0, "beam": 1e-20, "pbeam": 1e-20, "bestpath": False}
RECOGNISER_NAME = "pocketsphinx-5.1.1 allphone"
RECOGNISERS = ("pocketsphinx", "hama", "causal")  # mapping.config.RECOGNISER_NAMES
# a recogniser is named by one of RECOGNISERS, or, for the causal front end, by
# "causal:<model file>": the front end trained by a run's front_end stage (plain "causal" is the
# shipped model file, mapping.front_net.SHIPPED)
MODEL_SEPARATOR = ":"
SILENCE = PHONE_INDEX["sil"]
N_PHONES = len(PHONES)  # the 44 classes
MIN_UTTERANCE_S = 5.0  # an utterance may end at a pause once it is this long (s)
PAUSE_S = 0.3  # silence at the end of the hypothesis that makes a pause (s)
MAX_UTTERANCE_S = 30.0  # an utterance ends here without a pause (s)
_SAMPLES_PER_DECODER_FRAME = RECOGNISER_RATE // RECOGNISER_FPS
PROGRESS_STEP_S = 1.0  # seconds of audio fed between two updates of the progress bar
COST_SAMPLE_S = 2.0  # seconds of audio whose cost is measured for the cost line
# tqdm's bar of seconds of audio (total=samples, unit_scale=1 / sample rate)
AUDIO_BAR = ("{l_bar}{bar}| {n:.1f}/{total:.1f} s [{elapsed}<{remaining}, "
             "{rate_fmt}{postfix}]")
# whether recognise_windows shows its bar when not told (progress_bars sets it for a block)
_PROGRESS = contextvars.ContextVar("recogniser_progress", default=False)
# the content-keyed cache (groundwork.cache.ArrayCache) recognise_windows reads and fills, when
# one is set (hearing_cache)
_CACHE = contextvars.ContextVar("recogniser_cache", default=None)
HEARD_KIND = "heard"  # the cache's kind of entries of what a recogniser heard
# bump when what an entry holds changes for the same audio and settings (a stream's rule, the
# windows' layout): every entry keyed with the old value is then heard again
HEARD_VERSION = 1


def new_decoder() -> Decoder:
    """A fresh pocketsphinx decoder with the wheel's en-US model and phone language model."""
    model = get_model_path()
    return Decoder(hmm=os.path.join(model, "en-us", "en-us"),
                   allphone=os.path.join(model, "en-us-phone.lm.bin"),
                   samprate=RECOGNISER_RATE, loglevel="FATAL", **DECODER_SETTINGS)


def phone_index(word: str) -> int:
    """The class index of a recognised phone (fillers and unknown symbols are silence)."""
    w = word.lower()
    return PHONE_INDEX[w] if w in PHONE_INDEX else SILENCE


def to_pcm16(y: np.ndarray) -> bytes:
    """Float audio in [-1, 1] as little-endian 16-bit PCM bytes (clipped at full scale)."""
    return np.round(np.asarray(y, np.float64) * 32768).clip(-32768, 32767).astype("<i2").tobytes()


class PhoneStream(BlockStream):
    """Recognised phones per video frame of one audio stream (see the module docstring).

    Parameters
    ----------
    sample_rate : int
        The rate of the audio pushed (Hz); ``sample_rate / fps`` must be an integer.
    fps : int
        Video frames per second.
    delay_frames : int
        Frames of look-ahead before a frame's phone is decided (≥ 0).
    back : int
        Past frames in each decision's window (≥ 0; see the module docstring).
    """

    def __init__(self, sample_rate: int, fps: int = 30, delay_frames: int = 3, back: int = 0):
        if sample_rate <= 0 or fps <= 0 or sample_rate % fps:
            raise ParameterError(f"sample rate {sample_rate} Hz has no integer hop at {fps} fps")
        if isinstance(delay_frames, bool) or not isinstance(delay_frames, (int, np.integer)) \
                or delay_frames < 0:
            raise ParameterError(f"delay_frames must be a non-negative integer, got "
                                 f"{delay_frames!r}")
        if isinstance(back, bool) or not isinstance(back, (int, np.integer)) or back < 0:
            raise ParameterError(f"back must be a non-negative integer, got {back!r}")
        self._start(sample_rate, fps, delay_frames, back)
        self.hop = self.sample_rate // self.fps  # blocks of one hop each
        self.decoder = new_decoder()
        self.decoder.start_utt()
        self._resampler = (None if self.sample_rate == RECOGNISER_RATE else
                           soxr.ResampleStream(self.sample_rate, RECOGNISER_RATE, 1,
                                               dtype="float32", quality="HQ"))
        self._fed = 0  # samples (at RECOGNISER_RATE) fed to the decoder
        self._utt_start = 0  # the sample at which the current utterance starts
        self._closed: dict[int, int] = {}  # frame -> final phone, frames of ended utterances
        self.utterances = 1  # utterances begun

    def _feed(self, block: np.ndarray, last: bool = False) -> None:
        x = block if self._resampler is None else self._resampler.resample_chunk(block,
                                                                                 last=last)
        if len(x):
            self.decoder.process_raw(to_pcm16(x), full_utt=False)
            self._fed += len(x)

    def _segments(self) -> list:
        segs = self.decoder.seg()
        return [] if segs is None else [(s.start_frame, s.end_frame, phone_index(s.word))
                                        for s in segs]

    def _label(self, segs: list, k: int) -> int:
        """Frame k's phone: final when its instant lies in an ended utterance, else from the
        current utterance's hypothesis ``segs`` (silence where it does not reach)."""
        if k < 0:
            return SILENCE
        t = (k * RECOGNISER_RATE) // self.fps  # the frame's instant, in samples
        if t < self._utt_start:
            return self._closed.get(k, SILENCE)
        f = (t - self._utt_start) // _SAMPLES_PER_DECODER_FRAME
        for start, end, p in reversed(segs):  # the window sits at the end of the hypothesis
            if start <= f <= end:
                return p
            if end < f:
                break
        return SILENCE

    def _maybe_end_utterance(self, segs: list) -> None:
        """End the current utterance at a pause (or at its longest), keeping the final phones of
        the frames still to be read, and begin the next one (see the module docstring)."""
        length = (self._fed - self._utt_start) / RECOGNISER_RATE
        if length < MIN_UTTERANCE_S:
            return
        pause = bool(segs) and segs[-1][2] == SILENCE and \
            (segs[-1][1] - segs[-1][0] + 1) >= PAUSE_S * RECOGNISER_FPS
        if not pause and length < MAX_UTTERANCE_S:
            return
        self.decoder.end_utt()
        final = self._segments()
        first = max(0, len(self._windows) - self.back)
        last = -(-self._fed * self.fps // RECOGNISER_RATE)  # frames whose instant was fed
        self._closed = {k: self._label(final, k) for k in range(first, last + 1)}
        self._utt_start = self._fed
        self.decoder.start_utt()
        self.utterances += 1

    def _decide(self, segs: list) -> list[int]:
        """Decide the next frame: its window of phones under the hypothesis ``segs``."""
        k = len(self._windows)
        window = [self._label(segs, j) for j in range(k - self.back, k + self.delay + 1)]
        self._windows.append(window)
        return window

    def push_windows(self, chunk: np.ndarray) -> list[list[int]]:
        """Add mono samples (any length); return the windows of the frames newly decided."""
        out = []
        for block in self._blocks_of(chunk):
            self._feed(block)
            self._blocks += 1
            segs = self._segments()
            while len(self._windows) + self.delay <= self._blocks:
                out.append(self._decide(segs))
            self._maybe_end_utterance(segs)
        return out

    def flush_windows(self) -> list[list[int]]:
        """End of the audio: the windows of the remaining frames, from the final hypothesis."""
        rest = self._end()
        if rest is None:
            return []
        self._feed(rest, last=True)
        self.decoder.end_utt()
        segs = self._segments()
        return [self._decide(segs) for _ in range(len(self._windows), self.n_total)]


def label_windows(phones: np.ndarray, back: int, forward: int) -> np.ndarray:
    """Windows (n_frames, back + 1 + forward) of a labelled phone sequence (n_frames,): frame k's
    row holds the phones of frames k − back … k + forward, silence outside the utterance."""
    padded = np.pad(np.asarray(phones, np.int64), (back, forward), constant_values=SILENCE)
    return np.lib.stride_tricks.sliding_window_view(padded, back + 1 + forward).copy()


def phone_inputs(windows: np.ndarray) -> np.ndarray:
    """The one-hot code (n_frames, window · 44) of windows of phone indices (n_frames, window),
    frame-major: the phone-input MLPs' features."""
    w = np.asarray(windows)
    out = np.zeros((len(w), w.shape[1], N_PHONES), np.float32)
    np.put_along_axis(out, w[:, :, None], 1.0, axis=2)
    return out.reshape(len(w), -1)


def fit_length(labels: np.ndarray, n: int) -> np.ndarray:
    """``labels`` (or windows, frame-major) cut or extended (repeating the last) to ``n``
    frames, as the features are."""
    labels = np.asarray(labels)
    if len(labels) >= n:
        return labels[:n]
    return np.concatenate([labels, np.repeat(labels[-1:], n - len(labels), axis=0)])


def recogniser_name(recogniser: str = "pocketsphinx") -> str:
    """The model and version of a recogniser of :data:`RECOGNISERS` (for the causal front end,
    its model file's checksum: a retrained front end is another recogniser to every cache)."""
    kind, model = split_recogniser(recogniser)
    if kind == "causal":
        return front_net.front_name(model)
    return RECOGNISER_NAME if kind == "pocketsphinx" else hama_front.RECOGNISER_NAME


def split_recogniser(recogniser: str) -> tuple[str, str | None]:
    """``(kind, model file or None)`` of a recogniser's name: ``"hama"`` → ``("hama", None)``,
    ``"causal:front.npz"`` → ``("causal", "front.npz")``; anything else is the one-line
    :class:`ParameterError` of an unknown recogniser."""
    kind, sep, model = (recogniser.partition(MODEL_SEPARATOR) if isinstance(recogniser, str)
                        else (None, "", ""))
    if kind not in RECOGNISERS or (sep and (kind != "causal" or not model)):
        raise ParameterError(f"unknown recogniser {recogniser!r}; allowed: "
                             f"{', '.join(RECOGNISERS)} (or causal:<model file>)")
    return kind, (model or None)


def recogniser_speakers(recogniser: str) -> frozenset:
    """The speakers a recogniser of ours was trained on (the causal front end's model file
    records them; a score on one of them is *seen*); empty for pocketsphinx and hama, whose
    training speakers are not ours to know."""
    kind, model = split_recogniser(recogniser)
    if kind != "causal":
        return frozenset()
    return front_net.training_speakers(model)


def _check_recogniser(recogniser: str) -> None:
    split_recogniser(recogniser)


def phone_stream(recogniser: str, sample_rate: int, fps: int = 30, delay_frames: int = 3,
                 back: int = 0):
    """A fresh stream of the recogniser ``recogniser`` (:data:`RECOGNISERS`, or
    ``causal:<model file>``): a :class:`PhoneStream`, a :class:`mapping.hama_front.HamaStream`
    or a :class:`mapping.causal_front.CausalStream`, the same interface."""
    kind, model = split_recogniser(recogniser)
    if kind == "hama":
        return hama_front.HamaStream(sample_rate, fps, delay_frames, back)
    if kind == "causal":
        return causal_front.CausalStream(sample_rate, fps, delay_frames, back, model=model)
    return PhoneStream(sample_rate, fps, delay_frames, back)


def recognise_windows(y: np.ndarray, sample_rate: int, *, fps: int = 30, delay_frames: int = 3,
                      back: int = 0, recogniser: str = "pocketsphinx",
                      progress: bool | None = None) -> np.ndarray:
    """The window of phones (n_frames, back + 1 + delay_frames) of every frame of a whole
    utterance, exactly as the recogniser's stream fed the same audio live decides them;
    ``ceil(n_samples / hop)`` frames. Column ``back`` is each frame's phone. ``progress``: a
    cost line and a bar on stderr while the audio is heard (:func:`feed`; None: as
    :func:`progress_bars` says, off by default); the windows are the same either way. Read
    from (and written to) the cache of :func:`hearing_cache` when one is set."""
    y = np.ascontiguousarray(y, dtype=np.float32)
    key = windows_key(y, sample_rate, fps=fps, delay_frames=delay_frames, back=back,
                      recogniser=recogniser)
    if key not in _HEARD:
        def make() -> dict:
            return {"windows": hear_windows(y, sample_rate, fps=fps, delay_frames=delay_frames,
                                            back=back, recogniser=recogniser,
                                            progress=progress)}

        windows = heard_entry(key, make, ("windows",))["windows"]
        if len(_HEARD) >= _HEARD_SIZE:
            _HEARD.pop(next(iter(_HEARD)))
        _HEARD[key] = windows
    return _HEARD[key].copy()


def hear_windows(y: np.ndarray, sample_rate: int, *, fps: int = 30, delay_frames: int = 3,
                 back: int = 0, recogniser: str = "pocketsphinx",
                 progress: bool | None = None) -> np.ndarray:
    """:func:`recognise_windows` heard now: a fresh stream fed all of ``y``, no memo, no
    cache (what an entry of the cache holds)."""
    stream = phone_stream(recogniser, sample_rate, fps, delay_frames, back)
    feed(stream, np.ascontiguousarray(y, dtype=np.float32), sample_rate, name=recogniser,
         progress=_PROGRESS.get() if progress is None else progress)
    return stream.windows


def audio_digest(y: np.ndarray, sample_rate: int) -> str:
    """The SHA-256 of mono audio's float32 bytes and its rate (Hz): what a cache key of heard
    audio names it by."""
    h = hashlib.sha256(np.ascontiguousarray(y, dtype=np.float32).tobytes())
    h.update(f"/{int(sample_rate)} Hz".encode("ascii"))
    return h.hexdigest()


def windows_key(y: np.ndarray, sample_rate: int, *, fps: int = 30, delay_frames: int = 3,
                back: int = 0, recogniser: str = "pocketsphinx") -> str:
    """The cache key of :func:`recognise_windows`' windows of audio ``y``: its
    :func:`audio_digest`, the recogniser's name and version (:func:`recogniser_name`), ``fps``,
    ``delay_frames``, ``back`` and :data:`HEARD_VERSION`."""
    return content_key("windows", HEARD_VERSION, recogniser_name(recogniser),
                       audio_digest(y, sample_rate),
                       {"fps": int(fps), "delay_frames": int(delay_frames), "back": int(back)})


@contextlib.contextmanager
def hearing_cache(cache):
    """Within the block, :func:`recognise_windows` (and :func:`heard_entry`) read and fill the
    content-keyed cache ``cache`` (a :class:`groundwork.cache.ArrayCache`; None: none)."""
    token = _CACHE.set(cache)
    try:
        yield cache
    finally:
        _CACHE.reset(token)


def active_cache():
    """The cache of the enclosing :func:`hearing_cache` block (None outside one)."""
    return _CACHE.get()


def heard_entry(key: str, make, names) -> dict:
    """The arrays ``make()`` gives (``{name: ndarray}``, holding every one of ``names``), read
    from the entry ``key`` of :data:`HEARD_KIND` in the :func:`active_cache` or made once into
    it; with no cache, ``make()``'s. An entry that cannot be read, or lacks one of ``names``,
    is made again."""
    cache = _CACHE.get()
    if cache is None:
        return make()
    arrays = cache.get_or_make(HEARD_KIND, key, make)
    if not set(names) <= set(arrays):  # written by other code under the same key: replace it
        arrays = make()
        with contextlib.suppress(OSError):
            cache.put(HEARD_KIND, key, arrays)
    return arrays


@contextlib.contextmanager
def progress_bars(on: bool = True):
    """Within the block, :func:`recognise_windows` called without ``progress`` shows its cost
    line and bar when ``on`` (for a caller that reaches it through other code, e.g.
    :meth:`mapping.checkpoint.AudioMapping.predict_audio`)."""
    token = _PROGRESS.set(bool(on))
    try:
        yield
    finally:
        _PROGRESS.reset(token)


def cost_line(name: str, audio_s: float, work_per_s: float, measured_s: float) -> str:
    """One line of what hearing ``audio_s`` seconds of audio will cost at ``work_per_s``
    seconds of work per second of audio, as measured on the first ``measured_s`` seconds."""
    total = audio_s * work_per_s
    about = f"{total:.0f} s" if total < 90 else f"{total / 60:.0f} min"
    return (f"{name}: {audio_s:.1f} s of audio, ~{work_per_s:.2f} s of work per s of audio "
            f"(about {about} on this machine, measured on the first {measured_s:.1f} s)")


def feed(stream, y: np.ndarray, sample_rate: int, *, name: str = "phones",
         progress: bool = False) -> None:
    """Push all of mono audio ``y`` at ``sample_rate`` Hz into a phone stream (a
    :class:`PhoneStream` or :class:`~mapping.hama_front.HamaStream`) and flush it.

    With ``progress`` the audio goes in steps of :data:`PROGRESS_STEP_S` seconds under a bar on
    stderr (seconds of audio heard), and once the first :data:`COST_SAMPLE_S` seconds are heard
    one line (:func:`cost_line`) gives their measured cost per second of audio and the time the
    whole will take at that rate. A stream decides from the blocks fed, never from how the
    chunks were cut (the streams' docstrings), so the windows are those of one push of the whole
    audio (tests/mapping/test_progress_front.py checks it)."""
    if not progress:
        stream.push_windows(y)
        stream.flush_windows()
        return
    first = min(len(y), max(1, seconds_to_samples(COST_SAMPLE_S, sample_rate)))
    step = max(1, seconds_to_samples(PROGRESS_STEP_S, sample_rate))
    with tqdm(total=len(y), unit=" s of audio", unit_scale=1 / sample_rate, desc=name,
              bar_format=AUDIO_BAR, file=sys.stderr) as bar:
        t0 = time.perf_counter()
        stream.push_windows(y[:first])
        spent = time.perf_counter() - t0
        bar.update(first)
        if first:
            bar.write(cost_line(name, len(y) / sample_rate, spent * sample_rate / first,
                                first / sample_rate), file=sys.stderr)
        for i in range(first, len(y), step):
            stream.push_windows(y[i:i + step])
            bar.update(min(step, len(y) - i))
        stream.flush_windows()


# the windows of the last utterances recognised, by recogniser, settings and audio: scoring a
# recording asks for them more than once (the animation and the gate's classes), and a grid's
# models with the same recogniser and context hear the same phones
_HEARD: dict = {}
_HEARD_SIZE = 512


def recognise(y: np.ndarray, sample_rate: int, *, fps: int = 30, delay_frames: int = 3,
              recogniser: str = "pocketsphinx") -> np.ndarray:
    """Phone index per frame of a whole utterance, exactly as the recogniser's stream fed the
    same audio live decides them; ``ceil(n_samples / hop)`` frames."""
    return recognise_windows(y, sample_rate, fps=fps, delay_frames=delay_frames,
                             recogniser=recogniser)[:, 0]
