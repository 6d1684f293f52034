"""Coarticulated articulatory trajectories from timed phones (Cohen & Massaro, 1993), and the
coarticulation model that draws them: the hand table or one fitted on a real mouth.

Each phone segment s has a target ``T_sp`` and a dominance magnitude ``alpha_sp`` per articulatory
parameter p. Its dominance at time t is

    D_sp(t) = alpha_sp · exp(−θ · |τ|^c),   θ = θ_anticipation before the centre, θ_carry-over after,

with τ the distance (s) to the segment centre, and the trajectory is the dominance-weighted mean
``F_p(t) = Σ_s D_sp(t) T_sp / Σ_s D_sp(t)``. Silences hold full dominance over their whole extent
(τ counts from the segment's edge), so the face rests during pauses. Bilabial closure is forced
inside every /p b m/ segment so that it is never averaged away.

An :class:`Articulation` holds one such model: targets and dominance per phone class and
parameter, the two rates and the power. ``synth.articulation`` selects it
(:func:`articulation_model`): ``table`` is the hand-typed table of :mod:`face_model.phones` with
the rates of ``synth.theta_anticipation``, ``synth.theta_carryover`` and
``synth.dominance_power``; any other value is a model file (:func:`write_articulation`), either
a name shipped in ``data_synth/articulation_models/`` (``grid-s1``: fitted on the real speaker's
training sentences by ``tools/fit_articulation.py``) or a path, and then the file's own rates
are used.
"""
from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from face_model.phones import (
    ARTIC_PARAMS,
    BILABIALS,
    N_ARTIC,
    N_PHONES,
    PHONE_INDEX,
    PHONES,
    check_phone,
    dominance_matrix,
    target_matrix,
)
from groundwork.errors import ParameterError
from groundwork.modelfile import read_model, write_model

_CLOSURE = ARTIC_PARAMS.index("closure")
TABLE = "table"
SHIPPED_DIR = Path(__file__).resolve().parent / "articulation_models"
KIND = "articulation"
VERSION = 1
# Bounds of a target (0 = rest, 1 = the face model's extreme; tuck to 1.5 as the face allows).
TARGET_BOUNDS = (0.0, 1.5)


@dataclass(frozen=True)
class Articulation:
    """One coarticulation model (Cohen & Massaro, 1993).

    Attributes
    ----------
    targets : ndarray, shape (44, 7)
        Target of each phone class (rows in :data:`~face_model.phones.PHONES` order) for each
        articulatory parameter (:data:`~face_model.phones.ARTIC_PARAMS` order).
    dominance : ndarray, shape (44, 7)
        Dominance magnitudes alpha, all > 0.
    theta_anticipation, theta_carryover : float
        Dominance decay rates in 1/s before and after a segment's centre.
    power : float
        The exponent c of |τ|.
    name : str
        ``table``, or the model file's name and checksum (what a corpus records).
    record : dict
        The file's record (provenance, fit figures); empty for the table.
    """

    targets: np.ndarray
    dominance: np.ndarray
    theta_anticipation: float
    theta_carryover: float
    power: float
    name: str = TABLE
    record: dict = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self):
        t, d = np.asarray(self.targets, float), np.asarray(self.dominance, float)
        if t.shape != (N_PHONES, N_ARTIC) or d.shape != (N_PHONES, N_ARTIC):
            raise ParameterError(f"articulation {self.name}: targets and dominance must be "
                                 f"({N_PHONES}, {N_ARTIC}), got {t.shape} and {d.shape}")
        if not (np.isfinite(t).all() and np.isfinite(d).all() and (d > 0).all()):
            raise ParameterError(f"articulation {self.name}: targets must be finite and "
                                 "dominance finite and > 0")
        rates = (self.theta_anticipation, self.theta_carryover, self.power)
        if not all(np.isfinite(r) and r > 0 for r in rates):
            raise ParameterError(f"articulation {self.name}: dominance rates and power must be "
                                 f"positive, got {rates[0]}, {rates[1]}, {rates[2]}")
        object.__setattr__(self, "targets", t)
        object.__setattr__(self, "dominance", d)

    @classmethod
    def table(cls, theta_anticipation: float = 16.0, theta_carryover: float = 25.0,
              power: float = 1.0) -> "Articulation":
        """The hand-typed table of :mod:`face_model.phones` with the given rates."""
        return cls(target_matrix(), dominance_matrix(), float(theta_anticipation),
                   float(theta_carryover), float(power))


def coarticulate(segments, times: np.ndarray, model: Articulation | None = None) -> np.ndarray:
    """Articulatory parameters at the given times.

    Parameters
    ----------
    segments : sequence of PhoneSegment
        Contiguous, time-ordered phone segments (44-class labels).
    times : ndarray, shape (n_frames,)
        Sample times in seconds (frame k at k / fps).
    model : Articulation, optional
        The coarticulation model; default: :meth:`Articulation.table` (θ← 16, θ→ 25 s⁻¹, c 1).

    Returns
    -------
    ndarray, shape (n_frames, 7), in ``ARTIC_PARAMS`` order.
    """
    model = Articulation.table() if model is None else model
    if len(segments) == 0:
        raise ParameterError("coarticulate: no phone segments")
    idx = np.array([PHONE_INDEX[check_phone(s.phone, source="coarticulate")] for s in segments])
    start = np.array([s.start_s for s in segments])
    end = np.array([s.end_s for s in segments])
    is_sil = np.array([s.phone == "sil" for s in segments])
    t = np.asarray(times, dtype=np.float64)[None, :]  # (1, n)
    log_decay = _log_decay(start, end, is_sil, t, model)  # (n_seg, n)
    # log D = log alpha − θ|τ|^c; normalising by the per-time maximum before exp keeps the
    # weighted mean exact however far a time lies from every segment centre.
    log_dom = np.log(model.dominance[idx])[:, None, :] + log_decay[:, :, None]  # (n_seg, n, 7)
    dom = np.exp(log_dom - log_dom.max(axis=0, keepdims=True))
    traj = (dom * model.targets[idx][:, None, :]).sum(0) / dom.sum(0)
    bilabial = np.array([s.phone in BILABIALS for s in segments])
    if bilabial.any():
        inside = (t >= start[bilabial, None]) & (t < end[bilabial, None])
        traj[inside.any(0), _CLOSURE] = 1.0
    return traj


def _log_decay(start, end, is_sil, t, model: Articulation) -> np.ndarray:
    """−θ|τ|^c per segment and time, (n_seg, n): τ from the centre, from the edge for silences."""
    centre = 0.5 * (start + end)
    signed = t - centre[:, None]  # (n_seg, n): negative before the centre
    edge = np.maximum(start[:, None] - t, t - end[:, None]).clip(min=0.0)
    dist = np.where(is_sil[:, None], edge, np.abs(signed))
    theta = np.where(signed < 0, model.theta_anticipation, model.theta_carryover)
    return -theta * dist**model.power


def articulation_path(value: str) -> Path:
    """The model file ``synth.articulation`` names: a shipped name or a path (not ``table``)."""
    shipped = SHIPPED_DIR / f"{value}.npz"
    if "/" not in value and not value.endswith(".npz"):
        return shipped
    return Path(value)


def shipped_names() -> list[str]:
    """The names of the shipped articulation models."""
    return sorted(p.stem for p in SHIPPED_DIR.glob("*.npz"))


def articulation_record(path) -> dict:
    """The provenance a model file of :func:`write_articulation` keeps (its ``corpus``,
    ``corpus_hash`` and ``training_utterances`` among them), checked against its checksum."""
    return dict(read_model(Path(path), kind=KIND, versions=(VERSION,),
                           what="articulation model file").metadata)


def write_articulation(path, model: Articulation, record: dict) -> Path:
    """Write ``model`` as a model file (kind ``articulation``) with ``record`` (provenance: the
    data, the command, the fit's figures). Returns ``path``."""
    meta = {**record, "phones": list(PHONES), "params": list(ARTIC_PARAMS),
            "theta_anticipation": model.theta_anticipation,
            "theta_carryover": model.theta_carryover, "power": model.power}
    return write_model(path, {"targets": model.targets, "dominance": model.dominance}, meta,
                       kind=KIND, version=VERSION)


def read_articulation(path) -> Articulation:
    """Read a model file written by :func:`write_articulation` (checked against its checksum).

    Raises
    ------
    ParameterError
        The file is missing, damaged, of another kind, or its phones or parameters are not
        this project's; one line naming the file.
    """
    path = Path(path)
    if not path.is_file():
        raise ParameterError(f"articulation model {path}: file not found; allowed: {TABLE}, a "
                             f"shipped name ({', '.join(shipped_names()) or 'none'}) or a "
                             "file written by tools/fit_articulation.py")
    mf = read_model(path, kind=KIND, versions=(VERSION,), what="articulation model file")
    meta = mf.metadata
    if list(meta.get("phones", [])) != list(PHONES) or \
            list(meta.get("params", [])) != list(ARTIC_PARAMS):
        raise ParameterError(f"articulation model {path}: its phone classes or articulatory "
                             "parameters are not this project's; fit it again")
    try:
        return Articulation(mf.arrays["targets"], mf.arrays["dominance"],
                            float(meta["theta_anticipation"]), float(meta["theta_carryover"]),
                            float(meta["power"]), name=f"{path.name}:{file_sha256(path)[:12]}",
                            record=meta)
    except (KeyError, TypeError, ValueError) as exc:
        raise ParameterError(f"articulation model {path}: incomplete record ({exc!r}); fit it "
                             "again") from None


def file_sha256(path) -> str:
    """SHA-256 of a file's bytes (what a corpus records of the model it was drawn with)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@functools.lru_cache(maxsize=8)
def _read_cached(path: str, mtime_ns: int, size: int) -> Articulation:
    return read_articulation(path)


def articulation_model(cfg) -> Articulation:
    """The coarticulation model ``cfg`` (a :class:`~data_synth.config.SynthConfig`) selects:
    ``synth.articulation`` ``table`` (with the config's rates) or a model file."""
    if cfg.articulation == TABLE:
        return Articulation.table(cfg.theta_anticipation, cfg.theta_carryover,
                                  cfg.dominance_power)
    path = articulation_path(cfg.articulation)
    if not path.is_file():
        return read_articulation(path)  # the one-line refusal
    st = path.stat()
    return _read_cached(str(path.resolve()), st.st_mtime_ns, st.st_size)


def articulation_file(cfg) -> Path | None:
    """The model file ``synth.articulation`` reads (None for ``table``): stages that draw faces
    depend on its content."""
    return None if cfg.articulation == TABLE else articulation_path(cfg.articulation)
