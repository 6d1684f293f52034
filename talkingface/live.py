"""``talkingface stream``: the real-time animator fed from a WAV file or a microphone.

Both sources deliver audio in chunks, each with the wall-clock time its last sample was
captured; :func:`run_stream` pushes them through a :class:`~mapping.animator.StreamingAnimator`,
shows the face if asked and measures:

* compute per frame (the animator's work for a chunk divided by the frames it emitted);
* latency of frame k: the wall-clock time it was emitted minus the time the instant ``k / fps``
  was captured. Capture times come from a clock origin fitted to the chunks (the earliest origin
  consistent with every chunk: a read can return late, never early), so the latency includes
  the look-ahead, the device buffering that delays reads, and the compute. It is only meaningful
  when the audio arrived in real time: a WAV played with ``--fast``, or a virtual device (the
  ALSA null device delivers silence as fast as it is read), is reported as not paced and its
  latency is not claimed.

With ``progress`` a stream of known length shows a bar of the audio streamed on stderr and,
once :data:`COST_SAMPLE_S` seconds have been pushed, one line of the animator's measured work
per second of audio and what the whole will take (:func:`cost_line`).

The microphone is read with ``sounddevice`` (PortAudio; the Debian package ``libportaudio2``)
in blocking reads of 16-bit samples at the mapping's sample rate, or at the device's own rate with streaming
resampling (``soxr``) when the device refuses that rate.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import numpy as np
import soxr
from tqdm import tqdm

from face_model.render import FaceRenderer
from groundwork.audio import seconds_to_samples
from groundwork.errors import ParameterError
from mapping.animator import StreamingAnimator
from mapping.recogniser import AUDIO_BAR


COST_SAMPLE_S = 2.0  # seconds of audio whose cost the cost line reports
WARM_S = 0.2  # seconds of silence pushed through a first animator, not measured


@dataclass
class StreamStats:
    frames: int
    audio_s: float
    wall_s: float
    paced: bool
    compute_p50_s: float
    compute_p99_s: float
    algorithmic_latency_s: float
    latency_p50_s: float | None
    latency_p99_s: float | None
    overflows: int = 0


def warm_stream(animator, expression: str = "neutral") -> StreamingAnimator:
    """A new :class:`~mapping.animator.StreamingAnimator` of ``animator`` once a first one has
    run :data:`WARM_S` s of silence (the first calls load code paths: not latency)."""
    warm = StreamingAnimator(animator, expression)
    warm.push(np.zeros(round(animator.mapping.sample_rate * WARM_S), np.float32))
    warm.flush()
    return StreamingAnimator(animator, expression)


def wav_chunks(y: np.ndarray, sr: int, *, chunk_s: float = 0.01, paced: bool = True):
    """``(chunk, capture_end_wall)`` pairs of a signal, slept to real time when ``paced``.

    Parameters
    ----------
    y : ndarray, shape (n_samples,)
        Mono audio.
    sr : int
        Sample rate, in Hz.
    chunk_s : float
        Seconds per chunk (at least one sample; the last chunk may be shorter).
    paced : bool
        Deliver each chunk when its last sample would have been captured in real time.

    Yields
    ------
    chunk : ndarray, shape (n,)
    capture_end_wall : float
        ``time.perf_counter()`` time at which the chunk's last sample was (or would have been)
        captured.
    """
    step = max(1, seconds_to_samples(chunk_s, sr))
    t0 = time.perf_counter()
    for i in range(0, len(y), step):
        chunk = y[i:i + step]
        due = t0 + (i + len(chunk)) / sr
        if paced:
            wait = due - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
        yield chunk, (due if paced else time.perf_counter())


def _sounddevice():
    try:
        import sounddevice
    except OSError as exc:  # the wheel is there but PortAudio is not
        raise ParameterError("the microphone needs the PortAudio library (Debian package "
                             "libportaudio2; `make test` and `make replicate` install it): "
                             f"{exc}") from None
    return sounddevice


def input_devices() -> list[dict]:
    """The audio input devices PortAudio sees: ``{"index", "name", "channels", "rate"}``."""
    sd = _sounddevice()
    return [{"index": i, "name": d["name"], "channels": d["max_input_channels"],
             "rate": d["default_samplerate"]}
            for i, d in enumerate(sd.query_devices()) if d["max_input_channels"] > 0]


class MicrophoneStats:
    """Counts what the device reported while it was read."""

    def __init__(self):
        self.overflows = 0
        self.rate = None
        self.device = None


def microphone_chunks(sr: int, *, seconds: float | None, device=None, chunk_s: float = 0.01,
                      stats: MicrophoneStats | None = None):
    """``(chunk, capture_end_wall)`` pairs from an input device, at ``sr`` Hz, mono.

    Parameters
    ----------
    sr : int
        Sample rate of the chunks, in Hz (the device is read at its own rate and resampled
        when it refuses this one).
    seconds : float or None
        Stop after this much captured audio (None: until KeyboardInterrupt).
    device : int, str or None
        A PortAudio device index or name (default: the system's default input).
    chunk_s : float
        Seconds per blocking read.
    stats : MicrophoneStats, optional
        Filled in with the device's name, its rate and the overflows it reported.

    Yields
    ------
    chunk : ndarray, shape (n,), float32
        In [-1, 1).
    capture_end_wall : float
        ``time.perf_counter()`` time at which the read returned.

    Raises
    ------
    ParameterError
        No input device, an unknown device, PortAudio missing, or ``seconds`` not > 0.
    """
    sd = _sounddevice()
    devices = input_devices()
    if not devices:
        raise ParameterError("no audio input device found (PortAudio lists none with input "
                             "channels); stream a WAV file instead: talkingface stream in.wav")
    if seconds is not None and not (np.isfinite(seconds) and seconds > 0):
        raise ParameterError(f"--seconds must be > 0, got {seconds!r}")
    try:
        info = sd.query_devices(device, kind="input")
    except (ValueError, sd.PortAudioError) as exc:
        names = ", ".join(f"{d['index']}: {d['name']}" for d in devices)
        raise ParameterError(f"input device {device!r}: {exc}; available: {names}") from None
    stats = MicrophoneStats() if stats is None else stats
    stats.device = info["name"]
    rate, resampler = sr, None
    try:
        sd.check_input_settings(device=device, channels=1, dtype="int16", samplerate=sr)
    except sd.PortAudioError:
        rate = int(info["default_samplerate"])
        resampler = soxr.ResampleStream(rate, sr, 1, dtype="float32")
    stats.rate = rate
    block = max(1, seconds_to_samples(chunk_s, rate))
    wanted = None if seconds is None else seconds_to_samples(seconds, rate)
    got = 0
    with sd.InputStream(device=device, channels=1, samplerate=rate, dtype="int16",
                        blocksize=block) as stream:
        while wanted is None or got < wanted:
            n = block if wanted is None else min(block, wanted - got)
            data, overflowed = stream.read(n)
            now = time.perf_counter()
            stats.overflows += int(bool(overflowed))
            got += len(data)
            chunk = data[:, 0].astype(np.float32) / 32768.0  # PCM16, as devices deliver it
            if resampler is not None:
                chunk = resampler.resample_chunk(chunk, last=wanted is not None and got >= wanted)
            yield np.ascontiguousarray(chunk, dtype=np.float32), now


def cost_line(audio_s: float, work_s: float, measured_s: float, paced: bool) -> str:
    """One line of what streaming ``audio_s`` seconds will cost, from ``work_s`` seconds of the
    animator's work on the first ``measured_s`` seconds of audio; a paced stream takes the
    audio's own duration."""
    per_s = work_s / measured_s
    total = audio_s if paced else audio_s * per_s
    about = f"{total:.0f} s" if total < 90 else f"{total / 60:.0f} min"
    return (f"stream: {audio_s:.1f} s of audio, ~{per_s:.2f} s of work per s of audio "
            f"(about {about}{', paced in real time' if paced else ''} on this machine, "
            f"measured on the first {measured_s:.1f} s)")


def run_stream(stream, chunks, *, show: bool = False, on_frame=None, progress: bool = False,
               total_samples: int | None = None, paced_input: bool = False) -> StreamStats:
    """Push ``(chunk, capture_end_wall)`` pairs through ``stream``, then flush it; see the
    module text for the figures.

    Parameters
    ----------
    stream : mapping.animator.StreamingAnimator
    chunks : iterable of (ndarray, float)
        :func:`wav_chunks` or :func:`microphone_chunks`: mono audio at ``stream.sr`` Hz and the
        wall-clock time its last sample was captured. Ctrl-C ends it (what was captured is
        still flushed).
    show : bool
        Show the face in a window as frames are emitted.
    on_frame : callable, optional
        Called with each emitted :class:`~mapping.animator.StreamFrame`.
    progress : bool
        A bar of the seconds of audio streamed and one cost line (:func:`cost_line`) on stderr;
        the frames are the same either way.
    total_samples : int, optional
        The length of the audio at ``stream.sr`` Hz, when known (the bar's total; the cost
        line needs it).
    paced_input : bool
        Whether the chunks come in real time (for the cost line only).

    Returns
    -------
    StreamStats
        Frames, audio and wall-clock seconds, compute per frame and latency percentiles (s).
    """
    renderer = None
    if show:
        renderer = FaceRenderer()
    fps, sr = stream.fps, stream.sr
    compute, emitted = [], []  # emitted: (frame index, wall time)
    origin, n_samples_in = np.inf, 0
    t_first = None
    work, cost_at = 0.0, seconds_to_samples(COST_SAMPLE_S, sr)  # the cost line's figures
    bar = tqdm(total=total_samples, unit=" s of audio", unit_scale=1 / sr, desc="stream",
               bar_format=AUDIO_BAR if total_samples else None, file=sys.stderr,
               disable=not progress)
    try:
        for chunk, t_end in chunks:
            if t_first is None:
                t_first = t_end - len(chunk) / sr
            n_samples_in += len(chunk)
            origin = min(origin, t_end - n_samples_in / sr)
            c0 = time.perf_counter()
            out = stream.push(chunk)
            now = time.perf_counter()
            compute.append((now - c0) / max(len(out), 1))
            for f in out:
                emitted.append((f.index, now))
                _deliver(f, on_frame, renderer)
            if progress and cost_at is not None:
                work += now - c0
                if n_samples_in >= min(cost_at, total_samples or cost_at):
                    if total_samples is not None:
                        bar.write(cost_line(total_samples / sr, work, n_samples_in / sr,
                                            paced_input), file=sys.stderr)
                    cost_at = None
            bar.update(len(chunk))
    except KeyboardInterrupt:
        pass  # Ctrl-C ends a microphone session; what was captured is still flushed
    finally:
        bar.close()
    for f in stream.flush():
        emitted.append((f.index, time.perf_counter()))
        _deliver(f, on_frame, renderer)
    audio_s = n_samples_in / sr
    wall_s = (time.perf_counter() - t_first) if t_first is not None else 0.0
    paced = audio_s > 0 and wall_s >= 0.8 * audio_s
    lat = np.array([t - (origin + k / fps) for k, t in emitted]) if emitted and paced else None
    comp = np.array(compute) if compute else np.zeros(1)
    return StreamStats(
        frames=len(emitted), audio_s=audio_s, wall_s=wall_s, paced=paced,
        compute_p50_s=float(np.percentile(comp, 50)), compute_p99_s=float(np.percentile(comp, 99)),
        algorithmic_latency_s=stream.latency_s,
        latency_p50_s=None if lat is None else float(np.percentile(lat, 50)),
        latency_p99_s=None if lat is None else float(np.percentile(lat, 99)))


def _deliver(frame, on_frame, renderer) -> None:
    if on_frame is not None:
        on_frame(frame)
    if renderer is not None:
        import cv2

        cv2.imshow("talkingface", cv2.cvtColor(renderer.render(frame.markers),
                                               cv2.COLOR_RGB2BGR))
        cv2.waitKey(1)
