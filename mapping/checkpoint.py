"""A trained mapping that turns audio into MUPs, saved as one self-describing file.

:class:`AudioMapping` holds the feature settings (sample rate, fps, MFCC count, deltas), a
trained method (:class:`~mapping.gated.GatedMLP` or a baseline) and the silence rule. It accepts
audio at any rate from 8 kHz to 192 kHz and resamples it to the training rate, so frame k is
always centred at k / fps seconds and the mel filters are the ones the method was trained with.

:meth:`AudioMapping.predict_audio` is the one audio → MUP entry point (the animator, the
streaming animator's frames, ``talkingface animate`` and the MLflow pyfunc model all go through
it or its :meth:`~AudioMapping.silence_fix`). Silence: frames whose analysis window is quieter
than ``silence_dbfs`` get the utterance MUPs of the neutral face (``rest_mups``: a closed,
neutral mouth) whatever the network says, so digital silence, far outside the training data,
gives a defined face. The expression MUPs are kept.
"""
from __future__ import annotations

import io
import json
import pickle
from pathlib import Path

import numpy as np

from face_model.audio import read_wav, resample
from face_model.errors import ParameterError
from mapping.features import audio_features, frame_rms_dbfs

FORMAT = "talkingface.mapping/2"  # /2: the silence rule (rest_mups, silence_dbfs) in the header
MIN_SR, MAX_SR = 8000, 192000


class AudioMapping:
    """Audio → MUPs per frame.

    Parameters
    ----------
    mapper : fitted mapping method
    sample_rate : int
        The rate of the training audio (Hz).
    fps, n_mfcc, deltas : the feature settings the method was trained with.
    rest_mups : array_like (n_utterance,)
        Utterance MUPs of the neutral face (:func:`rest_mups` of the Motion Units).
    silence_dbfs : float
        Frames quieter than this get ``rest_mups`` (a closed, neutral mouth).
    metadata : dict
        Anything worth keeping with the model (config, corpus hash, metrics).
    """

    def __init__(self, mapper, *, sample_rate: int, rest_mups, fps: int = 30, n_mfcc: int = 10,
                 deltas: bool = False, n_utterance: int = 7, silence_dbfs: float = -60.0,
                 metadata: dict | None = None):
        self.mapper = mapper
        self.sample_rate = int(sample_rate)
        self.fps = int(fps)
        self.n_mfcc = int(n_mfcc)
        self.deltas = bool(deltas)
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
        return audio_features(self.at_model_rate(y, sr), sr=self.sample_rate, fps=self.fps,
                              n_mfcc=self.n_mfcc, deltas=self.deltas)

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

    def predict_audio(self, y: np.ndarray, sr: int, expression: str = "neutral") -> np.ndarray:
        """MUPs (n_frames, A0 + Ak) with the silence rule; frame k is centred at k / fps s."""
        self.check_expression(expression)
        y_m = self.at_model_rate(y, sr)  # checked and resampled once
        feats = audio_features(y_m, sr=self.sample_rate, fps=self.fps, n_mfcc=self.n_mfcc,
                               deltas=self.deltas)
        est = self.mapper.predict(feats, expression)
        levels = frame_rms_dbfs(y_m, sr=self.sample_rate, fps=self.fps, n_frames=len(est))
        return self.silence_fix(est, levels)

    def predict_wav(self, path, expression: str = "neutral") -> np.ndarray:
        """MUPs of a WAV file (multi-channel files are mixed to mono)."""
        y, sr = read_wav(path, mix_to_mono=True)
        return self.predict_audio(y, sr, expression)

    # -- persistence -----------------------------------------------------------------------
    def save(self, path) -> Path:
        """One file: a JSON header line, then the pickled method (torch modules included)."""
        header = {"format": FORMAT, "sample_rate": self.sample_rate, "fps": self.fps,
                  "n_mfcc": self.n_mfcc, "deltas": self.deltas, "n_utterance": self.n_utterance,
                  "rest_mups": self.rest_mups.tolist(), "silence_dbfs": self.silence_dbfs,
                  "method": getattr(self.mapper, "name", type(self.mapper).__name__),
                  "expressions": list(self.expressions), "metadata": self.metadata}
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "wb") as f:
            f.write(json.dumps(header, sort_keys=True, default=str).encode() + b"\n")
            pickle.dump(self.mapper, f, protocol=pickle.HIGHEST_PROTOCOL)
        return path

    @classmethod
    def load(cls, path) -> "AudioMapping":
        path = Path(path)
        if not path.is_file():
            raise ParameterError(f"mapping model {path} not found")
        with open(path, "rb") as f:
            first = f.readline()
            try:
                header = json.loads(first)
            except (json.JSONDecodeError, UnicodeDecodeError):
                header = {}
            if header.get("format") != FORMAT:
                raise ParameterError(f"{path}: not a talkingface mapping model (expected format "
                                     f"{FORMAT!r}, got {header.get('format')!r})")
            mapper = pickle.load(io.BufferedReader(f))
        return cls(mapper, sample_rate=header["sample_rate"], fps=header["fps"],
                   n_mfcc=header["n_mfcc"], deltas=header["deltas"],
                   n_utterance=header["n_utterance"], rest_mups=header["rest_mups"],
                   silence_dbfs=header["silence_dbfs"], metadata=header["metadata"])


def rest_mups(units) -> np.ndarray:
    """Utterance MUPs (A0,) of zero deformation, the neutral face, under ``units``."""
    return units.transform(np.zeros((1, units.mean_.shape[0])))[0, :units.n_utterance]
