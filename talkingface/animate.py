"""``talkingface animate`` and ``talkingface stream``: a face from any WAV file.

The trained mapping comes from ``--model`` (a run name, a run folder or a ``.tfmap`` file) or, by
default, from the most recent run under ``runs/`` that has a trained mapping. A run's model is
its voice-robust model (stage ``voices``, trained on many voices for real speech) when it has
one, else the paper's single-voice mapping (``mapping/<method>_utterance.tfmap``, which
``--model`` can name as a file).
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from face_model.atomic import atomic_file, check_output_file
from face_model.audio import read_wav
from face_model.errors import ParameterError
from face_model.keyframes import KeyframeModel, write_keyframe_tracks
from face_model.motion_units import MotionUnits
from face_model.movie import write_mp4
from face_model.render import FaceRenderer
from mapping.animator import FaceAnimator, StreamingAnimator
from mapping.checkpoint import AudioMapping
from talkingface.live import MicrophoneStats, microphone_chunks, run_stream, wav_chunks


CLIP_LEVEL = 0.999
CLIP_WARN_FRACTION = 0.001


def find_model(model: str | None, runs_dir="runs") -> tuple[Path, Path]:
    """``(mapping .tfmap, motion_units.npz)`` for ``--model`` (see the module docstring)."""
    runs = Path(runs_dir)
    if model is None:
        done = sorted(runs.glob("*/mapping/done.json"), key=lambda p: p.stat().st_mtime)
        if not done:
            raise ParameterError(
                f"no trained mapping under {runs}/: run `make replicate` (or `talkingface train "
                "--name NAME`) first, or pass --model with a run name or a .tfmap file")
        run = done[-1].parent.parent
    else:
        p = Path(model)
        if p.suffix == ".tfmap":
            if p.is_dir():
                raise ParameterError(f"--model {p} is a folder, not a .tfmap model file")
            if not p.is_file():
                raise ParameterError(f"--model {p}: file not found")
            return p, model_units(p)
        if p.is_file():
            raise ParameterError(f"--model {p} is not a .tfmap model file; give a run name, a "
                                 "run folder or a .tfmap file")
        run = p if p.is_dir() else runs / model
        if not (run / "mapping" / "done.json").is_file():
            raise ParameterError(f"--model {model}: no trained mapping in {run}/mapping (train "
                                 "it with `talkingface train --name NAME`)")
    try:
        done = json.loads((run / "mapping" / "done.json").read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise ParameterError(f"{run / 'mapping' / 'done.json'}: not valid JSON ({exc}); train "
                             "the run again") from None
    models = done.get("models", {})
    if not models:
        raise ParameterError(f"{run}/mapping holds no saved model")
    robust = voices_default(run)
    if robust is not None:  # the run's voice-robust model (stage voices) is the default
        return robust, run / "units" / "motion_units.npz"
    split = "utterance" if "utterance" in models else next(iter(models))
    return run / "mapping" / models[split], run / "units" / "motion_units.npz"



def voices_default(run: Path) -> Path | None:
    """The voice-robust model of a run (``voices/done.json``: its ``model`` child), if any."""
    done_file = run / "voices" / "done.json"
    if not done_file.is_file():
        return None
    try:
        done = json.loads(done_file.read_text(encoding="utf-8"))
        return run / "voices" / done["models"][done["model"]]["tfmap"]
    except (ValueError, UnicodeDecodeError, KeyError, TypeError) as exc:
        raise ParameterError(f"{done_file}: not a finished voices stage ({exc!r}); make the "
                             "run's voices stage again (talkingface replicate --name NAME)") \
            from None


def model_units(tfmap: Path) -> Path:
    """The Motion Units of the run a ``.tfmap`` belongs to: ``<run>/mapping/x.tfmap`` or a
    voice-robust model ``<run>/voices/<child>/x.tfmap``."""
    for run in (tfmap.parent.parent, tfmap.parent.parent.parent):
        units = run / "units" / "motion_units.npz"
        if units.is_file():
            return units
    raise ParameterError(f"--model {tfmap}: the Motion Units of its run "
                         f"({tfmap.parent.parent / 'units' / 'motion_units.npz'}) are missing")


def load_animator(model: str | None, runs_dir="runs"):
    tfmap, units = find_model(model, runs_dir)
    return FaceAnimator(AudioMapping.load(tfmap), MotionUnits.load(units)), tfmap


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
    existing output file is replaced only with ``overwrite``."""
    animator, tfmap = load_animator(model, runs_dir)
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
    t0 = time.perf_counter()
    mups, markers = animator.animate(y, sr, expression)
    renderer = FaceRenderer()
    fps = animator.mapping.fps
    write_mp4(out_mp4, (renderer.render(m) for m in markers), len(markers), renderer.size,
              fps=fps, audio_path=wav, progress=progress)
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
            "model": str(tfmap), "warning": warn}


def _streaming(model, expression, runs_dir):
    """A warmed-up StreamingAnimator (the first calls load code paths: not latency)."""
    animator, tfmap = load_animator(model, runs_dir)
    warm = StreamingAnimator(animator, expression)
    warm.push(np.zeros(animator.mapping.sample_rate // 5, np.float32))
    warm.flush()
    return StreamingAnimator(animator, expression), animator, tfmap


def _summary(stats, tfmap, warn) -> dict:
    return {**asdict(stats), "model": str(tfmap), "warning": warn}


def stream_file(wav, *, expression: str = "neutral", model: str | None = None, runs_dir="runs",
                chunk_s: float = 0.01, paced: bool = True, show: bool = False,
                on_frame=None) -> dict:
    """Play a WAV through the :class:`~mapping.animator.StreamingAnimator` in chunks of
    ``chunk_s`` seconds, paced in real time unless ``paced`` is False; returns the figures of
    :func:`talkingface.live.run_stream`."""
    stream, animator, tfmap = _streaming(model, expression, runs_dir)
    y, sr, warn = read_speech(wav)
    y = animator.mapping.at_model_rate(y, sr)
    stats = run_stream(stream, wav_chunks(y, stream.sr, chunk_s=chunk_s, paced=paced),
                       show=show, on_frame=on_frame)
    return _summary(stats, tfmap, warn)


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
