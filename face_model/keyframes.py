"""Keyframes and the conversion between MUPs and keyframe weights (§IV-B, Eqs. 3–4; §VII-B).

The paper's eight keyframes are ``smile``, ``sad`` and the visemes ``i a o f u m``. Each keyframe
κ'_i is picked from the training data by *semantic correspondence*:

* **viseme v** — neutral-speech frames at the centre of phone segments whose viseme is v (the
  frame nearest the segment's midpoint, kept only if it lies inside the segment). Only the phones
  of v with the strongest articulation are used: phones are ranked by their lip dominance in
  :mod:`face_model.phones` (e.g. ``aa`` for ``a``, ``uw w`` for ``u``, ``p b m`` for ``m``) and
  added tier by tier until at least ``min_samples`` frames are found (or v has no phones left).
* **expression k** — frames of k-utterances at the *hold* of the expression. A frame's expression
  strength is its Eq. 1 residual projected on the direction of ``m_k0`` (the mean residual: the
  average expression beyond the utterance MUs); the hold is every frame with strength ≥
  ``hold_fraction`` × the utterance's maximum. Among hold frames, closed-mouth frames are preferred
  so that the keyframe is the pure expression: silence (``sil``) if at least ``min_samples`` such
  frames exist, else silence and bilabials (``sil p b m``), else all hold frames.

The keyframe is the element-wise **median** of its selected frames (robust to marker noise and
to the odd mis-timed phone boundary).

Space: every shape is a *deformation* (158,), pixels, from the speaker's neutral face
(:func:`face_model.alignment.corpus_deformations`), so the neutral face s_0 of Eq. 3 is the zero
vector and the weights are blend-shape weights: b = 0 is the neutral face, b = e_i keyframe i.
With s_0 = 0, Eq. 4 reads

    b    = (KᵀK)⁻¹ Kᵀ d,            d = Eq. 2 of the MUPs
    c_0j = m_0jᵀ (K b − m_00)
    c_kj = α_k m_kjᵀ (K b − Σ_i c_0i m_0i − m_00 − m_k0)

The conversion is a projection and is lossy: for an expression, Eq. 2 shapes span a 9-dimensional
affine (10-dimensional linear) space that 8 keyframes cannot cover, and keyframes taken from data
are not exactly inside the MU space either. :meth:`KeyframeModel.round_trip_error` measures it.
"""
from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from face_model.alignment import corpus_deformations
from face_model.motion_units import N_DIM, MotionUnits
from face_model.phones import BILABIALS, PHONE_INDEX, PHONES, dominance_matrix, viseme
from groundwork import modelfile, numerics
from groundwork.errors import NotFittedError, ParameterError

KEYFRAMES = ("smile", "sad", "i", "a", "o", "f", "u", "m")
EXPRESSION_KEYFRAMES, VISEME_KEYFRAMES = KEYFRAMES[:2], KEYFRAMES[2:]
# The keyframe model file, a groundwork.modelfile of this kind. Versions:
# 1: the Motion Units in a layout of their own, not their to_arrays record (no longer read);
# 2: np.savez of ``shapes``, the Motion Units' arrays (``mu_``) and a JSON ``metadata`` with
#    ``format`` = LEGACY_FORMAT; no checksum (still read);
# 3: written by groundwork.modelfile: the same arrays and record (without ``format``), plus
#    kind, version, array manifest and SHA-256 in the metadata, written atomically.
KIND, VERSION = "keyframes", 3
LEGACY_FORMAT = "talkingface.keyframes/2"
TRACKS_FORMAT, TRACKS_VERSION = "talkingface.keyframe_tracks", 1
_MU_PREFIX = "mu_"  # the Motion Units' arrays inside a keyframe model file


@dataclass(frozen=True)
class RoundTripError:
    """MUP → keyframe weights → MUP error (Eq. 4 both ways) over ``n_frames`` frames.

    ``mup_rmse`` is in MUP units, ``mup_relative`` = ‖Δc‖ / ‖c‖; ``pixel_rmse`` and
    ``pixel_max`` are per-marker Euclidean distances (pixels) between the Eq. 2 shapes of the
    MUPs before and after; ``shape_relative`` = ‖Δd‖ / ‖d‖ (d: deformation from the neutral face).
    For ``neutral`` only the A_0 utterance MUPs count (α_k = 0).
    """

    n_frames: int
    mup_rmse: float
    mup_relative: float
    pixel_rmse: float
    pixel_max: float
    shape_relative: float


@dataclass(frozen=True)
class KeyframeTracks:
    """Tracks read from a file: ``weights`` (n_frames, 8) in :data:`KEYFRAMES` order, frame k at
    ``k / fps`` s; ``expression`` and ``source`` are None for CSV files."""

    weights: np.ndarray
    fps: float
    expression: str | None
    source: str | None

    @property
    def times(self) -> np.ndarray:
        return np.arange(len(self.weights)) / self.fps


def _centre_frames(utt, phones: set) -> list[int]:
    """Frames nearest the midpoints of ``utt``'s segments of ``phones`` that fall inside them."""
    per_frame = utt.phone_per_frame()
    centres = ((int(math.floor(0.5 * (s.start_s + s.end_s) * utt.fps + 0.5)), s.phone)
               for s in utt.phones if s.phone in phones)
    return [k for k, p in centres if k < utt.n_frames and per_frame[k] == PHONE_INDEX[p]]


class KeyframeModel:
    """The eight keyframes κ'_i and the Eq. 4 conversion, scikit-learn style.

    Parameters
    ----------
    min_samples : int
        Frames wanted per keyframe before the selection widens no further (see module notes).
    hold_fraction : float in (0, 1]
        A frame of an expression utterance is at the hold if its expression strength is at least
        this fraction of the utterance's maximum.

    Attributes (after ``fit``)
    --------------------------
    shapes_ : ndarray (8, 158)      κ'_i as rows, deformations (pixels) from the neutral face
    pinv_ : ndarray (8, 158)        (KᵀK)⁻¹Kᵀ
    condition_ : float              condition number of K
    units_ : MotionUnits            the MUs the MUPs refer to
    selection_ : dict name → list of (utt_id, frame)   the frames each keyframe is the median of
    """

    def __init__(self, min_samples: int = 10, hold_fraction: float = 0.9):
        self.min_samples = min_samples
        self.hold_fraction = hold_fraction

    @property
    def K(self) -> np.ndarray:
        """K = [κ'_1 … κ'_8], shape (158, 8)."""
        self._check_fitted()
        return self.shapes_.T

    # -- fitting ---------------------------------------------------------------------------
    @numerics.single_threaded
    def fit(self, corpus, units: MotionUnits, *, deformations: dict | None = None):
        """Pick the keyframes from ``corpus`` and build K.

        Parameters
        ----------
        corpus : Corpus
            Needs neutral utterances and utterances of both ``smile`` and ``sad``.
        units : MotionUnits
            Fitted MUs with ``smile`` and ``sad`` expression MUs.
        deformations : dict utt_id → ndarray (n_frames, 158), optional
            Deformations (pixels) from the speaker's neutral face; default: computed with
            :func:`face_model.alignment.corpus_deformations` and the alignment of ``units``.
        """
        if not isinstance(self.min_samples, (int, np.integer)) or self.min_samples < 1:
            raise ParameterError(f"min_samples must be a positive integer, got "
                                 f"{self.min_samples!r}")
        if not 0.0 < self.hold_fraction <= 1.0:
            raise ParameterError(f"hold_fraction must be in (0, 1], got {self.hold_fraction!r}")
        units._check_fitted()
        missing = [k for k in EXPRESSION_KEYFRAMES if k not in units.expressions_]
        if missing:
            raise ParameterError(f"the Motion Units have no {' or '.join(missing)} MUs; the "
                                 f"keyframes need both (units have: {units.expressions_})")
        if deformations is None:
            deformations = corpus_deformations(
                corpus, model=units.metadata_.get("alignment", "similarity"))
        for u in corpus.utterances:
            shape = np.shape(deformations.get(u.utt_id))
            if shape != (u.n_frames, N_DIM):
                raise ParameterError(f"deformations for {u.utt_id} must have shape "
                                     f"({u.n_frames}, {N_DIM}), got {shape}")
        self.units_ = units
        self.selection_ = {n: self._select_viseme(corpus, n) for n in VISEME_KEYFRAMES}
        self.selection_.update({n: self._select_expression(corpus, deformations, n)
                                for n in EXPRESSION_KEYFRAMES})
        self.shapes_ = np.stack([np.median([deformations[u][k] for u, k in self.selection_[n]],
                                           axis=0) for n in KEYFRAMES])
        self._set_matrix()
        return self

    @classmethod
    def from_shapes(cls, shapes, units: MotionUnits) -> "KeyframeModel":
        """A model with given keyframes ``shapes`` (8, 158): κ'_i as rows in :data:`KEYFRAMES`
        order, pixels from the neutral face (e.g. another face model's keyframes, mapped)."""
        units._check_fitted()
        shapes = np.asarray(shapes, dtype=np.float64)
        if shapes.shape != (len(KEYFRAMES), N_DIM) or not np.all(np.isfinite(shapes)):
            raise ParameterError(f"keyframe shapes must be finite, shape ({len(KEYFRAMES)}, "
                                 f"{N_DIM}); got {shapes.shape}")
        model = cls()
        model.shapes_, model.units_, model.selection_ = shapes.copy(), units, {}
        model._set_matrix()
        return model

    def _select_viseme(self, corpus, name: str) -> list:
        lip = dominance_matrix()[:, 1]
        phones = [p for p in PHONES if viseme(p) == name]
        chosen: list = []
        for level in sorted({lip[PHONE_INDEX[p]] for p in phones}, reverse=True):
            use = {p for p in phones if lip[PHONE_INDEX[p]] >= level}
            chosen = [(u.utt_id, k) for u in corpus.by_expression("neutral")
                      for k in _centre_frames(u, use)]
            if len(chosen) >= self.min_samples:
                break
        if not chosen:
            raise ParameterError(f"no neutral-speech frame at the centre of a phone of viseme "
                                 f"{name!r} ({' '.join(phones)}); keyframe {name!r} cannot be "
                                 "picked")
        return chosen

    def _select_expression(self, corpus, deformations: dict, name: str) -> list:
        mu = self.units_
        direction = mu.expression_mean_[name] / np.linalg.norm(mu.expression_mean_[name])
        hold: list = []
        for u in corpus.by_expression(name):
            d = np.asarray(deformations[u.utt_id], dtype=np.float64) - mu.mean_
            strength = (d - (d @ mu.components_.T) @ mu.components_) @ direction  # Eq. 1
            if strength.max() > 0:
                phones = u.phone_per_frame()
                hold += [(u.utt_id, int(k), PHONES[phones[k]])
                         for k in np.flatnonzero(strength >= self.hold_fraction * strength.max())]
        if not hold:
            raise ParameterError(f"no {name!r} utterance shows the expression; keyframe "
                                 f"{name!r} cannot be picked")
        for closed in ({"sil"}, {"sil"} | BILABIALS, None):
            chosen = [(u, k) for u, k, p in hold if closed is None or p in closed]
            if len(chosen) >= self.min_samples:
                break
        return chosen

    def _set_matrix(self) -> None:
        s = numerics.svd(self.shapes_, compute_uv=False)
        if s[-1] <= 1e-9 * s[0]:
            raise ParameterError("the keyframes are linearly dependent (K has rank < 8); "
                                 "(KᵀK)⁻¹ of Eq. 4 does not exist")
        self.condition_ = float(s[0] / s[-1])
        self.pinv_ = numerics.pinv(self.shapes_.T)

    def _check_fitted(self) -> None:
        if not hasattr(self, "shapes_"):
            raise NotFittedError("KeyframeModel is not fitted yet: call fit() or "
                                 "KeyframeModel.load()")

    def _check(self, array, width: int, what: str, expression: str | None = None) -> np.ndarray:
        self._check_fitted()
        allowed = ("neutral",) + tuple(self.units_.expressions_)
        if expression is not None and expression not in allowed:
            raise ParameterError(f"expression {expression!r} is unknown; allowed: "
                                 f"{', '.join(allowed)}")
        a = np.asarray(array, dtype=np.float64)
        if a.ndim != 2 or a.shape[1] != width:
            raise ParameterError(f"{what} must have shape (n_frames, {width}), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ParameterError(f"{what} hold NaN or inf values")
        return a

    # -- Eq. 4 -----------------------------------------------------------------------------
    def shapes_to_keyframes(self, deformations) -> np.ndarray:
        """Least-squares weights b = (KᵀK)⁻¹Kᵀ d (Eq. 4), (n_frames, 8), of deformations
        ``d`` (n_frames, 158), pixels from the neutral face."""
        return self._check(deformations, N_DIM, "deformations") @ self.pinv_.T

    def keyframes_to_shapes(self, b) -> np.ndarray:
        """Deformations K b (s − s_0 of Eq. 3), (n_frames, 158), pixels, of weights b (n, 8)."""
        return self._check(b, len(KEYFRAMES), "keyframe weights") @ self.shapes_

    def mups_to_keyframes(self, mups, expression: str = "neutral") -> np.ndarray:
        """Keyframe weights b (n_frames, 8) of MUPs (n_frames, A_0 + A_k) by Eq. 4."""
        self._check_fitted()
        mups = self._check(mups, self.units_.n_mups, "MUPs (A_0 + A_k columns)", expression)
        return self.shapes_to_keyframes(self.units_.inverse_transform(mups, expression))

    def keyframes_to_mups(self, b, expression: str = "neutral") -> np.ndarray:
        """MUPs (n_frames, A_0 + A_k) of keyframe weights b (n_frames, 8) by Eq. 4; the
        expression part is zero for ``neutral`` (α_k = 0)."""
        self._check(b, len(KEYFRAMES), "keyframe weights", expression)
        mu, s = self.units_, self.keyframes_to_shapes(b)
        c0 = (s - mu.mean_) @ mu.components_.T
        ck = np.zeros((len(s), mu.n_expression))
        if expression != "neutral":
            ck = ((s - c0 @ mu.components_ - mu.mean_ - mu.expression_mean_[expression])
                  @ mu.expression_components_[expression].T)
        return np.concatenate([c0, ck], axis=1)

    def round_trip_error(self, mups, expression: str = "neutral") -> RoundTripError:
        """The error of MUPs (n_frames ≥ 1, A_0 + A_k) → b → MUPs (Eq. 4 both ways); see
        :class:`RoundTripError`."""
        back = self.keyframes_to_mups(self.mups_to_keyframes(mups, expression), expression)
        mups = np.asarray(mups, dtype=np.float64)
        if len(mups) == 0:
            raise ParameterError("round_trip_error needs at least one frame of MUPs")
        d, d2 = (self.units_.inverse_transform(m, expression) for m in (mups, back))
        if expression == "neutral":
            mups, back = (m[:, : self.units_.n_utterance] for m in (mups, back))
        dist = np.linalg.norm((d2 - d).reshape(len(d), -1, 2), axis=2)
        return RoundTripError(
            n_frames=len(mups),
            mup_rmse=float(np.sqrt(np.mean((back - mups) ** 2))),
            mup_relative=float(np.linalg.norm(back - mups) / max(np.linalg.norm(mups), 1e-300)),
            pixel_rmse=float(np.sqrt(np.mean(dist**2))), pixel_max=float(dist.max()),
            shape_relative=float(np.linalg.norm(d2 - d) / max(np.linalg.norm(d), 1e-300)))

    # -- persistence -----------------------------------------------------------------------
    def save(self, path) -> Path:
        """Write one model file (:mod:`groundwork.modelfile`, kind ``keyframes``, version
        :data:`VERSION`), atomically: K (``shapes``, (8, 158)), the Motion Units it converts to
        (their :meth:`MotionUnits.to_arrays` arrays, names prefixed ``mu_``) and a JSON
        metadata record (the Motion Units' own record under ``units``)."""
        self._check_fitted()
        unit_arrays, unit_meta = self.units_.to_arrays()
        meta = {"keyframes": list(KEYFRAMES),
                "min_samples": int(self.min_samples), "hold_fraction": float(self.hold_fraction),
                "selection": {k: [[a, int(f)] for a, f in v] for k, v in self.selection_.items()},
                "units": unit_meta}
        arrays = {_MU_PREFIX + name: x for name, x in unit_arrays.items()}
        return modelfile.write_model(path, {"shapes": self.shapes_, **arrays}, meta, kind=KIND,
                                     version=VERSION)

    @classmethod
    def load(cls, path) -> "KeyframeModel":
        """Rebuild a model, with its Motion Units, saved by :meth:`save` (or by the version-2
        code, without a checksum).

        Raises
        ------
        ParameterError
            Naming the file: missing, not a model file, damaged (checksum), another kind or
            version, Python objects inside, or Motion Units arrays missing.
        """
        path = Path(path)
        if not path.is_file():
            raise ParameterError(f"keyframe model file {path} not found")
        found = modelfile.read_model(path, kind=KIND, versions=(VERSION,),
                                     what="keyframe model file", legacy=(modelfile.METADATA,))
        meta = found.metadata
        if (found.legacy and meta.get("format") != LEGACY_FORMAT) or (
                meta.get("keyframes") != list(KEYFRAMES)):
            raise ParameterError(f"{path}: not a keyframe model of this version (format "
                                 f"{meta.get('format')!r}, expected {LEGACY_FORMAT!r} or kind "
                                 f"{KIND!r} version {VERSION})")
        unit_arrays = {name[len(_MU_PREFIX):]: a for name, a in found.arrays.items()
                       if name.startswith(_MU_PREFIX)}
        units = MotionUnits.from_arrays(unit_arrays, meta["units"],
                                        source=f"{path} (its Motion Units)")
        model = cls(meta["min_samples"], meta["hold_fraction"])
        model.shapes_, model.units_ = found.arrays["shapes"], units
        model.selection_ = {k: [(a, f) for a, f in v] for k, v in meta["selection"].items()}
        model._set_matrix()
        return model

# -- keyframe weight tracks --------------------------------------------------------------------
def write_keyframe_tracks(path, weights, fps: float = 30, *, expression: str,
                          source: str) -> Path:
    """Write keyframe weights (n_frames, 8), frame k at k / fps s, as ``.json`` or ``.csv``.

    JSON schema: ``{"format": "talkingface.keyframe_tracks", "version": 1, "fps", "n_frames",
    "keyframes": [8 names], "expression", "source", "frames": [{"time_s", "weights": [8]}]}``;
    weights are dimensionless Eq. 4 blend weights (0 = neutral face, 1 = the full keyframe) in
    the order of ``keyframes``. CSV: header ``time_s,smile,sad,i,a,o,f,u,m``, one row per frame
    (no expression or source). Floats are written in full precision: reading gives them back.
    """
    path = Path(path)
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 2 or w.shape[1] != len(KEYFRAMES):
        raise ParameterError(f"weights must have shape (n_frames, {len(KEYFRAMES)}), got {w.shape}")
    if not np.all(np.isfinite(w)):
        raise ParameterError("weights hold NaN or inf values")
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise ParameterError(f"fps must be a positive number, got {fps!r}")
    times = [k / fps for k in range(len(w))]
    if path.suffix == ".json":
        doc = {"format": TRACKS_FORMAT, "version": TRACKS_VERSION, "fps": fps,
               "n_frames": len(w), "keyframes": list(KEYFRAMES), "expression": expression,
               "source": source, "frames": [{"time_s": t, "weights": row.tolist()}
                                            for t, row in zip(times, w)]}
        path.write_text(json.dumps(doc, indent=1))
    elif path.suffix == ".csv":
        with open(path, "w", newline="") as f:
            out = csv.writer(f, lineterminator="\n")
            out.writerow(["time_s", *KEYFRAMES])
            out.writerows([repr(t), *map(repr, row.tolist())] for t, row in zip(times, w))
    else:
        raise ParameterError(f"{path}: keyframe tracks are written as .json or .csv, "
                             f"not {path.suffix!r}")
    return path


def _parse_tracks(path: Path) -> tuple:
    """(names, times, rows, fps, expression, source) as found in the file, unvalidated."""
    if path.suffix == ".json":
        doc = json.loads(path.read_text())
        if not isinstance(doc, dict) or (doc.get("format"), doc.get("version")) != (
                TRACKS_FORMAT, TRACKS_VERSION):
            got = (doc.get("format"), doc.get("version")) if isinstance(doc, dict) else doc
            raise ParameterError(f"{path}: not keyframe tracks (format, version = {got}; "
                                 f"expected {TRACKS_FORMAT!r}, {TRACKS_VERSION})")
        rows = [list(fr["weights"]) for fr in doc["frames"]]
        if doc.get("n_frames", len(rows)) != len(rows):
            raise ParameterError(f"{path}: n_frames is {doc['n_frames']} but {len(rows)} "
                                 "frames are listed")
        return (list(doc["keyframes"]), [float(fr["time_s"]) for fr in doc["frames"]], rows,
                float(doc["fps"]), doc.get("expression"), doc.get("source"))
    if path.suffix == ".csv":
        with open(path, newline="") as f:
            table = list(csv.reader(f))
        if not table or table[0][:1] != ["time_s"]:
            raise ParameterError(f"{path}: the header must start with 'time_s', got "
                                 f"{table[0] if table else 'an empty file'}")
        times = [float(r[0]) for r in table[1:]]
        # fps from the typical step, so that a single wrong time is the one reported
        step = float(np.median(np.diff(times))) if len(times) > 1 else 1 / 30
        fps = 1.0 / step if step > 0 else math.nan
        fps = float(round(fps)) if abs(fps - round(fps)) < 1e-6 else fps
        return table[0][1:], times, [[float(x) for x in r[1:]] for r in table[1:]], fps, None, None
    raise ParameterError(f"{path}: keyframe tracks are .json or .csv files, not {path.suffix!r}")


def read_keyframe_tracks(path) -> KeyframeTracks:
    """Read and validate tracks written by :func:`write_keyframe_tracks`.

    Keyframe columns may come in any order; the weights are returned in :data:`KEYFRAMES` order.
    A CSV file's fps is its time step (30 for a single frame).

    Raises
    ------
    ParameterError
        Naming the file and the problem: wrong format or version, unknown, missing or repeated
        keyframe names, times not at k / fps, non-finite weights, rows of the wrong length.
    """
    path = Path(path)
    if not path.is_file():
        raise ParameterError(f"{path}: keyframe tracks file not found")
    try:
        names, times, rows, fps, expression, source = _parse_tracks(path)
    except ParameterError:
        raise
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise ParameterError(f"{path}: malformed keyframe tracks ({exc!r})") from exc
    unknown = [n for n in names if n not in KEYFRAMES]
    if unknown or sorted(names) != sorted(KEYFRAMES):
        raise ParameterError(f"{path}: unknown keyframe names {unknown}; allowed: "
                             f"{', '.join(KEYFRAMES)}" if unknown else
                             f"{path}: keyframes must be {', '.join(KEYFRAMES)} once each, "
                             f"got {list(names)}")
    bad = [i for i, r in enumerate(rows) if len(r) != len(KEYFRAMES)]
    if bad or not rows:
        raise ParameterError(f"{path}: frame {bad[0]} has {len(rows[bad[0]])} weights, expected "
                             f"{len(KEYFRAMES)}" if bad else f"{path}: no frames")
    if not (math.isfinite(fps) and fps > 0):
        raise ParameterError(f"{path}: fps must be a positive number, got {fps}")
    try:
        w = np.asarray(rows, dtype=np.float64)[:, [names.index(k) for k in KEYFRAMES]]
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{path}: weights must be numbers ({exc})") from exc
    if not np.all(np.isfinite(w)):
        i, j = np.argwhere(~np.isfinite(w))[0]
        raise ParameterError(f"{path}: non-finite weight at frame {i}, keyframe {KEYFRAMES[j]!r}")
    t = np.asarray(times)
    wrong = np.flatnonzero(np.abs(t - np.arange(len(t)) / fps) > 1e-6)
    if wrong.size:
        k = int(wrong[0])
        raise ParameterError(f"{path}: time_s must increase in steps of 1/fps = {1 / fps:.6f} s "
                             f"from 0 (frame k at k/fps); frame {k} is at {t[k]} s")
    return KeyframeTracks(w, fps, expression, source)
