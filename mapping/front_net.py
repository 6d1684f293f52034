"""The causal phone front end's network, features and model file (issue 40); its stream is
:mod:`mapping.causal_front`.

Features. Step s stands for the instant s · 10 ms of 16 kHz audio: its ``n_mels`` log-mel
energies are read from a 25-ms periodic-Hann window ending :data:`MARGIN` samples (0.5 ms)
before that instant (16 kHz samples [160 s − 408, 160 s − 8), zeros before the audio): a step
reads no audio after its instant, and the few samples soxr holds back until the next block never
delay a step past the block that reaches its instant. Power spectrum (512-point FFT), the
model's mel filters (HTK triangles up to ``mel_fmax_hz``), log with a floor of
:data:`LOG_FLOOR`, the training set's mean and std: all stored in the model file.
:func:`log_mel` is the same arithmetic offline, for training.

Net (weights from the model file, PyTorch's layouts, so torch-trained weights load directly):
causal Conv1d(n_mels → H, kernel 5) → ReLU → causal Conv1d(H → H, kernel 3, dilation 2) → ReLU →
GRU(H) (torch.nn.GRU's gates, order r, z, n) → Linear(H → 44 · (L + 1)). Head l = 0 … L
(L = ``lookahead_ms`` / 10) at step s scores the phone of instant (s − l) · 10 ms: it has heard
l · 10 ms past the instant it names. The causal convolutions see zeros before the first step.

Model file (:func:`write_front` / :func:`read_front`, :mod:`groundwork.modelfile` kind
:data:`KIND`): the weights, the mel filters and the normalisation, with a record of the
settings, the training speakers and the teacher. :func:`front_name` names a file by its
checksum, so retrained weights change every cache key that carries it.
"""
from __future__ import annotations

from pathlib import Path

import librosa
import numpy as np
from scipy.special import expit

from face_model.phones import PHONE_INDEX, PHONES
from groundwork.errors import ParameterError
from groundwork.modelfile import ModelFileError, checksum, manifest, read_model, write_model

RATE = 16000  # Hz, the net's audio rate
HOP = 160  # 16 kHz samples per step (10 ms)
STEPS_PER_S = RATE // HOP  # 100
WIN = 400  # samples of a step's window (25 ms)
N_FFT = 512
MARGIN = 8  # samples between a step's window end and its instant (0.5 ms; see the docstring)
LOG_FLOOR = 1e-6
RESAMPLE_QUALITY = "QQ"  # soxr's quick resampler: no filter delay
K1, K2, DILATION2 = 5, 3, 2  # the two causal convolutions' kernels and the second's dilation
CONTEXT = K1 - 1  # past inputs each convolution keeps (4 = (K2 - 1) · DILATION2 as well)
MAX_LOOKAHEAD_MS = 100
N_CLASSES = len(PHONES)  # 44
SILENCE = PHONE_INDEX["sil"]
KIND, VERSION = "phone_front", 1
NAME = f"causal-front v{VERSION}"
SHIPPED = Path(__file__).parent / "models" / "causal_front.npz"
WEIGHTS = ("conv1_w", "conv1_b", "conv2_w", "conv2_b", "gru_w_ih", "gru_w_hh", "gru_b_ih",
           "gru_b_hh", "head_w", "head_b")
ARRAYS = ("mel_filters", "mel_mean", "mel_std") + WEIGHTS
_WINDOW = np.hanning(WIN + 1)[:-1].astype(np.float32)  # periodic Hann


# -- features ------------------------------------------------------------------------------------

def mel_filters(n_mels: int = 40, fmax: float = RATE / 2) -> np.ndarray:
    """HTK-scale triangular filters (n_mels, N_FFT // 2 + 1) float32, unnormalised, 0 Hz to
    ``fmax`` Hz, librosa's as :mod:`mapping.filterbank` builds its own."""
    return librosa.filters.mel(sr=RATE, n_fft=N_FFT, n_mels=int(n_mels), fmin=0.0,
                               fmax=float(fmax), htk=True, norm=None).astype(np.float32)


def n_steps(n16: int) -> int:
    """Steps of ``n16`` samples of 16 kHz audio: every s ≥ 0 whose window ends inside it."""
    return (int(n16) + MARGIN) // HOP + 1


def frames_log_mel(frames: np.ndarray, filters: np.ndarray) -> np.ndarray:
    """Log-mel energies (n, n_mels) float32 of windows of 16 kHz audio (n, :data:`WIN`)."""
    spec = np.fft.rfft(np.asarray(frames, np.float32) * _WINDOW, n=N_FFT, axis=1)
    power = (spec.real ** 2 + spec.imag ** 2).astype(np.float32)
    return np.log(np.maximum(power @ filters.T, np.float32(LOG_FLOOR)))


def log_mel(y16: np.ndarray, filters: np.ndarray) -> np.ndarray:
    """The log-mel energies (:func:`n_steps`, n_mels) float32 of a whole 16 kHz utterance, the
    stream's arithmetic (unnormalised): row s is read from samples [160 s − 408, 160 s − 8)."""
    y = np.asarray(y16, np.float32).reshape(-1)
    n = n_steps(len(y))
    padded = np.concatenate([np.zeros(WIN + MARGIN, np.float32), y])
    frames = np.lib.stride_tricks.sliding_window_view(padded, WIN)[::HOP][:n]
    return frames_log_mel(frames, filters)


# -- the net ---------------------------------------------------------------------------------------

class Front:
    """A loaded front end: its arrays (see :func:`random_front`), record and forward pass.

    Parameters
    ----------
    arrays : dict str → ndarray
        :data:`ARRAYS`, float32, in PyTorch's layouts (Conv1d ``(out, in, kernel)``, GRU
        ``(3H, in)`` in gate order r, z, n, Linear ``(out, in)``).
    metadata : dict
        The record; ``lookahead_ms`` is read from it.
    name : str
        :func:`front_name`'s text.
    """

    def __init__(self, arrays: dict, metadata: dict, name: str, where: str = "phone front"):
        a = {k: np.asarray(arrays[k], np.float32) for k in ARRAYS if k in arrays}
        missing = [k for k in ARRAYS if k not in a]
        if missing:
            raise ParameterError(f"{where}: arrays {missing} missing; a phone front holds "
                                 f"{', '.join(ARRAYS)}")
        look = metadata.get("lookahead_ms")
        if isinstance(look, bool) or not isinstance(look, int) or not 0 <= look <= \
                MAX_LOOKAHEAD_MS or look % 10:
            raise ParameterError(f"{where}: lookahead_ms is {look!r}; allowed: a multiple of "
                                 f"10 from 0 to {MAX_LOOKAHEAD_MS}")
        hidden, n_mels = a["conv1_w"].shape[:2] if a["conv1_w"].ndim == 3 else (0, 0)
        self.heads = look // 10 + 1
        shapes = {"mel_filters": (n_mels, N_FFT // 2 + 1), "mel_mean": (n_mels,),
                  "mel_std": (n_mels,), "conv1_w": (hidden, n_mels, K1), "conv1_b": (hidden,),
                  "conv2_w": (hidden, hidden, K2), "conv2_b": (hidden,),
                  "gru_w_ih": (3 * hidden, hidden), "gru_w_hh": (3 * hidden, hidden),
                  "gru_b_ih": (3 * hidden,), "gru_b_hh": (3 * hidden,),
                  "head_w": (N_CLASSES * self.heads, hidden),
                  "head_b": (N_CLASSES * self.heads,)}
        bad = [f"{k} {a[k].shape} (expected {s})" for k, s in shapes.items() if a[k].shape != s]
        if bad or not hidden:
            raise ParameterError(f"{where}: arrays of the wrong shape: {'; '.join(bad)}")
        if not all(np.all(np.isfinite(v)) for v in a.values()) or np.any(a["mel_std"] <= 0):
            raise ParameterError(f"{where}: weights not finite or a mel_std not positive")
        self.arrays, self.metadata, self.name = a, dict(metadata), name
        self.n_mels, self.hidden, self.lookahead_ms = int(n_mels), int(hidden), look
        # im2col layouts: row t·in + c of a (kernel · in, out) matrix is weight [out, c, t]
        self._w1 = np.ascontiguousarray(a["conv1_w"].transpose(2, 1, 0).reshape(-1, hidden))
        self._w2 = np.ascontiguousarray(a["conv2_w"].transpose(2, 1, 0).reshape(-1, hidden))
        self._w_ih = np.ascontiguousarray(a["gru_w_ih"].T)
        self._w_hh = np.ascontiguousarray(a["gru_w_hh"].T)
        self._w_head = np.ascontiguousarray(a["head_w"].T)
        self._inv_std = (1.0 / a["mel_std"]).astype(np.float32)

    def new_state(self) -> dict:
        """The state before the first step: zero convolution context, zero GRU state."""
        return {"x": np.zeros((CONTEXT, self.n_mels), np.float32),
                "a": np.zeros((CONTEXT, self.hidden), np.float32),
                "h": np.zeros(self.hidden, np.float32)}

    def normalise(self, mel: np.ndarray) -> np.ndarray:
        """Log-mel energies (n, n_mels) normalised by the training set's mean and std."""
        return (np.asarray(mel, np.float32) - self.arrays["mel_mean"]) * self._inv_std

    def forward(self, x: np.ndarray, state: dict | None = None) -> np.ndarray:
        """Scores (n, heads, 44) float32 (logits) of normalised features ``x`` (n, n_mels),
        continuing ``state`` (updated in place; None: a fresh one, as at the start)."""
        state = self.new_state() if state is None else state
        x = np.asarray(x, np.float32).reshape(-1, self.n_mels)
        n, H = len(x), self.hidden
        if not n:
            return np.zeros((0, self.heads, N_CLASSES), np.float32)
        xs = np.concatenate([state["x"], x])
        cols = np.concatenate([xs[t:t + n] for t in range(K1)], axis=1)
        a1 = np.maximum(cols @ self._w1 + self.arrays["conv1_b"], 0)
        a1s = np.concatenate([state["a"], a1])
        cols = np.concatenate([a1s[DILATION2 * t:DILATION2 * t + n] for t in range(K2)],
                              axis=1)
        a2 = np.maximum(cols @ self._w2 + self.arrays["conv2_b"], 0)
        gi = a2 @ self._w_ih + self.arrays["gru_b_ih"]
        h, out = state["h"], np.empty((n, H), np.float32)
        b_hh = self.arrays["gru_b_hh"]
        for i in range(n):
            gh = h @ self._w_hh + b_hh
            r = expit(gi[i, :H] + gh[:H])
            z = expit(gi[i, H:2 * H] + gh[H:2 * H])
            c = np.tanh(gi[i, 2 * H:] + r * gh[2 * H:])
            h = (1 - z) * c + z * h
            out[i] = h
        state["x"], state["a"], state["h"] = xs[-CONTEXT:], a1s[-CONTEXT:], h
        logits = out @ self._w_head + self.arrays["head_b"]
        return logits.reshape(n, self.heads, N_CLASSES)


def random_front(seed: int, n_mels: int = 40, hidden: int = 32,
                 lookahead_ms: int = 100) -> tuple[dict, dict]:
    """``(arrays, metadata)`` of an untrained net with seeded weights (PyTorch's default
    initialisation ranges), for tests: the normalisation maps log-mel energies of about −16
    (silence) to 2 (loud speech) into ±1."""
    rng = np.random.default_rng(seed)
    heads = lookahead_ms // 10 + 1

    def uniform(shape, fan_in):
        bound = 1 / np.sqrt(fan_in)
        return rng.uniform(-bound, bound, size=shape).astype(np.float32)

    arrays = {"mel_filters": mel_filters(n_mels),
              "mel_mean": np.full(n_mels, -7.0, np.float32),
              "mel_std": np.full(n_mels, 9.0, np.float32),
              "conv1_w": uniform((hidden, n_mels, K1), n_mels * K1),
              "conv1_b": uniform((hidden,), n_mels * K1),
              "conv2_w": uniform((hidden, hidden, K2), hidden * K2),
              "conv2_b": uniform((hidden,), hidden * K2),
              "gru_w_ih": uniform((3 * hidden, hidden), hidden),
              "gru_w_hh": uniform((3 * hidden, hidden), hidden),
              "gru_b_ih": uniform((3 * hidden,), hidden),
              "gru_b_hh": uniform((3 * hidden,), hidden),
              "head_w": 4 * uniform((N_CLASSES * heads, hidden), hidden),
              "head_b": uniform((N_CLASSES * heads,), hidden)}
    return arrays, {"n_mels": n_mels, "hidden": hidden, "lookahead_ms": lookahead_ms,
                    "mel_fmax_hz": RATE / 2, "seed": int(seed), "trained": False,
                    "training_speakers": [], "teacher": None, "corpora": []}


# -- the model file --------------------------------------------------------------------------------

def write_front(path, arrays: dict, metadata: dict) -> Path:
    """Write a front end's model file (kind :data:`KIND`, version :data:`VERSION`); the arrays
    are checked as :class:`Front` loads them, and the record gains ``phones`` (the class
    order)."""
    record = {**metadata, "phones": list(PHONES)}
    Front(arrays, record, "", where=str(path))
    return write_model(path, {k: np.asarray(arrays[k], np.float32) for k in ARRAYS}, record,
                       kind=KIND, version=VERSION)


def read_front(path) -> tuple[dict, dict]:
    """``(arrays, metadata)`` of a front end's model file (one-line
    :class:`~groundwork.modelfile.ModelFileError` for a missing, damaged or other file)."""
    mf = read_model(path, kind=KIND, versions=(VERSION,), what="phone front model file")
    if mf.metadata.get("phones") != list(PHONES):
        raise ModelFileError(f"{path}: its phone classes are not this version's "
                             f"{len(PHONES)} ({', '.join(PHONES[:3])}, …)")
    return mf.arrays, mf.metadata


def digest(arrays: dict, metadata: dict) -> str:
    """The SHA-256 a model file of these arrays and record carries (its checksum)."""
    arrays = {k: np.asarray(arrays[k], np.float32) for k in ARRAYS}
    record = {**metadata, "kind": KIND, "version": VERSION, "arrays": manifest(arrays)}
    return checksum(arrays, record)


def resolve(model=None) -> Path:
    """The model file meant by ``model``: None or "" → :data:`SHIPPED`, else the path; a
    missing file is a :class:`ParameterError` naming it."""
    path = SHIPPED if model is None or model == "" else Path(model)
    if not path.is_file():
        raise ParameterError(f"phone front model file {path} not found")
    return path


_LOADED: dict = {}  # (path, mtime, size) -> Front


def load(model=None) -> Front:
    """The :class:`Front` of a model file (:func:`resolve`), read once per file version (path,
    modification time, size); a :class:`Front` is returned as it is."""
    if isinstance(model, Front):
        return model
    path = resolve(model).resolve()
    st = path.stat()
    key = (str(path), st.st_mtime_ns, st.st_size)
    if key not in _LOADED:
        arrays, metadata = read_front(path)
        front = Front(arrays, metadata, f"{NAME} sha256:{digest(arrays, metadata)[:12]}",
                      where=str(path))
        for old in [k for k in _LOADED if k[0] == key[0]]:
            del _LOADED[old]
        _LOADED[key] = front
    return _LOADED[key]


def front_name(model=None) -> str:
    """``"causal-front v1 sha256:<12 hex digits of the model file's checksum>"``."""
    return load(model).name


def training_speakers(model=None) -> frozenset:
    """The speakers the front end's training audio came from (its model file's
    ``training_speakers``): a score on one of them is *seen*."""
    return frozenset(load(model).metadata.get("training_speakers") or ())


def make_front(arrays: dict, metadata: dict) -> Front:
    """A :class:`Front` of arrays and a record in memory, named as its file would be."""
    return Front(arrays, metadata, f"{NAME} sha256:{digest(arrays, metadata)[:12]}")
