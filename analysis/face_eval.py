"""Predicted lips scored against a real talking face (``talkingface evaluate-face``).

A model draws 79 markers from the audio (:class:`mapping.animator.FaceAnimator`); the real
video's landmarks become the same 79 markers, aligned (:func:`face_model.alignment.align_markers`).
Both give a mouth opening per frame (:func:`face_model.layout.mouth_opening`, px). One clip is a
:class:`ClipTrack`; :func:`score_clips` scores a set. The two openings may differ by one frame
(rounding of the clip's length; the longer is trimmed); more is refused as not the same clip.

Per-speaker normalisation. Each speaker's real openings are z-scored with that speaker's mean
and standard deviation (``ddof = 0``) over all its frames in all its clips; the predicted ones
the same way with the *prediction's own* per-speaker mean and deviation: a model trained on
another face draws on another scale, and the question is whether the lips move *when* the real
ones do. A still track (deviation 0) gives z = 0, r = NaN and no closures. Per-clip r ignores
affine maps anyway; pooled r would otherwise be decided by the speakers' scales and offsets.

Correlation. Per clip: Pearson's r of the normalised openings
(:func:`analysis.speech_eval.correlation`). Pooled: r over every frame of every clip end to end
(normalised per speaker, so frame-weighted over speakers), with the mean and median of the
per-clip r (NaN ones left out).

Closures. The truth is the real lips' own closures. Closed level (:func:`closure_threshold`):
P10 + 0.10 × (P90 − P10) of the speaker's openings over all its frames. A detector never puts
pressed lips' landmarks exactly 0 px apart, and what it reports for them depends on speaker,
camera and detector, so the level comes from the speaker's own distribution. In running speech
the lips are shut for a sizeable share of frames (each /p b m/ for two or three, pauses longer),
so the lowest decile lies on that closed floor; a tenth of the ordinary opening range (P10–P90,
ignoring yawns and detector failures) is the margin for landmark jitter, far below any open
vowel. Ranks only: the same frames on pixels and z-scores and, on the prediction's own
distribution, whatever its scale. Fixed a priori, not tuned on scores. Limitation: a speaker
closed for under about a tenth of the frames has P10 above the floor, and the rule marks the
most nearly closed frames (the closed level of silent frames would need a voice-activity
decision this module does not have).

A closure *event* is a run of at least :data:`MIN_EVENT_S` (two frames at 30 fps) at or below
the level: a bilabial hold lasts that long; one low frame is as likely jitter. The prediction
*agrees* with a real event when its own normalised opening is at or below its own level (same
rule) in a frame of the event widened by :data:`TOLERANCE_S` (two frames at 30 fps) each side:
real video shot at 25 fps and resampled to 30 moves a closure's edges by up to a frame (a 40 ms
source frame covers 1.2 target frames), and the mapping places a closure from acoustic evidence
(transitions into it, burst or nasal murmur at its release) read through a centred window of
3 back and 3 forward frames (paper §VI-A, ``context_forward``), so a frame early or late is
within what the audio tells, as is a recording's small audio–video offset. A *false closure* is
a predicted event (same minimum length) overlapping no real event widened the same way; its
rate is per predicted event.

LVE (:func:`analysis.lip_metrics.lip_vertex_error`), when the model was trained on the speaker
(the caller passes both aligned markers): mean over frames of the largest Euclidean error over
the lip markers 46–75, pixels of the aligned (layout) frame.
"""
from __future__ import annotations

import csv
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from matplotlib.patches import Patch

from analysis.figures import report_figure
from analysis.lip_metrics import lip_vertex_error
from analysis.speech_eval import correlation
from face_model.layout import N_MARKERS, mouth_opening
from groundwork.atomic import atomic_file
from groundwork.errors import ParameterError

CLOSED_PERCENTILE = 10.0  # the closed floor of a speaker's openings
SPREAD_PERCENTILES = (10.0, 90.0)  # the speaker's ordinary opening range
CLOSED_MARGIN = 0.10  # fraction of that range added to the floor
MIN_EVENT_S = 2 / 30  # shortest closure event: two frames at 30 fps
TOLERANCE_S = 2 / 30  # an event is widened by two frames at 30 fps on each side
MAX_LENGTH_DIFF = 1  # frames the real and predicted openings of a clip may differ by
_ROUND = 1e-9  # z units: a frame at the threshold stays closed after rounding
CSV_COLUMNS = ("clip", "speaker", "n_frames", "fps", "r", "closure_events", "closures_agreed",
               "closure_agreed_frac", "predicted_closure_events", "false_closures", "lve_px")


def _track(x, what: str, clip: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 1 or len(a) < 2:
        raise ParameterError(f"clip {clip!r}: {what} opening must be 1-D with at least 2 "
                             f"frames, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ParameterError(f"clip {clip!r}: {what} opening has {int((~np.isfinite(a)).sum())} "
                             "non-finite frames; all must be finite")
    return a


def _marker_track(x, n: int, what: str, clip: str) -> np.ndarray:
    m = np.asarray(x, dtype=np.float64)
    if m.shape != (n, N_MARKERS, 2):
        raise ParameterError(f"clip {clip!r}: {what} markers must have shape ({n}, {N_MARKERS}, "
                             f"2) to match its opening, got {m.shape}")
    return m


@dataclass(frozen=True)
class ClipTrack:
    """One clip: real and predicted openings (px, one per frame at ``fps``) and, for LVE, the
    aligned markers of both (both or neither, each as long as its opening).

    Raises
    ------
    ParameterError
        Naming the clip: openings not finite 1-D tracks, lengths differing by more than
        :data:`MAX_LENGTH_DIFF` frames, markers of the wrong shape, ``fps`` not positive.
    """

    clip: str
    speaker: str
    real: np.ndarray
    predicted: np.ndarray
    fps: float = 30.0
    real_markers: np.ndarray | None = field(default=None, repr=False)
    predicted_markers: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        c = self.clip
        real, pred = _track(self.real, "real", c), _track(self.predicted, "predicted", c)
        if abs(len(real) - len(pred)) > MAX_LENGTH_DIFF:
            raise ParameterError(f"clip {c!r}: real opening has {len(real)} frames and predicted "
                                 f"{len(pred)}; they may differ by at most {MAX_LENGTH_DIFF}")
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise ParameterError(f"clip {c!r}: fps must be positive, got {self.fps}")
        if (self.real_markers is None) != (self.predicted_markers is None):
            raise ParameterError(f"clip {c!r}: give both real and predicted markers, or neither")
        object.__setattr__(self, "real", real)
        object.__setattr__(self, "predicted", pred)
        if self.real_markers is not None:
            object.__setattr__(self, "real_markers",
                               _marker_track(self.real_markers, len(real), "real", c))
            object.__setattr__(self, "predicted_markers", _marker_track(
                self.predicted_markers, len(pred), "predicted", c))

    @classmethod
    def from_markers(cls, clip: str, speaker: str, real_markers, predicted_markers,
                     fps: float = 30.0, *, lve: bool = True) -> ClipTrack:
        """The track of two aligned marker sequences (n, 79, 2) px, openings by
        :func:`~face_model.layout.mouth_opening`; the markers kept for LVE when ``lve`` (the
        model was trained on this speaker)."""
        real, pred = np.asarray(real_markers), np.asarray(predicted_markers)
        return cls(clip, speaker, mouth_opening(real), mouth_opening(pred), fps,
                   real if lve else None, pred if lve else None)

    @property
    def n_frames(self) -> int:
        """Frames scored: the shorter of the two openings."""
        return min(len(self.real), len(self.predicted))


def closure_threshold(opening) -> float:
    """The closed level of one speaker's openings: P10 + 0.10 × (P90 − P10) (NaN for a still
    or empty track, which has no closures)."""
    x = np.asarray(opening, dtype=np.float64)
    if len(x) < 2 or np.std(x) == 0:
        return float("nan")
    lo, hi = np.percentile(x, SPREAD_PERCENTILES)
    return float(np.percentile(x, CLOSED_PERCENTILE) + CLOSED_MARGIN * (hi - lo))


def _frames(seconds: float, fps: float) -> int:
    return max(1, int(round(seconds * fps)))


def closure_events(opening, threshold: float, min_frames: int) -> list[tuple[int, int]]:
    """``[(first, stop)]`` runs of at least ``min_frames`` frames with ``opening`` at or below
    ``threshold`` (none when it is NaN)."""
    closed = np.asarray(opening) <= threshold + _ROUND
    edges = np.flatnonzero(np.diff(np.concatenate([[0], closed.astype(int), [0]])))
    return [(a, b) for a, b in zip(edges[::2].tolist(), edges[1::2].tolist())
            if b - a >= min_frames]


@dataclass(frozen=True)
class SpeakerNorm:
    """A speaker's normalisation (px) and closed levels (z units) for real and predicted."""

    speaker: str
    n_frames: int
    real_mean: float
    real_std: float
    predicted_mean: float
    predicted_std: float
    real_threshold_z: float
    predicted_threshold_z: float


@dataclass(frozen=True)
class NormalisedTrack:
    """One clip after normalisation, what :func:`opening_strip_figure` draws."""

    clip: str
    speaker: str
    fps: float
    real: np.ndarray = field(repr=False)
    predicted: np.ndarray = field(repr=False)
    real_threshold_z: float
    predicted_threshold_z: float
    events: list  # real closure events, (first, stop)
    agreed: list  # per event
    predicted_events: list
    false: list  # per predicted event: overlaps no real event


@dataclass(frozen=True)
class ClipScore:
    """One row of the per-clip table (:data:`CSV_COLUMNS`)."""

    clip: str
    speaker: str
    n_frames: int
    fps: float
    r: float
    closure_events: int
    closures_agreed: int
    predicted_closure_events: int
    false_closures: int
    lve_px: float

    @property
    def closure_agreed_frac(self) -> float:
        e = self.closure_events
        return self.closures_agreed / e if e else float("nan")

    def row(self) -> dict:
        return {c: getattr(self, c) for c in CSV_COLUMNS}


@dataclass
class FaceScores:
    """Per-clip scores, per-speaker normalisation and the pooled figures (module docstring)."""

    clips: list
    speakers: list
    pooled: dict
    tracks: list = field(default_factory=list, repr=False)

    def to_dict(self) -> dict:
        """Plain JSON-ready values (NaN as None) with the closure rule's settings."""
        rule = {"closed_percentile": CLOSED_PERCENTILE,
                "spread_percentiles": list(SPREAD_PERCENTILES), "closed_margin": CLOSED_MARGIN,
                "min_event_s": MIN_EVENT_S, "tolerance_s": TOLERANCE_S}
        return _json_safe({"rule": rule, "pooled": self.pooled,
                           "speakers": [asdict(s) for s in self.speakers],
                           "clips": [c.row() for c in self.clips]})


def _json_safe(x):
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    return int(x) if isinstance(x, np.integer) else x


def _z(x: np.ndarray, mean: float, std: float) -> np.ndarray:
    return (x - mean) / std if std > 0 else np.zeros_like(x)


def _score_clip(t: ClipTrack, norm: SpeakerNorm) -> tuple[ClipScore, NormalisedTrack]:
    n = t.n_frames
    real = _z(t.real[:n], norm.real_mean, norm.real_std)
    pred = _z(t.predicted[:n], norm.predicted_mean, norm.predicted_std)
    min_len, tol = _frames(MIN_EVENT_S, t.fps), _frames(TOLERANCE_S, t.fps)
    events = closure_events(real, norm.real_threshold_z, min_len)
    wide = [(max(0, a - tol), min(n, b + tol)) for a, b in events]
    pred_closed = pred <= norm.predicted_threshold_z + _ROUND
    agreed = [bool(pred_closed[a:b].any()) for a, b in wide]
    pred_events = closure_events(pred, norm.predicted_threshold_z, min_len)
    false = [not any(c < b and d > a for a, b in wide) for c, d in pred_events]
    lve = float("nan")
    if t.real_markers is not None:
        flat = (lambda m: m[:n].reshape(n, 2 * N_MARKERS))
        lve = lip_vertex_error(flat(t.real_markers), flat(t.predicted_markers))
    score = ClipScore(t.clip, t.speaker, n, float(t.fps), correlation(real, pred), len(events),
                      sum(agreed), len(pred_events), sum(false), lve)
    track = NormalisedTrack(t.clip, t.speaker, float(t.fps), real, pred, norm.real_threshold_z,
                            norm.predicted_threshold_z, events, agreed, pred_events, false)
    return score, track


def _speaker_norm(speaker: str, tracks: list) -> SpeakerNorm:
    real = np.concatenate([t.real[:t.n_frames] for t in tracks])
    pred = np.concatenate([t.predicted[:t.n_frames] for t in tracks])
    rm, rs, pm, ps = real.mean(), real.std(), pred.mean(), pred.std()
    return SpeakerNorm(speaker, len(real), float(rm), float(rs), float(pm), float(ps),
                       closure_threshold(_z(real, rm, rs)), closure_threshold(_z(pred, pm, ps)))


def score_clips(tracks) -> FaceScores:
    """Score every clip of ``tracks`` (:class:`ClipTrack`), normalising per speaker over all
    of that speaker's clips given here.

    Returns
    -------
    FaceScores
        ``clips`` in the order given; ``pooled`` with ``clips, speakers, frames, r_pooled,
        r_clip_mean, r_clip_median, closure_events, closures_agreed, closure_agreed_frac,
        predicted_closure_events, false_closures, false_closure_frac, lve_px`` (frame-weighted
        over the clips with markers; NaN for none) and ``lve_clips``.

    Raises
    ------
    ParameterError
        No tracks, an item that is not a ClipTrack, or a clip id given twice.
    """
    tracks = list(tracks)
    if not tracks:
        raise ParameterError("no clips to score; give at least one ClipTrack")
    seen, by_speaker = set(), {}
    for t in tracks:
        if not isinstance(t, ClipTrack):
            raise ParameterError(f"tracks must be ClipTrack, got {type(t).__name__}")
        if t.clip in seen:
            raise ParameterError(f"clip {t.clip!r} is given twice; clip ids must be unique")
        seen.add(t.clip)
        by_speaker.setdefault(t.speaker, []).append(t)
    norms = {s: _speaker_norm(s, ts) for s, ts in by_speaker.items()}
    scored = [_score_clip(t, norms[t.speaker]) for t in tracks]
    clips, normed = [s for s, _ in scored], [n for _, n in scored]
    rs = np.array([c.r for c in clips])
    rs, nan = rs[np.isfinite(rs)], float("nan")
    events, agreed = sum(c.closure_events for c in clips), sum(c.closures_agreed for c in clips)
    pred_events, false = (sum(c.predicted_closure_events for c in clips),
                          sum(c.false_closures for c in clips))
    with_lve = [c for c in clips if math.isfinite(c.lve_px)]
    lve_frames = sum(c.n_frames for c in with_lve)
    pooled = {
        "clips": len(clips), "speakers": len(norms), "frames": sum(c.n_frames for c in clips),
        "r_pooled": correlation(np.concatenate([n.real for n in normed]),
                                np.concatenate([n.predicted for n in normed])),
        "r_clip_mean": float(np.mean(rs)) if len(rs) else nan,
        "r_clip_median": float(np.median(rs)) if len(rs) else nan,
        "closure_events": events, "closures_agreed": agreed,
        "closure_agreed_frac": agreed / events if events else nan,
        "predicted_closure_events": pred_events, "false_closures": false,
        "false_closure_frac": false / pred_events if pred_events else nan,
        "lve_px": (sum(c.lve_px * c.n_frames for c in with_lve) / lve_frames
                   if with_lve else nan),
        "lve_clips": len(with_lve)}
    return FaceScores(clips, list(norms.values()), pooled, normed)


def write_scores_csv(scores: FaceScores, path) -> Path:
    """The per-clip table (:data:`CSV_COLUMNS`, floats in full), written atomically; the
    pooled figures are in :meth:`FaceScores.to_dict`."""
    path = Path(path)
    with atomic_file(path) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(CSV_COLUMNS)
            for c in scores.clips:
                w.writerow([repr(v) if isinstance(v, float) else v for v in c.row().values()])
    return path


def opening_strip_figure(track, path, title: str = "", *, width: float = 1.0) -> Path:
    """Real and predicted normalised opening of one clip over time, the real closure events
    shaded (green: the prediction agrees, red: missed) and the predicted false closures marked.

    ``track``: a :class:`NormalisedTrack` from :attr:`FaceScores.tracks` (normalised with its
    speaker's statistics), or a :class:`ClipTrack`, then normalised on its own frames.
    """
    if isinstance(track, ClipTrack):
        track = score_clips([track]).tracks[0]
    if not isinstance(track, NormalisedTrack):
        raise ParameterError(f"track must be a ClipTrack or NormalisedTrack, got "
                             f"{type(track).__name__}")
    fps, half = track.fps, 0.5 / track.fps
    t = np.arange(len(track.real)) / fps
    with report_figure(path, width=width, height_in=2.6) as fig:
        ax = fig.subplots()
        for (a, b), ok in zip(track.events, track.agreed):
            ax.axvspan(a / fps - half, b / fps - half, color="#2ca02c" if ok else "#d62728",
                       alpha=0.2, lw=0)
        for (a, b), bad in zip(track.predicted_events, track.false):
            if bad:
                ax.plot([a / fps - half, b / fps - half], [0, 0], c="#9467bd", lw=4,
                        transform=ax.get_xaxis_transform(), solid_capstyle="butt")
        ax.plot(t, track.real, c="0.2", lw=1.3, label="real")
        ax.plot(t, track.predicted, c="#1f77b4", lw=1.3, label="predicted")
        for thr, c, lab in ((track.real_threshold_z, "0.2", "closed levels"),
                            (track.predicted_threshold_z, "#1f77b4", None)):
            if math.isfinite(thr):
                ax.axhline(thr, c=c, lw=0.8, ls=":", label=lab)
        ax.set_xlim(t[0], t[-1])
        ax.set_xlabel("time (s)")
        ax.set_ylabel("lip opening (z, per speaker)")
        ax.set_title(title or f"{track.clip} ({track.speaker})", wrap=True)
        ax.grid(alpha=0.3)
        handles = ax.get_legend_handles_labels()[0] + [
            Patch(color="#2ca02c", alpha=0.3, label="closure, agreed"),
            Patch(color="#d62728", alpha=0.3, label="closure, missed"),
            Patch(color="#9467bd", label="false closure")]
        fig.legend(handles=handles, loc="outside lower center", ncol=6)
    return Path(path)
