"""The live latency of trained mappings, measured as ``talkingface stream`` measures it: a fixed
real recording pushed, paced in real time, through the same
:class:`~mapping.animator.StreamingAnimator` loop (:func:`talkingface.live.run_stream` fed
by :func:`talkingface.live.wav_chunks` with ``paced=True``).

The development rule weighs time with these figures: a model whose latency p99 exceeds
``targets.stream_latency_p99_ms`` (the paper's window plus one frame,
:data:`analysis.config.PAPER_STREAM_LATENCY_MS`) cannot be the default, whatever its accuracy
(:func:`analysis.dev_rule.dev_choice`, :func:`analysis.dev_rule.excluded_by_latency`).

Latency of frame k: the wall-clock time the animator emitted it minus the time the instant
``k / fps`` was captured, so it holds the look-ahead, half the analysis window, the chunking and
the compute. It is only meaningful when the audio arrives in real time, so every measurement is
paced: it costs the recording's length per model (:data:`RECORDING`: 4.0 s), plus loading the
model. The models are measured one after the other, never in parallel: on shared cores each
would add to the others' latency. Nothing in it is random (no seed); the figures vary with the
machine's load, as any wall-clock figure does.

The recording: ``analysis/real_speech/arctic/awb_a0007.wav`` (CMU ARCTIC, speaker awb, one
sentence of 4.0 s at 16 kHz), the one ``FIELD_NOTES`` measured the front ends on. Only its audio
is used, for timing: no label of it is read and no score is made, so no test figure enters the
choice (the development part's recordings are single digits under 2 s: too few frames for a
99th percentile).

File written by :func:`measure_models` (``runs/<name>/speech_eval/latency.json`` in the stage)::

    {"recording": path, "seconds": s, "chunk_s": s, "paced": true,
     "models": {name: {latency_p50_ms, latency_p99_ms, compute_p50_ms, compute_p99_ms,
                       algorithmic_latency_ms, paced, frames, recording, seconds, model}}}

``latency_*`` are None for a model whose stream was not paced (the machine fell behind by more
than the loop tolerates), which the rule counts as not measured.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from analysis.dev_rule import LATENCY_FILE
from analysis.speech_set import SET_DIR
from face_model.motion_units import MotionUnits
from groundwork.atomic import atomic_file
from groundwork.audio import read_wav
from groundwork.errors import ParameterError
from mapping.animator import FaceAnimator
from mapping.checkpoint import AudioMapping
from talkingface.live import run_stream, warm_stream, wav_chunks
from talkingface.stages.models import model_units

RECORDING = SET_DIR / "arctic" / "awb_a0007.wav"  # 4.0 s, 16 kHz: see the module docstring
CHUNK_S = 0.01  # seconds per chunk, as `talkingface stream` pushes them


def _shown(path: Path) -> str:
    """``path`` relative to the repository when inside it (the JSON names the recording)."""
    try:
        return str(Path(path).resolve().relative_to(SET_DIR.parents[1]))
    except ValueError:
        return str(path)


def _ms(seconds: float | None) -> float | None:
    return None if seconds is None else 1000.0 * float(seconds)


def measure_latency(tfmap_path, wav_path=RECORDING, *, units=None, chunk_s: float = CHUNK_S,
                    expression: str = "neutral") -> dict:
    """The live latency of one trained mapping on one recording, paced in real time.

    Parameters
    ----------
    tfmap_path : path-like
        A trained mapping (``.tfmap``, :meth:`mapping.checkpoint.AudioMapping.load`).
    wav_path : path-like
        The recording (default :data:`RECORDING`); mono or mixed to mono, any rate the model
        resamples from. Streaming it takes its own length.
    units : path-like, optional
        The Motion Units (``motion_units.npz``); default: the model's own
        (:func:`talkingface.stages.models.model_units`).
    chunk_s : float
        Seconds of audio per chunk, > 0.
    expression : str
        The expression the face is animated with.

    Returns
    -------
    dict
        ``latency_p50_ms``, ``latency_p99_ms`` (ms; None when the stream was not paced),
        ``compute_p50_ms``, ``compute_p99_ms`` (the animator's work per emitted frame, ms),
        ``algorithmic_latency_ms`` (the look-ahead and half the analysis window, ms),
        ``paced`` (bool), ``frames``, ``recording`` (its path), ``seconds`` (its length, s),
        ``model`` (the ``.tfmap`` path).

    Raises
    ------
    ParameterError
        A missing model or recording, or ``chunk_s`` not > 0.
    """
    tfmap, wav = Path(tfmap_path), Path(wav_path)
    if not (np.isfinite(chunk_s) and chunk_s > 0):
        raise ParameterError(f"chunk_s is {chunk_s!r}; allowed: a number of seconds > 0")
    for path, what in ((tfmap, "model"), (wav, "recording")):
        if not path.is_file():
            raise ParameterError(f"{path}: {what} file not found")
    units = Path(units) if units is not None else model_units(tfmap)
    animator = FaceAnimator(AudioMapping.load(tfmap), MotionUnits.load(units))
    animator.check_expression(expression)
    stream = warm_stream(animator, expression)
    y, sr = read_wav(wav, mix_to_mono=True)
    y = animator.mapping.at_model_rate(y, sr)
    stats = run_stream(stream, wav_chunks(y, stream.sr, chunk_s=chunk_s, paced=True))
    return {"latency_p50_ms": _ms(stats.latency_p50_s),
            "latency_p99_ms": _ms(stats.latency_p99_s),
            "compute_p50_ms": _ms(stats.compute_p50_s),
            "compute_p99_ms": _ms(stats.compute_p99_s),
            "algorithmic_latency_ms": _ms(stats.algorithmic_latency_s),
            "paced": bool(stats.paced), "frames": stats.frames,
            "recording": _shown(wav), "seconds": len(y) / stream.sr, "model": str(tfmap)}


def measure_models(models: dict, wav=RECORDING, out_json=None, *, chunk_s: float = CHUNK_S,
                   progress: bool = True) -> dict:
    """:func:`measure_latency` of every model, one after the other, into ``latency.json``.

    Parameters
    ----------
    models : dict
        Name (as in speech_eval's results, e.g. ``voices-hama``) → a ``.tfmap`` path, or a
        tuple whose first two items are the ``.tfmap`` and its ``motion_units.npz`` (the
        ``models`` of :func:`talkingface.stages.speech_eval.evaluate_models`).
    wav : path-like
        The recording (default :data:`RECORDING`); each model costs its length, paced.
    out_json : path-like, optional
        The file written (the module docstring gives its contents); a folder gets
        :data:`analysis.dev_rule.LATENCY_FILE` inside it. None: nothing written.
    chunk_s : float
        Seconds per chunk.
    progress : bool
        A bar over the models on stderr (its total: the models; each takes the recording's
        length).

    Returns
    -------
    dict
        What the file holds.
    """
    out = {}
    names = list(models)
    with tqdm(total=len(names), desc=f"live latency, {len(names)} models x the recording "
                                     "paced in real time", unit=" model", file=sys.stderr,
              disable=not progress) as bar:
        for name in names:
            bar.set_postfix_str(name)
            spec = models[name]
            tfmap, units = (spec[0], spec[1]) if isinstance(spec, (tuple, list)) else (spec,
                                                                                      None)
            out[name] = measure_latency(tfmap, wav, units=units, chunk_s=chunk_s)
            bar.update()
    res = {"recording": _shown(Path(wav)),
           "seconds": next((v["seconds"] for v in out.values()), None),
           "chunk_s": chunk_s, "paced": all(v["paced"] for v in out.values()), "models": out}
    if out_json is not None:
        path = Path(out_json)
        path = path / LATENCY_FILE if path.is_dir() else path
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_file(path) as tmp:
            Path(tmp).write_text(json.dumps(res, indent=1), encoding="utf-8")
    return res
