"""A trained mapping that turns audio into MUPs, saved as one self-describing file.

:class:`AudioMapping` holds the feature settings (sample rate, fps, MFCC count, deltas), a
trained method (:class:`~mapping.gated_mlp.GatedMLP` or a baseline) and the silence rule. It accepts
audio at any rate from 8 kHz to 192 kHz and resamples it to the training rate, so frame k is
always centred at k / fps seconds and the mel filters are the ones the method was trained with
(their upper edge, ``mel_fmax_hz``, included: a model whose edge is at or below 8 kHz reads
the same band from 16 kHz audio as from its training audio).

:meth:`AudioMapping.predict_audio` is the one audio → MUP entry point (the animator, the
streaming animator's frames, ``talkingface animate`` and the MLflow pyfunc model all go through
it or its :meth:`~AudioMapping.silence_fix`). Silence: frames whose analysis window is quieter
than ``silence_dbfs`` get the utterance MUPs of the neutral face (``rest_mups``: a closed,
neutral mouth) whatever the network says, so digital silence, far outside the training data,
gives a defined face. The expression MUPs are kept.

The file (``.tfmap``, kind ``audio_mapping``, version :data:`VERSION`) is data, never code: a
:mod:`groundwork.modelfile` holding the method's arrays (``mapper/...``, from the method's
``to_arrays``, see :mod:`mapping.state`) and a JSON metadata record, with a SHA-256 of both.
A mapping whose recogniser is a causal front end of its own model file (``causal:<file>``,
:mod:`mapping.causal_front`) keeps a copy of that file beside it (:func:`front_file`) and the
front end's checksummed name in its record; loading finds it there and refuses another.

Loading reads numbers and JSON only; it refuses a truncated or damaged file, a member holding
Python objects, a checksum mismatch and the pickled models of formats /1 and /2 (never
unpickled), naming the file. Files of format /3 (the record under ``header``) still load.
"""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np

from groundwork import modelfile
from groundwork.audio import read_wav, resample
from groundwork.errors import ParameterError
from mapping.baselines import BASELINES, Baseline
from mapping.features import audio_features, check_align, frame_rms_dbfs
from mapping.filterbank import check_mel_fmax
from mapping.gated_mlp import GatedMLP
from mapping.recogniser import fit_length, recognise_windows, recogniser_name, split_recogniser
from mapping.state import ArrayGroup

# Versions of the file (formats /1–/3 named themselves "talkingface.mapping/<n>"):
# /1: a JSON header line + a pickle; /2: the silence rule (rest_mups, silence_dbfs) in the header
#     (both refused unread: a model file is data, never code);
# /3: one .npz of numbers and a JSON ``header`` (``format``, the record, the array manifest and
#     the arrays' SHA-256), nothing pickled (still read);
# 4: a groundwork.modelfile: the record under ``metadata`` with kind, version, array manifest and
#    a SHA-256 of the arrays and the record (no ``format``).
KIND, VERSION = "audio_mapping", 4
FORMAT_NAME = "talkingface.mapping"
FORMAT_3, HEADER_3 = f"{FORMAT_NAME}/3", "header"  # the last format before the model file
WHAT = "talkingface mapping model"
MAPPER = "mapper"  # the method's arrays are stored as "mapper/<its own name>"
MIN_SR, MAX_SR = 8000, 192000


class AudioMapping:
    """Audio → MUPs per frame.

    Parameters
    ----------
    mapper : fitted mapping method
    sample_rate : int
        The rate of the training audio (Hz).
    fps, n_mfcc, deltas, window_align, mel_fmax_hz : the feature settings the method was
        trained with (``window_align``: :func:`mapping.features.aligned`; a model saved before
        it existed is "centre"; ``mel_fmax_hz``: the mel filterbank's upper edge in Hz, 0 for
        sr/2, :func:`mapping.filterbank.check_mel_fmax`; a model saved before it existed is 0).
    rest_mups : array_like (n_utterance,)
        Utterance MUPs of the neutral face (:func:`rest_mups` of the Motion Units).
    silence_dbfs : float
        Frames quieter than this get ``rest_mups`` (a closed, neutral mouth).
    metadata : dict
        Anything worth keeping with the model (config, corpus hash, metrics).
    """

    def __init__(self, mapper, *, sample_rate: int, rest_mups, fps: int = 30, n_mfcc: int = 10,
                 deltas: bool = False, n_utterance: int = 7, silence_dbfs: float = -60.0,
                 metadata: dict | None = None, window_align: str = "centre",
                 mel_fmax_hz: float = 0.0):
        self.mapper = mapper
        self.sample_rate = int(sample_rate)
        self.fps = int(fps)
        self.n_mfcc = int(n_mfcc)
        self.deltas = bool(deltas)
        check_align(window_align)
        self.window_align = window_align
        check_mel_fmax(mel_fmax_hz, self.sample_rate)
        self.mel_fmax_hz = float(mel_fmax_hz)
        self.n_utterance = int(n_utterance)
        self.rest_mups = np.asarray(rest_mups, dtype=np.float64)
        if self.rest_mups.shape != (self.n_utterance,):
            raise ParameterError(f"rest_mups must have shape ({self.n_utterance},), got "
                                 f"{self.rest_mups.shape}")
        self.silence_dbfs = float(silence_dbfs)
        self.metadata = dict(metadata or {})

    @property
    def expressions(self) -> tuple:
        m = self.mapper
        trained = getattr(m, "expressions_", None)
        if trained is None:
            trained = tuple(e for e in getattr(m, "models_", {}) if e != "neutral")
        return ("neutral", *trained)

    def at_model_rate(self, y: np.ndarray, sr: int) -> np.ndarray:
        """Mono float32 audio at the training rate (checked, resampled when needed)."""
        if not isinstance(sr, (int, np.integer)) or not MIN_SR <= sr <= MAX_SR:
            raise ParameterError(f"unsupported sample rate {sr!r} Hz; allowed: an integer from "
                                 f"{MIN_SR} to {MAX_SR} Hz (the model resamples to "
                                 f"{self.sample_rate} Hz)")
        y = np.asarray(y, dtype=np.float32)
        if y.ndim != 1:
            raise ParameterError(f"audio must be mono, shape (n_samples,), got {y.shape}")
        if sr == self.sample_rate:
            return y
        return resample(y, sr_in=int(sr), sr_out=self.sample_rate)

    def features(self, y: np.ndarray, sr: int) -> np.ndarray:
        """Raw per-frame features of mono audio ``y`` at ``sr`` Hz (resampled if needed)."""
        return self._features(self.at_model_rate(y, sr))

    def _features(self, y_m: np.ndarray) -> np.ndarray:
        """Raw per-frame features of audio already at the model's rate."""
        return audio_features(y_m, sr=self.sample_rate, fps=self.fps, n_mfcc=self.n_mfcc,
                              deltas=self.deltas, align=self.window_align,
                              mel_fmax_hz=self.mel_fmax_hz)

    @property
    def cmvn(self) -> str:
        """The features' causal cepstral normalisation: "none", "mean" or "meanvar"."""
        ctx = getattr(self.mapper, "context_", None)
        return getattr(ctx, "cmvn", "none")

    def normalized_features(self, y: np.ndarray, sr: int) -> np.ndarray:
        """The features the method's networks see, before context stacking: raw features →
        causal CMVN (if the model has it) → standardisation. (n_frames, n_features) float32;
        the streaming animator's frames carry the same rows."""
        return self.mapper.context_.normalize(self.features(y, sr))

    def check_expression(self, expression: str) -> str:
        if expression not in self.expressions:
            raise ParameterError(f"expression {expression!r} is not known to this model; "
                                 f"allowed: {', '.join(self.expressions)}")
        return expression

    def silence_fix(self, mups: np.ndarray, levels_dbfs: np.ndarray) -> np.ndarray:
        """``mups`` (float32 copy) with the neutral face's utterance MUPs on the frames whose
        level (dBFS) is below ``silence_dbfs``."""
        out = np.array(mups, dtype=np.float32, copy=True)
        quiet = np.asarray(levels_dbfs) < self.silence_dbfs
        out[quiet, : self.n_utterance] = self.rest_mups
        return out

    @property
    def needs_phones(self) -> bool:
        """True when the mapping's gate is the phone recogniser (:mod:`mapping.recogniser`)."""
        return bool(getattr(self.mapper, "needs_phones", False))

    def recognised_phones(self, y_m: np.ndarray, n_frames: int) -> np.ndarray | None:
        """The recogniser's windows of phones of audio at the model's rate, for the mapping's
        context and decided with its look-ahead as a live stream decides them (None when the
        gate does not use them)."""
        if not self.needs_phones:
            return None
        m = self.mapper
        if m.gate_front_end == "labels":
            raise ParameterError("this mapping is an oracle (gate_front_end 'labels'): it reads "
                                 "a corpus's true phone labels and cannot animate audio")
        return fit_length(recognise_windows(y_m, self.sample_rate, fps=self.fps,
                                            delay_frames=m.context_forward,
                                            back=m.context_back,
                                            recogniser=getattr(m, "recogniser",
                                                               "pocketsphinx")), n_frames)

    def gate_classes(self, y: np.ndarray, sr: int) -> np.ndarray:
        """The gate's class of every frame of mono audio (a gated mapping only)."""
        y_m = self.at_model_rate(y, sr)
        feats = self._features(y_m)
        return self.mapper.gate_classes(feats, self.recognised_phones(y_m, len(feats)))

    def predict_audio(self, y: np.ndarray, sr: int, expression: str = "neutral") -> np.ndarray:
        """MUPs (n_frames, A0 + Ak) with the silence rule; frame k is at k / fps s (its window
        centred there, or ending there: ``window_align``)."""
        self.check_expression(expression)
        y_m = self.at_model_rate(y, sr)  # checked and resampled once
        feats = self._features(y_m)
        if self.needs_phones:
            est = self.mapper.predict(feats, expression, self.recognised_phones(y_m, len(feats)))
        else:
            est = self.mapper.predict(feats, expression)
        levels = frame_rms_dbfs(y_m, sr=self.sample_rate, fps=self.fps, n_frames=len(est),
                                align=self.window_align)
        return self.silence_fix(est, levels)

    def predict_wav(self, path, expression: str = "neutral") -> np.ndarray:
        """MUPs of a WAV file (multi-channel files are mixed to mono)."""
        y, sr = read_wav(path, mix_to_mono=True)
        return self.predict_audio(y, sr, expression)

    # -- persistence -----------------------------------------------------------------------
    def save(self, path) -> Path:
        """Write the model as one model file (:mod:`groundwork.modelfile`) of numbers and JSON,
        never Python objects.

        Members: ``metadata`` (a JSON string: kind ``audio_mapping``, :data:`VERSION`, the
        feature and silence settings, ``method``, ``expressions``, ``metadata``, the method's
        ``method_params`` from its ``to_arrays``, the ``arrays`` manifest of every array's
        dtype and shape, and the ``sha256`` of the arrays and the record) and the method's
        arrays, each under ``mapper/`` + the method's own name. The file is written beside
        ``path`` and then moved over it, so a crash leaves the old file or the new one, never
        a part.
        """
        to_arrays = getattr(self.mapper, "to_arrays", None)
        if to_arrays is None:
            raise ParameterError(f"method {type(self.mapper).__name__} cannot be saved: it has "
                                 "no to_arrays()")
        own, params = to_arrays()
        # as they are: a Fortran-ordered array (Ridge's coef_) is stored and read back in that
        # order, so BLAS takes the same path and predictions stay identical to the last bit
        arrays = {f"{MAPPER}/{name}": np.asarray(a) for name, a in own.items()}
        record = {"sample_rate": self.sample_rate, "fps": self.fps,
                  "n_mfcc": self.n_mfcc, "deltas": self.deltas, "n_utterance": self.n_utterance,
                  "window_align": self.window_align, "mel_fmax_hz": self.mel_fmax_hz,
                  "rest_mups": self.rest_mups.tolist(), "silence_dbfs": self.silence_dbfs,
                  "method": getattr(self.mapper, "name", type(self.mapper).__name__),
                  "expressions": list(self.expressions), "metadata": self.metadata,
                  "method_params": params}
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        _keep_front(path, params, record)
        return modelfile.write_model(path, arrays, record, kind=KIND, version=VERSION,
                                     default=_json_default)

    @classmethod
    def load(cls, path) -> "AudioMapping":
        """Read a model written by :meth:`save`.

        Nothing in the file is executed: the members are parsed as ``.npy`` arrays of numbers
        (a member holding Python objects is refused before it is read), the record is JSON,
        and the method is rebuilt by its ``from_arrays``. The kind and version (or format /3),
        the arrays' names, dtypes and shapes, and their SHA-256 are checked; every problem is a
        ParameterError naming the file.
        """
        path = Path(path)
        if not path.is_file():
            raise ParameterError(f"mapping model {path} not found")
        record, arrays = _read(path)
        method = record.get("method")
        if method == GatedMLP.name:
            estimator = GatedMLP
        elif method in BASELINES:
            estimator = Baseline
        else:
            raise ParameterError(f"{path}: unknown mapping method {method!r}; allowed: "
                                 f"{GatedMLP.name}, {', '.join(BASELINES)}")
        group = ArrayGroup({n[len(MAPPER) + 1:]: a for n, a in arrays.items()})
        try:
            _find_front(path, record)
            mapper = estimator.from_arrays(group, record["method_params"])
            if mapper.name != method:
                raise ParameterError(f"the metadata names method {method!r} but its parameters "
                                     f"describe {mapper.name!r}")
            unused = group.unused()
            if unused:
                raise ParameterError(f"arrays {unused} belong to no part of the {method} model")
            model = cls(mapper, sample_rate=record["sample_rate"], fps=record["fps"],
                        n_mfcc=record["n_mfcc"], deltas=record["deltas"],
                        n_utterance=record["n_utterance"], rest_mups=record["rest_mups"],
                        silence_dbfs=record["silence_dbfs"], metadata=record["metadata"],
                        window_align=record.get("window_align", "centre"),
                        mel_fmax_hz=record.get("mel_fmax_hz", 0.0))
            if list(model.expressions) != record["expressions"]:
                raise ParameterError(f"the metadata lists expressions {record['expressions']} "
                                     f"but the method was trained on {list(model.expressions)}")
        except ParameterError as e:
            raise ParameterError(f"{path}: {e}") from e
        except (KeyError, TypeError, ValueError, IndexError, AttributeError, RuntimeError) as e:
            # a record that passes the format check but does not describe a model of it
            raise ParameterError(f"{path}: malformed {WHAT} record ({type(e).__name__}: "
                                 f"{e})") from e
        return model


def front_file(path) -> Path:
    """Where the causal front end's model file of the mapping ``path`` is kept: beside it,
    ``<stem>.front.npz``."""
    path = Path(path)
    return path.with_name(f"{path.stem}.front.npz")


def _keep_front(path: Path, params: dict, record: dict) -> None:
    """A mapping whose recogniser is a causal front end of its own model file
    (``causal:<file>``) keeps a copy of that file beside it (:func:`front_file`), named in
    ``params`` by its file name, with its checksum in ``record`` (``front_name``)."""
    kind, model = split_recogniser(params.get("recogniser", "pocketsphinx"))
    if kind != "causal" or model is None:
        return
    record["front_name"] = recogniser_name(params["recogniser"])
    target = front_file(path)
    if Path(model).resolve() != target.resolve():
        tmp = target.with_name(target.name + ".tmp")
        shutil.copyfile(model, tmp)
        os.replace(tmp, target)
    params["recogniser"] = f"causal:{target.name}"


def _find_front(path: Path, record: dict) -> None:
    """The inverse of :func:`_keep_front`: the recogniser ``causal:<file name>`` read back as
    the file beside ``path``, checked to be the front end the mapping was trained with."""
    params = record.get("method_params") or {}
    recogniser = params.get("recogniser") if isinstance(params, dict) else None
    if not isinstance(recogniser, str) or not recogniser.startswith("causal:"):
        return
    kept = path.parent / Path(recogniser.partition(":")[2]).name
    if not kept.is_file():
        raise ParameterError(f"its causal front end {kept} is missing (it is kept beside the "
                             "mapping)")
    params["recogniser"] = f"causal:{kept.resolve()}"
    if recogniser_name(params["recogniser"]) != record.get("front_name"):
        raise ParameterError(f"its causal front end {kept} is not the one it was trained with "
                             f"({record.get('front_name')!r})")


def _json_default(obj):
    """JSON for numpy scalars and arrays; anything else (in ``metadata``) as its text."""
    if isinstance(obj, (np.integer, np.floating, np.bool_)):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)


def _read(path: Path) -> tuple[dict, dict]:
    """``(record, arrays)`` of a model file of version 4 or format /3, checked (see
    :meth:`AudioMapping.load`)."""
    _refuse_pickled(path)
    found = modelfile.read_model(path, kind=KIND, versions=(VERSION,), what=WHAT,
                                 legacy=(HEADER_3,))
    record = dict(found.metadata)
    if found.legacy:  # format /3: its format, manifest and the arrays' SHA-256 in the header
        fmt = record.pop("format", None)
        if fmt != FORMAT_3:
            _refuse_format(path, fmt)
        modelfile.check_arrays(path, found.arrays, record.pop("arrays", None),
                               record.pop("sha256", None), member=HEADER_3)
    for name, a in found.arrays.items():
        if not name.startswith(MAPPER + "/"):
            raise ParameterError(f"{path}: array {name!r} is {a.dtype.str} {a.shape}, not one "
                                 f"of the method's (their names start with {MAPPER + '/'!r})")
    return record, found.arrays


def _refuse_pickled(path: Path):
    """Formats /1 and /2: a JSON header line, then a pickle (refused, never unpickled)."""
    with open(path, "rb") as f:
        if f.read(1) != b"{":  # a zip starts with "PK"
            return
        f.seek(0)
        first = f.readline(1 << 20)
    try:
        header = json.loads(first)
    except (json.JSONDecodeError, UnicodeDecodeError):
        header = None
    if isinstance(header, dict):
        _refuse_format(path, header.get("format"), where="a JSON header line, not an .npz "
                                                         "archive")


def _refuse_format(path: Path, fmt, *, where: str = f"expected format {FORMAT_3!r} in its "
                                                    f"{HEADER_3}"):
    """The ParameterError for a file of format ``fmt`` (not :data:`FORMAT_3`); the pickled
    formats /1 and /2 get their own."""
    version = fmt[len(FORMAT_NAME) + 1:] if isinstance(fmt, str) and fmt.startswith(
        FORMAT_NAME + "/") else None
    if version in ("1", "2"):
        parts = path.resolve().parts
        name = parts[-3] if len(parts) >= 3 and parts[-2] == "mapping" else "NAME"
        raise ParameterError(f"{path} was saved by an older version that stored Python objects "
                             f"(format {fmt!r}); re-train it with `talkingface train --name "
                             f"{name}` (it is not loaded: loading it could run code)")
    raise ParameterError(f"{path}: not a {WHAT} ({where}, got format {fmt!r})")


def rest_mups(units) -> np.ndarray:
    """Utterance MUPs (A0,) of zero deformation, the neutral face, under ``units``."""
    return units.transform(np.zeros((1, units.mean_.shape[0])))[0, :units.n_utterance]
