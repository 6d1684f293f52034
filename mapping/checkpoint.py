"""A trained mapping that turns audio into MUPs, saved as one self-describing file.

:class:`AudioMapping` holds the feature settings (sample rate, fps, MFCC count, deltas), a
trained method (:class:`~mapping.gated_mlp.GatedMLP` or a baseline) and the silence rule. It accepts
audio at any rate from 8 kHz to 192 kHz and resamples it to the training rate, so frame k is
always centred at k / fps seconds and the mel filters are the ones the method was trained with.

:meth:`AudioMapping.predict_audio` is the one audio → MUP entry point (the animator, the
streaming animator's frames, ``talkingface animate`` and the MLflow pyfunc model all go through
it or its :meth:`~AudioMapping.silence_fix`). Silence: frames whose analysis window is quieter
than ``silence_dbfs`` get the utterance MUPs of the neutral face (``rest_mups``: a closed,
neutral mouth) whatever the network says, so digital silence, far outside the training data,
gives a defined face. The expression MUPs are kept.

The file (``.tfmap``, format :data:`FORMAT`) is data, never code: one ``.npz`` holding a JSON
``header`` and the method's arrays (``mapper/...``, from the method's ``to_arrays``, see
:mod:`mapping.state`), with their SHA-256 in the header. Loading reads numbers and JSON only;
it refuses a truncated or damaged file, a member holding Python objects, a checksum mismatch
and the pickled models of formats /1 and /2 (never unpickled), naming the file.
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import zipfile
import zlib
from pathlib import Path

import numpy as np

from groundwork.audio import read_wav, resample
from groundwork.errors import ParameterError
from mapping.baselines import BASELINES, Baseline
from mapping.features import audio_features, check_align, frame_rms_dbfs
from mapping.gated_mlp import GatedMLP
from mapping.recogniser import fit_length, recognise_windows
from mapping.state import NUMERIC_KINDS, ArrayGroup

# /1: JSON header line + pickle; /2: the silence rule (rest_mups, silence_dbfs) in the header;
# /3: one .npz of numbers and a JSON header, nothing pickled (a model file is data, never code).
FORMAT_NAME, FORMAT_VERSION = "talkingface.mapping", 3
FORMAT = f"{FORMAT_NAME}/{FORMAT_VERSION}"
MAPPER = "mapper"  # the method's arrays are stored as "mapper/<its own name>"
ZIP_MAGIC = b"PK\x03\x04"
MIN_SR, MAX_SR = 8000, 192000


class AudioMapping:
    """Audio → MUPs per frame.

    Parameters
    ----------
    mapper : fitted mapping method
    sample_rate : int
        The rate of the training audio (Hz).
    fps, n_mfcc, deltas, window_align : the feature settings the method was trained with
        (``window_align``: :func:`mapping.features.aligned`; a model saved before it existed
        is "centre").
    rest_mups : array_like (n_utterance,)
        Utterance MUPs of the neutral face (:func:`rest_mups` of the Motion Units).
    silence_dbfs : float
        Frames quieter than this get ``rest_mups`` (a closed, neutral mouth).
    metadata : dict
        Anything worth keeping with the model (config, corpus hash, metrics).
    """

    def __init__(self, mapper, *, sample_rate: int, rest_mups, fps: int = 30, n_mfcc: int = 10,
                 deltas: bool = False, n_utterance: int = 7, silence_dbfs: float = -60.0,
                 metadata: dict | None = None, window_align: str = "centre"):
        self.mapper = mapper
        self.sample_rate = int(sample_rate)
        self.fps = int(fps)
        self.n_mfcc = int(n_mfcc)
        self.deltas = bool(deltas)
        check_align(window_align)
        self.window_align = window_align
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
                              deltas=self.deltas, align=self.window_align)

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
                                            back=m.context_back), n_frames)

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
        """Write the model as one ``.npz`` of numbers and a JSON header, never Python objects.

        Members: ``header`` (a JSON string: :data:`FORMAT`, the feature and silence settings,
        ``method``, ``expressions``, ``metadata``, the method's ``method_params`` from its
        ``to_arrays``, the ``arrays`` manifest of every array's dtype and shape, and their
        ``sha256``) and the method's arrays, each under ``mapper/`` + the method's own name.
        The file is written beside ``path`` and then moved over it, so a crash leaves the old
        file or the new one, never a part.
        """
        to_arrays = getattr(self.mapper, "to_arrays", None)
        if to_arrays is None:
            raise ParameterError(f"method {type(self.mapper).__name__} cannot be saved: it has "
                                 "no to_arrays()")
        own, params = to_arrays()
        # as they are: a Fortran-ordered array (Ridge's coef_) is stored and read back in that
        # order, so BLAS takes the same path and predictions stay identical to the last bit
        arrays = {f"{MAPPER}/{name}": np.asarray(a) for name, a in own.items()}
        bad = [n for n, a in arrays.items() if a.dtype.kind not in NUMERIC_KINDS]
        if bad:
            raise ParameterError(f"arrays {bad} of the method are not numeric; a model file "
                                 "holds numbers only")
        header = {"format": FORMAT, "sample_rate": self.sample_rate, "fps": self.fps,
                  "n_mfcc": self.n_mfcc, "deltas": self.deltas, "n_utterance": self.n_utterance,
                  "window_align": self.window_align,
                  "rest_mups": self.rest_mups.tolist(), "silence_dbfs": self.silence_dbfs,
                  "method": getattr(self.mapper, "name", type(self.mapper).__name__),
                  "expressions": list(self.expressions), "metadata": self.metadata,
                  "method_params": params,
                  "arrays": {n: {"dtype": a.dtype.str, "shape": list(a.shape)}
                             for n, a in sorted(arrays.items())},
                  "sha256": checksum(arrays)}
        text = json.dumps(header, sort_keys=True, default=_json_default)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        try:
            with open(tmp, "wb") as f:
                np.savez(f, allow_pickle=False, header=np.array(text), **arrays)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
        return path

    @classmethod
    def load(cls, path) -> "AudioMapping":
        """Read a model written by :meth:`save`.

        Nothing in the file is executed: the members are parsed as ``.npy`` arrays of numbers
        (a member holding Python objects is refused before it is read), the header is JSON,
        and the method is rebuilt by its ``from_arrays``. The format, the arrays' names, dtypes
        and shapes, and their SHA-256 are checked; every problem is a ParameterError naming
        the file.
        """
        path = Path(path)
        if not path.is_file():
            raise ParameterError(f"mapping model {path} not found")
        header, arrays = _read(path)
        method = header.get("method")
        if method == GatedMLP.name:
            estimator = GatedMLP
        elif method in BASELINES:
            estimator = Baseline
        else:
            raise ParameterError(f"{path}: unknown mapping method {method!r}; allowed: "
                                 f"{GatedMLP.name}, {', '.join(BASELINES)}")
        group = ArrayGroup({n[len(MAPPER) + 1:]: a for n, a in arrays.items()})
        try:
            mapper = estimator.from_arrays(group, header["method_params"])
            if mapper.name != method:
                raise ParameterError(f"the header names method {method!r} but its parameters "
                                     f"describe {mapper.name!r}")
            unused = group.unused()
            if unused:
                raise ParameterError(f"arrays {unused} belong to no part of the {method} model")
            model = cls(mapper, sample_rate=header["sample_rate"], fps=header["fps"],
                        n_mfcc=header["n_mfcc"], deltas=header["deltas"],
                        n_utterance=header["n_utterance"], rest_mups=header["rest_mups"],
                        silence_dbfs=header["silence_dbfs"], metadata=header["metadata"],
                        window_align=header.get("window_align", "centre"))
            if list(model.expressions) != header["expressions"]:
                raise ParameterError(f"the header lists expressions {header['expressions']} "
                                     f"but the method was trained on {list(model.expressions)}")
        except ParameterError as e:
            raise ParameterError(f"{path}: {e}") from e
        except (KeyError, TypeError, ValueError, IndexError, AttributeError, RuntimeError) as e:
            # a header that passes the format check but does not describe a model of it
            raise ParameterError(f"{path}: malformed {FORMAT} header ({type(e).__name__}: "
                                 f"{e})") from e
        return model


def checksum(arrays: dict) -> str:
    """SHA-256 (hex) of named arrays: each name, dtype, shape and values (in C order, whatever
    the memory layout), by name."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.asarray(arrays[name])
        h.update(json.dumps([name, a.dtype.str, list(a.shape)]).encode() + b"\n")
        h.update(a.tobytes(order="C"))
    return h.hexdigest()


def _json_default(obj):
    """JSON for numpy scalars and arrays; anything else (in ``metadata``) as its text."""
    if isinstance(obj, (np.integer, np.floating, np.bool_)):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)


def _read(path: Path) -> tuple[dict, dict]:
    """``(header, arrays)`` of a model file, checked (see :meth:`AudioMapping.load`)."""
    with open(path, "rb") as f:
        start = f.read(len(ZIP_MAGIC))
    if start != ZIP_MAGIC:
        if ZIP_MAGIC.startswith(start):
            raise ParameterError(f"{path}: not a talkingface mapping model: the file is empty or "
                                 f"truncated ({len(start)} bytes)")
        _refuse_old_or_foreign(path)
    members = {}
    try:
        with zipfile.ZipFile(path) as z:
            for info in z.infolist():
                name = info.filename[:-4] if info.filename.endswith(".npy") else None
                if name is None or name in members:
                    raise ParameterError(f"{path}: member {info.filename!r} is not one of the "
                                         "model's arrays")
                if info.compress_type != zipfile.ZIP_STORED:  # what save writes; no zip bomb
                    raise ParameterError(f"{path}: member {info.filename!r} is compressed; "
                                         "AudioMapping.save writes the arrays uncompressed")
                members[name] = _parse_npy(path, name, z.read(info))
    except (zipfile.BadZipFile, zipfile.LargeZipFile, NotImplementedError, EOFError, OSError,
            zlib.error) as e:
        raise ParameterError(f"{path}: the model file is truncated or damaged ({e}); save or "
                             "copy it again") from e
    header = _header(path, members.pop("header", None))
    manifest = header.get("arrays")
    if not isinstance(manifest, dict):
        raise ParameterError(f"{path}: the header has no array manifest")
    missing, extra = sorted(set(manifest) - set(members)), sorted(set(members) - set(manifest))
    if missing or extra:
        raise ParameterError(f"{path}: the arrays do not match the header (missing: "
                             f"{missing or 'none'}; not in the header: {extra or 'none'})")
    for name, a in members.items():
        entry = manifest[name]
        if not name.startswith(MAPPER + "/") or not isinstance(entry, dict) or (
                entry.get("dtype"), entry.get("shape")) != (a.dtype.str, list(a.shape)):
            raise ParameterError(f"{path}: array {name!r} is {a.dtype.str} {a.shape}, the header "
                                 f"says {entry!r}")
    if checksum(members) != header.get("sha256"):
        raise ParameterError(f"{path}: checksum mismatch: the arrays are not the ones saved "
                             f"(SHA-256 {checksum(members)}, header {header.get('sha256')!r}); "
                             "the file is damaged")
    return header, members


def _parse_npy(path: Path, name: str, data: bytes) -> np.ndarray:
    """One ``.npy`` member as an array of numbers (or the header's string): its dtype is read
    from the ``.npy`` header first, and anything holding Python objects is refused unread."""
    buf = io.BytesIO(data)
    try:
        version = np.lib.format.read_magic(buf)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(buf)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(buf)
        else:
            raise ValueError(f"unsupported .npy version {version}")
    except ValueError as e:
        raise ParameterError(f"{path}: member {name!r} is not a numpy array ({e})") from e
    if dtype.hasobject:
        raise ParameterError(f"{path}: array {name!r} holds pickled Python objects; a model "
                             "file may hold numbers only, so it is not loaded (loading it could "
                             "run code)")
    allowed = "U" if name == "header" else NUMERIC_KINDS
    if dtype.kind not in allowed or (name == "header" and shape != ()):
        raise ParameterError(f"{path}: array {name!r} has dtype {dtype} {shape}; allowed: "
                             + ("one string" if name == "header" else "numbers"))
    size = int(np.prod(shape, dtype=object)) * dtype.itemsize  # Python ints: no overflow
    if size != len(data) - buf.tell():  # checked before read_array allocates the array
        raise ParameterError(f"{path}: array {name!r} should hold {size} bytes, the file has "
                             f"{len(data) - buf.tell()}; the file is damaged")
    buf.seek(0)
    try:
        return np.lib.format.read_array(buf, allow_pickle=False)
    except ValueError as e:
        raise ParameterError(f"{path}: array {name!r} is truncated or damaged ({e})") from e


def _header(path: Path, member) -> dict:
    """The JSON header of a model file, its format checked."""
    if member is None:
        raise ParameterError(f"{path}: not a talkingface mapping model (no header; expected "
                             f"format {FORMAT!r})")
    try:
        header = json.loads(str(member[()]))
    except (json.JSONDecodeError, RecursionError) as e:
        raise ParameterError(f"{path}: not a talkingface mapping model (its header is not "
                             f"JSON: {e})") from e
    fmt = header.get("format") if isinstance(header, dict) else None
    if fmt != FORMAT:
        _refuse_format(path, fmt)
    return header


def _refuse_old_or_foreign(path: Path):
    """A file that is not a zip: an old header + pickle model (never unpickled), or another."""
    with open(path, "rb") as f:
        first = f.readline(1 << 20)
    try:
        header = json.loads(first)
    except (json.JSONDecodeError, UnicodeDecodeError):
        header = None
    _refuse_format(path, header.get("format") if isinstance(header, dict) else None)
    raise ParameterError(f"{path}: not a talkingface mapping model (not an .npz archive)")


def _refuse_format(path: Path, fmt):
    """The ParameterError for a file of format ``fmt`` (not :data:`FORMAT`)."""
    version = fmt[len(FORMAT_NAME) + 1:] if isinstance(fmt, str) and fmt.startswith(
        FORMAT_NAME + "/") else None
    if version in ("1", "2"):
        parts = path.resolve().parts
        name = parts[-3] if len(parts) >= 3 and parts[-2] == "mapping" else "NAME"
        raise ParameterError(f"{path} was saved by an older version that stored Python objects "
                             f"(format {fmt!r}); re-train it with `talkingface train --name "
                             f"{name}` (it is not loaded: loading it could run code)")
    if version is not None and version.isdigit() and int(version) > FORMAT_VERSION:
        raise ParameterError(f"{path} was saved by a newer version of talkingface (format "
                             f"{fmt!r}; this version reads {FORMAT!r}); update talkingface")
    if fmt != FORMAT:
        raise ParameterError(f"{path}: not a talkingface mapping model (expected format "
                             f"{FORMAT!r}, got {fmt!r})")


def rest_mups(units) -> np.ndarray:
    """Utterance MUPs (A0,) of zero deformation, the neutral face, under ``units``."""
    return units.transform(np.zeros((1, units.mean_.shape[0])))[0, :units.n_utterance]
