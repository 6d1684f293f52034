"""``talkingface animate`` and ``talkingface stream``: a face from any WAV file.

The trained mapping comes from ``--model``, found by :func:`talkingface.stages.models.find_model`
(a run name, a run folder or a ``.tfmap`` file; by default the most recent run with a trained
mapping, and a run's voice-robust model when it has one; with no trained run, the default model
shipped with the package). Both commands say which model they used
(:func:`talkingface.stages.models.model_label`).
"""
from __future__ import annotations

import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
from tqdm import tqdm

from face_model.keyframes import KeyframeModel, write_keyframe_tracks
from face_model.render import FaceRenderer
from groundwork.atomic import atomic_file, check_output_file
from groundwork.audio import read_wav
from groundwork.errors import ParameterError
from groundwork.movie import write_mp4
from talkingface.live import MicrophoneStats, microphone_chunks, run_stream, warm_stream, wav_chunks
from talkingface.stages.models import load_animator, model_label


PASSES_BAR = "{desc}: {percentage:3.0f}%|{bar}| {n}/{total} passes [{elapsed}{postfix}]"
CLIP_LEVEL = 0.999
CLIP_WARN_FRACTION = 0.001


def read_speech(path) -> tuple[np.ndarray, int, str | None]:
    """Mono float audio, its rate, and a warning when the file is clipped."""
    y, sr = read_wav(path, mix_to_mono=True)
    clipped = float(np.mean(np.abs(y) >= CLIP_LEVEL))
    warn = None
    if clipped > CLIP_WARN_FRACTION:
        warn = (f"{path}: {100 * clipped:.1f} % of the samples are clipped; the face follows "
                "the distorted sound")
    return y, sr, warn


def animate_file(wav, out_mp4, *, expression: str = "neutral", model: str | None = None,
                 markers_out=None, keyframes_out=None, runs_dir="runs",
                 progress: bool = True, overwrite: bool = False) -> dict:
    """WAV → MP4 (and optionally markers .npy and keyframe tracks); returns a summary. An
    existing output file is replaced only with ``overwrite``.

    With ``progress`` the passes report on stderr as they go: a bar over the two passes
    (:func:`passes`: the audio to MUPs, then the render) names the audio's length and frames
    and the pass under way; inside it the recogniser front end, when the model's gate has one,
    prints its cost measured on the first seconds of audio and its bar
    (:func:`mapping.recogniser.feed`), then the render shows its bar
    (:func:`groundwork.movie.write_mp4`). The outputs are the same either way."""
    animator, tfmap = load_animator(model, runs_dir, shipped=True)
    animator.check_expression(expression)
    # every output and input is checked before the render, so a mistake costs no work
    check_output_file(out_mp4, "--out", overwrite=overwrite)
    for path, what in ((markers_out, "--markers"), (keyframes_out, "--keyframes")):
        if path:
            check_output_file(path, what, overwrite=overwrite)
    keyframes = None
    if keyframes_out:
        if Path(keyframes_out).suffix not in (".json", ".csv"):
            raise ParameterError(f"--keyframes {keyframes_out}: keyframe tracks are written as "
                                 f".json or .csv, not {Path(keyframes_out).suffix!r}")
        kf_path = tfmap.parent.parent / "keyframes" / "keyframes.npz"
        if not kf_path.is_file():
            raise ParameterError(f"keyframes were not fitted for this run ({kf_path} missing); "
                                 "run `talkingface replicate` for it")
        keyframes = KeyframeModel.load(kf_path)
    y, sr, warn = read_speech(wav)
    desc, names = passes(animator, len(y), sr)
    t0 = time.perf_counter()
    with tqdm(total=len(names), desc=desc, bar_format=PASSES_BAR, file=sys.stderr,
              disable=not progress) as bar:
        bar.set_postfix_str(names[0])
        mups, markers = animator.animate(y, sr, expression, progress=progress)
        bar.update()
        bar.set_postfix_str(names[1])
        renderer = FaceRenderer()
        fps = animator.mapping.fps
        write_mp4(out_mp4, (renderer.render(m) for m in markers), len(markers), renderer.size,
                  fps=fps, audio_path=wav, progress=progress)
        bar.update()
    seconds = time.perf_counter() - t0
    if markers_out:
        with atomic_file(markers_out) as tmp, open(tmp, "wb") as f:
            np.save(f, markers.astype(np.float32))
    if keyframes is not None:
        write_keyframe_tracks(keyframes_out, keyframes.mups_to_keyframes(mups, expression), fps,
                              expression=expression, source=str(wav))
    duration = len(y) / sr
    return {"frames": len(markers), "audio_s": duration, "seconds": seconds,
            "x_realtime": duration / seconds if seconds > 0 else float("inf"),
            "model": model_label(tfmap), "warning": warn}


def passes(animator, n_samples: int, sr: int) -> tuple[str, list[str]]:
    """What ``talkingface animate`` does with ``n_samples`` of audio at ``sr`` Hz: the
    description of its bar (the audio's length and its frames, one per started 1 / fps s) and
    the names of its two passes, in order."""
    m = animator.mapping
    n = -(-n_samples * m.fps // sr)
    front = (f"the phones heard by {getattr(m.mapper, 'recogniser', 'pocketsphinx')}, "
             if m.needs_phones else "")
    return (f"animate {n_samples / sr:.1f} s of audio (~{n} frames at {m.fps} fps)",
            [f"{front}the network", "the render"])


def _streaming(model, expression, runs_dir):
    """A warmed-up StreamingAnimator (the first calls load code paths: not latency)."""
    animator, tfmap = load_animator(model, runs_dir, shipped=True)
    return warm_stream(animator, expression), animator, tfmap


def _summary(stats, tfmap, warn, announce: bool = True) -> dict:
    """A stream's figures and its model (said on stderr once the stream has ended, with
    ``announce``: the summary line of ``talkingface stream`` does not name it)."""
    if announce:
        print(f"model: {model_label(tfmap)}", file=sys.stderr)
    return {**asdict(stats), "model": model_label(tfmap), "warning": warn}


def stream_file(wav, *, expression: str = "neutral", model: str | None = None, runs_dir="runs",
                chunk_s: float = 0.01, paced: bool = True, show: bool = False,
                on_frame=None, progress: bool = True) -> dict:
    """Play a WAV through the :class:`~mapping.animator.StreamingAnimator` in chunks of
    ``chunk_s`` seconds, paced in real time unless ``paced`` is False; returns the figures of
    :func:`talkingface.live.run_stream` (``progress``: its cost line and bar on stderr; the
    frames are the same either way)."""
    stream, animator, tfmap = _streaming(model, expression, runs_dir)
    y, sr, warn = read_speech(wav)
    y = animator.mapping.at_model_rate(y, sr)
    stats = run_stream(stream, wav_chunks(y, stream.sr, chunk_s=chunk_s, paced=paced),
                       show=show, on_frame=on_frame, progress=progress,
                       total_samples=len(y), paced_input=paced)
    return _summary(stats, tfmap, warn, announce=progress)


def stream_microphone(*, expression: str = "neutral", model: str | None = None,
                      runs_dir="runs", seconds: float | None = None, device=None,
                      chunk_s: float = 0.01, show: bool = False, on_frame=None) -> dict:
    """Animate live from an input device (see :mod:`talkingface.live`) for ``seconds`` of
    audio or until Ctrl-C; returns the figures of :func:`talkingface.live.run_stream` plus the
    device, its rate and the number of input overflows (samples the device dropped)."""
    stream, _, tfmap = _streaming(model, expression, runs_dir)
    mic = MicrophoneStats()
    stats = run_stream(stream, microphone_chunks(stream.sr, seconds=seconds, device=device,
                                                 chunk_s=chunk_s, stats=mic),
                       show=show, on_frame=on_frame)
    stats.overflows = mic.overflows
    warn = (f"the input overflowed {mic.overflows} times: audio was lost"
            if mic.overflows else None)
    return {**_summary(stats, tfmap, warn), "device": mic.device, "device_rate": mic.rate}
