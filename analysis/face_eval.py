"""Predicted lips scored against a real talking face (``talkingface evaluate-face``, the report's
real-speaker section), by rules that measure speech (DESIGN.md, "Evaluation on real data").

A model draws 79 markers from the audio (:class:`mapping.animator.FaceAnimator`); the real
video's landmarks become the same 79 markers, aligned (:func:`face_model.alignment.align_markers`).
Both give a mouth opening per frame (:func:`face_model.layout.mouth_opening`, px); a peer gives an
opening in its own units. One clip is a :class:`ClipTrack`: the two openings, of exactly the same
length (any difference is an error naming the clip), the frame rate ``fps`` (frame k at k / fps
s), the clip's phone labels, and per frame a ``speech`` mask (phone ≠ ``sil``) and a ``valid``
mask (False where the video's face was not detected and was interpolated: the corpus's
``quality/<utt>.csv``). :func:`score_clips` scores a set.

Frames. Invalid frames are left out of every score. The headline figures are over the valid
**speech frames**; the valid silence frames are scored apart (in a sentence of GRID most frames
are silence, where every mouth is shut: agreement there says nothing about speech). A clip
without phone labels has no known speech frames: its valid frames are all scored as "speech"
and ``speech_known`` is False (the caller says so).

Correlation. Per clip and per part (speech, silence), the real and the predicted openings are
centred and scaled on that part's frames of that clip (z, ``ddof = 0``; a constant track gives
z = 0), which removes each clip's level and scale (a model trained on another face draws on
another scale; a clip's mean must not enter the pooled figure). Pooled r is then Pearson's r
over the pooled frames, which for z-scores is ``Σ z_real · z_pred / N``. Per-clip r (Pearson
over the clip's speech frames, NaN when either is constant) is a secondary figure (median and
mean of the finite ones).

Closures, on the segments the phones say must close. A bilabial segment is a run of adjacent
``p b m`` phones; a control segment is one non-bilabial speech phone. Each segment is tested on
the frames within :data:`HALF_WINDOW_S` of its centre (the same length for both kinds: half a
typical /p b m/ of 80 ms plus two frames at 30 fps of tolerance for the 25 → 30 fps resampling
of real video and a recording's audio–video offset), restricted to valid speech frames. A track
**closes** a segment when at some tested frame its opening is at most its own speech-frame
minimum plus :data:`CLOSE_FRACTION` of its own speech-frame range (minimum to maximum over the
clip's valid speech frames): one rule, chosen a priori, for the real lips (so the truth is
checked), for hits (bilabial segments the prediction closes) and for false closures (control
segments the prediction closes). Controls whose window overlaps a bilabial window, or that
are not wholly valid speech frames, are not tested. A track constant over the speech frames
has no range and closes nothing.

Chance. Beside every figure, the same prediction circularly shifted by :data:`CHANCE_SHIFTS`
of its clip's length (rounded to frames), scored by the same code with the truth's masks and
segments; the chance figure is the mean over the shifts.

Interval. With the speaker as the unit (:func:`analysis.speaker_bootstrap.speaker_interval`):
pooled r as the ratio ``Σ z·z / N`` over clips, closure rates as hits / segments; fewer than
three speakers give no interval and its reason.

LVE (:func:`analysis.lip_metrics.lip_vertex_error`), when the model was trained on the speaker
(the caller passes both aligned markers): mean over valid frames of the largest Euclidean error
over the lip markers 46–75, pixels of the aligned (layout) frame.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field

import numpy as np

from analysis.figures import report_figure
from analysis.lip_metrics import lip_vertex_error
from analysis.speaker_bootstrap import speaker_interval
from analysis.speech_eval import correlation
from face_model.layout import N_MARKERS, mouth_opening
from groundwork.atomic import atomic_file
from groundwork.errors import ParameterError

BILABIALS = frozenset({"p", "b", "m"})
SILENCE = "sil"
HALF_WINDOW_S = 0.1  # a segment is tested within this of its centre, seconds
CLOSE_FRACTION = 0.2  # closed: within this fraction of the track's own speech range of its min
CHANCE_SHIFTS = (1 / 3, 2 / 3)  # circular shifts of the prediction, fractions of its clip
CSV_COLUMNS = ("clip", "speaker", "n_frames", "fps", "valid_frames", "speech_frames",
               "r_speech", "r_silence", "bilabial_segments", "real_closed", "closures_hit",
               "control_segments", "real_false_closures", "false_closures", "chance_r_speech",
               "chance_closures_hit", "chance_false_closures", "lve_px")


def _track(x, what: str, clip: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 1 or len(a) < 2:
        raise ParameterError(f"clip {clip!r}: {what} opening must be 1-D with at least 2 "
                             f"frames, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ParameterError(f"clip {clip!r}: {what} opening has {int((~np.isfinite(a)).sum())} "
                             "non-finite frames; all must be finite")
    return a


def _mask(x, n: int, what: str, clip: str) -> np.ndarray:
    m = np.asarray(x)
    if m.shape != (n,):
        raise ParameterError(f"clip {clip!r}: {what} mask must have shape ({n},) to match the "
                             f"openings, got {m.shape}")
    return m.astype(bool)


def phone_segments(phones) -> tuple:
    """``((start_s, end_s, phone), …)`` of PhoneSegment-like objects or tuples."""
    return tuple((float(p.start_s), float(p.end_s), str(p.phone)) if hasattr(p, "phone")
                 else (float(p[0]), float(p[1]), str(p[2])) for p in phones)


def speech_mask(phones, n: int, fps: float) -> np.ndarray:
    """Per frame (k at k / fps s) True where a non-silence phone covers it (the rule of
    :meth:`face_model.corpus.Utterance.phone_per_frame`), shape (n,)."""
    t = np.arange(n) / fps
    out = np.zeros(n, bool)
    for s, e, ph in phone_segments(phones):
        if ph != SILENCE:
            out[(t >= s) & (t < e)] = True
    return out


def closure_segments(phones) -> tuple[list, list]:
    """``(bilabial, control)``: the centres (s) of the runs of adjacent /p b m/ phones, and of
    the other non-silence phones."""
    bil, ctl, prev = [], [], None
    for s, e, ph in phone_segments(phones):
        if ph in BILABIALS:
            if prev in BILABIALS and abs(bil[-1][1] - s) < 1e-6:
                bil[-1] = (bil[-1][0], e)
            else:
                bil.append((s, e))
        elif ph != SILENCE:
            ctl.append((s, e))
        prev = ph
    return [(a + b) / 2 for a, b in bil], [(a + b) / 2 for a, b in ctl]


@dataclass(frozen=True)
class ClipTrack:
    """One clip: real and predicted openings (one per frame at ``fps``), its phone labels
    (``(start_s, end_s, phone)`` or :class:`face_model.corpus.PhoneSegment`; None: unknown),
    the ``speech`` mask (from the phones unless given) and the ``valid`` mask (default all),
    and, for LVE, the aligned markers of both (both or neither).

    Raises
    ------
    ParameterError
        Naming the clip: openings not finite 1-D tracks, lengths that differ (with both
        lengths), masks or markers of the wrong shape, ``fps`` not positive.
    """

    clip: str
    speaker: str
    real: np.ndarray
    predicted: np.ndarray
    fps: float
    phones: tuple | None = field(default=None, repr=False)
    valid: np.ndarray | None = field(default=None, repr=False)
    speech: np.ndarray | None = field(default=None, repr=False)
    real_markers: np.ndarray | None = field(default=None, repr=False)
    predicted_markers: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        c = self.clip
        real, pred = _track(self.real, "real", c), _track(self.predicted, "predicted", c)
        if len(real) != len(pred):
            raise ParameterError(f"clip {c!r}: real opening has {len(real)} frames and predicted "
                                 f"{len(pred)}; they must be equal")
        if not (isinstance(self.fps, (int, float, np.number)) and math.isfinite(self.fps)
                and self.fps > 0):
            raise ParameterError(f"clip {c!r}: fps must be positive, got {self.fps}")
        if (self.real_markers is None) != (self.predicted_markers is None):
            raise ParameterError(f"clip {c!r}: give both real and predicted markers, or neither")
        n, set_ = len(real), (lambda k, v: object.__setattr__(self, k, v))
        set_("real", real)
        set_("predicted", pred)
        set_("fps", float(self.fps))
        phones = None if self.phones is None else phone_segments(self.phones)
        set_("phones", phones)
        set_("valid", np.ones(n, bool) if self.valid is None
             else _mask(self.valid, n, "valid", c))
        if self.speech is not None:
            set_("speech", _mask(self.speech, n, "speech", c))
        elif phones is not None:
            set_("speech", speech_mask(phones, n, self.fps))
        for k in ("real_markers", "predicted_markers"):
            m = getattr(self, k)
            if m is not None:
                m = np.asarray(m, dtype=np.float64)
                if m.shape != (n, N_MARKERS, 2):
                    raise ParameterError(f"clip {c!r}: {k.split('_')[0]} markers must have shape "
                                         f"({n}, {N_MARKERS}, 2) to match its opening, got "
                                         f"{m.shape}")
                set_(k, m)

    @classmethod
    def from_markers(cls, clip: str, speaker: str, real_markers, predicted_markers, fps: float,
                     *, phones=None, valid=None, lve: bool = True) -> ClipTrack:
        """The track of two aligned marker sequences (n, 79, 2) px, openings by
        :func:`~face_model.layout.mouth_opening`; the markers kept for LVE when ``lve`` (the
        model was trained on this speaker)."""
        real, pred = np.asarray(real_markers), np.asarray(predicted_markers)
        if len(real) != len(pred):
            raise ParameterError(f"clip {clip!r}: real markers have {len(real)} frames and "
                                 f"predicted {len(pred)}; they must be equal")
        return cls(clip, speaker, mouth_opening(real), mouth_opening(pred), fps, phones, valid,
                   None, real if lve else None, pred if lve else None)

    @property
    def n_frames(self) -> int:
        return len(self.real)

    @property
    def speech_known(self) -> bool:
        return self.speech is not None

    def parts(self) -> tuple[np.ndarray, np.ndarray]:
        """``(speech, silence)`` frame masks, valid frames only (all valid frames are speech
        when the speech frames are unknown)."""
        if self.speech is None:
            return self.valid.copy(), np.zeros(self.n_frames, bool)
        return self.valid & self.speech, self.valid & ~self.speech


def _z(x: np.ndarray) -> np.ndarray:
    s = x.std() if len(x) else 0.0
    return (x - x.mean()) / s if s > 0 else np.zeros_like(x)


def _zsum(real: np.ndarray, pred: np.ndarray, m: np.ndarray) -> float:
    """``Σ z_real · z_pred`` over the frames ``m`` (each z on those frames)."""
    return float(np.dot(_z(real[m]), _z(pred[m]))) if m.any() else 0.0


def closed_level(x: np.ndarray, speech: np.ndarray) -> float:
    """The level at or below which track ``x`` is closed: its speech-frame minimum plus
    :data:`CLOSE_FRACTION` of its speech-frame range (NaN: no speech frame or no range)."""
    if not speech.any():
        return float("nan")
    lo, hi = float(x[speech].min()), float(x[speech].max())
    return lo + CLOSE_FRACTION * (hi - lo) if hi > lo else float("nan")


def _windows(centres, n: int, fps: float, usable: np.ndarray) -> list[tuple]:
    """Per centre (s): ``(frames of its window that are usable, whole window usable)``."""
    t = np.arange(n) / fps
    out = []
    for c in centres:
        w = np.abs(t - c) <= HALF_WINDOW_S + 1e-9
        out.append((np.flatnonzero(w & usable), bool(w.any() and usable[w].all())))
    return out


def _closes(x: np.ndarray, level: float, windows: list) -> list[bool]:
    if math.isnan(level):
        return [False] * len(windows)
    return [bool(len(w) and (x[w] <= level + 1e-12).any()) for w in windows]


@dataclass(frozen=True)
class ClipScore:
    """One row of the per-clip table (:data:`CSV_COLUMNS`) with the pooled-r sums."""

    clip: str
    speaker: str
    n_frames: int
    fps: float
    valid_frames: int
    speech_frames: int
    r_speech: float
    r_silence: float
    bilabial_segments: int
    real_closed: int
    closures_hit: int
    control_segments: int
    real_false_closures: int
    false_closures: int
    chance_r_speech: float
    chance_closures_hit: float
    chance_false_closures: float
    lve_px: float
    sums: dict = field(repr=False)  # zz_speech, zz_silence, n_silence, chance_zz_*

    def row(self) -> dict:
        return {c: getattr(self, c) for c in CSV_COLUMNS}


def _closure_counts(t: ClipTrack, pred: np.ndarray, speech: np.ndarray, bil, ctl) -> tuple:
    level = closed_level(pred, speech)
    return sum(_closes(pred, level, bil)), sum(_closes(pred, level, ctl))


def score_clip(t: ClipTrack) -> ClipScore:
    """One clip's figures and the sums the pooled ones are made of (module docstring)."""
    n, real, pred = t.n_frames, t.real, t.predicted
    speech, silence = t.parts()
    bil_c, ctl_c = closure_segments(t.phones) if t.phones is not None else ([], [])
    bil = [w for w, _ in _windows(bil_c, n, t.fps, speech) if len(w)]
    ctl = [w for (w, whole), c in zip(_windows(ctl_c, n, t.fps, speech), ctl_c)
           if whole and all(abs(c - b) > 2 * HALF_WINDOW_S for b in bil_c)]
    real_level = closed_level(real, speech)
    real_closed = sum(_closes(real, real_level, bil))
    real_false = sum(_closes(real, real_level, ctl))
    hits, false = _closure_counts(t, pred, speech, bil, ctl)
    sums = {"zz_speech": _zsum(real, pred, speech), "zz_silence": _zsum(real, pred, silence),
            "n_silence": int(silence.sum())}
    chance = {"zz_speech": [], "zz_silence": [], "hits": [], "false": []}
    for f in CHANCE_SHIFTS:
        shifted = np.roll(pred, int(round(f * n)))
        chance["zz_speech"].append(_zsum(real, shifted, speech))
        chance["zz_silence"].append(_zsum(real, shifted, silence))
        h, fc = _closure_counts(t, shifted, speech, bil, ctl)
        chance["hits"].append(h)
        chance["false"].append(fc)
    sums.update({f"chance_{k}": float(np.mean(v)) for k, v in chance.items()})
    lve = float("nan")
    if t.real_markers is not None and t.valid.any():
        flat = (lambda m: m[t.valid].reshape(int(t.valid.sum()), 2 * N_MARKERS))
        lve = lip_vertex_error(flat(t.real_markers), flat(t.predicted_markers))
    n_speech = int(speech.sum())
    return ClipScore(t.clip, t.speaker, n, t.fps, int(t.valid.sum()), n_speech,
                     correlation(real[speech], pred[speech]) if n_speech >= 2 else float("nan"),
                     correlation(real[silence], pred[silence]) if silence.sum() >= 2
                     else float("nan"), len(bil), real_closed, hits, len(ctl), real_false, false,
                     sums["chance_zz_speech"] / n_speech if n_speech else float("nan"),
                     sums["chance_hits"], sums["chance_false"], lve, sums)


@dataclass
class FaceScores:
    """Per-clip scores and the pooled figures (module docstring); ``tracks`` the clips scored."""

    clips: list
    pooled: dict
    tracks: list = field(default_factory=list, repr=False)

    def to_dict(self) -> dict:
        """Plain JSON-ready values (NaN as None) with the rule's settings."""
        rule = {"half_window_s": HALF_WINDOW_S, "close_fraction": CLOSE_FRACTION,
                "chance_shifts": list(CHANCE_SHIFTS), "bilabials": sorted(BILABIALS)}
        return _json_safe({"rule": rule, "pooled": self.pooled,
                           "clips": [c.row() for c in self.clips]})


def _json_safe(x):
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    return int(x) if isinstance(x, np.integer) else x


def _ratio(a: float, b: float) -> float:
    return a / b if b else float("nan")


def score_clips(tracks) -> FaceScores:
    """Score every clip of ``tracks`` (:class:`ClipTrack`) and pool them.

    Returns
    -------
    FaceScores
        ``clips`` in the order given; ``pooled``: ``clips, speakers, frames, valid_frames,
        excluded_frames, speech_frames, silence_frames, speech_known`` (every clip has phones),
        ``r_speech, r_silence`` (pooled r) and ``chance_r_speech, chance_r_silence``,
        ``r_clip_median, r_clip_mean`` (speech frames, finite clips), ``bilabial_segments,
        real_closed, real_closed_rate, closures_hit, closure_rate, chance_closure_rate,
        control_segments, real_false_closure_rate`` (the real lips' own, by the same test),
        ``false_closures, false_closure_rate, chance_false_closure_rate``,
        ``lve_px`` (frame-weighted over the clips with markers) and ``lve_clips``, and the
        speaker-level intervals ``interval_r_speech, interval_closure_rate`` (text: the
        interval, or why there is none).

    Raises
    ------
    ParameterError
        No tracks, an item that is not a ClipTrack, or a clip id given twice.
    """
    tracks = list(tracks)
    if not tracks:
        raise ParameterError("no clips to score; give at least one ClipTrack")
    seen = set()
    for t in tracks:
        if not isinstance(t, ClipTrack):
            raise ParameterError(f"tracks must be ClipTrack, got {type(t).__name__}")
        if t.clip in seen:
            raise ParameterError(f"clip {t.clip!r} is given twice; clip ids must be unique")
        seen.add(t.clip)
    clips = [score_clip(t) for t in tracks]
    tot = (lambda k: sum(c.sums[k] for c in clips))
    total = (lambda a: sum(getattr(c, a) for c in clips))
    n_sp, n_si = total("speech_frames"), tot("n_silence")
    rs = np.array([c.r_speech for c in clips])
    rs = rs[np.isfinite(rs)]
    bil, ctl = total("bilabial_segments"), total("control_segments")
    with_lve = [c for c in clips if math.isfinite(c.lve_px)]
    lve_frames = sum(c.valid_frames for c in with_lve)
    spk = [c.speaker for c in clips]
    r_int = speaker_interval(spk, [c.sums["zz_speech"] for c in clips],
                             [c.speech_frames for c in clips])
    c_int = speaker_interval(spk, [c.closures_hit for c in clips],
                             [c.bilabial_segments for c in clips])
    pooled = {
        "clips": len(clips), "speakers": len(set(spk)), "frames": total("n_frames"),
        "valid_frames": total("valid_frames"),
        "excluded_frames": total("n_frames") - total("valid_frames"),
        "speech_frames": n_sp, "silence_frames": n_si,
        "speech_known": all(t.speech_known for t in tracks),
        "r_speech": _ratio(tot("zz_speech"), n_sp), "r_silence": _ratio(tot("zz_silence"), n_si),
        "chance_r_speech": _ratio(tot("chance_zz_speech"), n_sp),
        "chance_r_silence": _ratio(tot("chance_zz_silence"), n_si),
        "r_clip_median": float(np.median(rs)) if len(rs) else float("nan"),
        "r_clip_mean": float(np.mean(rs)) if len(rs) else float("nan"),
        "bilabial_segments": bil, "real_closed": total("real_closed"),
        "real_closed_rate": _ratio(total("real_closed"), bil),
        "closures_hit": total("closures_hit"), "closure_rate": _ratio(total("closures_hit"), bil),
        "chance_closure_rate": _ratio(tot("chance_hits"), bil),
        "control_segments": ctl,
        "real_false_closure_rate": _ratio(total("real_false_closures"), ctl),
        "false_closures": total("false_closures"),
        "false_closure_rate": _ratio(total("false_closures"), ctl),
        "chance_false_closure_rate": _ratio(tot("chance_false"), ctl),
        "lve_px": (sum(c.lve_px * c.valid_frames for c in with_lve) / lve_frames
                   if with_lve else float("nan")),
        "lve_clips": len(with_lve),
        "interval_r_speech": r_int.text(3), "interval_closure_rate": c_int.text(3)}
    return FaceScores(clips, pooled, tracks)


def write_scores_csv(scores: FaceScores, path, *, extra: dict | None = None):
    """The per-clip table (:data:`CSV_COLUMNS`, floats in full, then the ``extra`` columns with
    one value for every row, e.g. ``input_rate``), written atomically; the pooled figures are in
    :meth:`FaceScores.to_dict`."""
    extra = dict(extra or {})
    with atomic_file(path) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow([*CSV_COLUMNS, *extra])
            for c in scores.clips:
                w.writerow([repr(float(v)) if isinstance(v, (float, np.floating)) else v
                            for v in c.row().values()] + list(extra.values()))
    return path


def normalised(track: ClipTrack) -> tuple[np.ndarray, np.ndarray]:
    """Real and predicted openings z-scored on the clip's valid speech frames (for figures)."""
    speech, _ = track.parts()
    out = []
    for x in (track.real, track.predicted):
        s = x[speech].std() if speech.any() else 0.0
        out.append((x - x[speech].mean()) / s if s > 0 else np.zeros_like(x))
    return out[0], out[1]


def opening_strip_figure(track: ClipTrack, path, title: str = "", *, width: float = 1.0):
    """Real and predicted opening of one clip over time (z on its speech frames), silence and
    invalid frames shaded, the /p b m/ segments marked (green: the prediction closes it, red:
    it does not)."""
    if not isinstance(track, ClipTrack):
        raise ParameterError(f"track must be a ClipTrack, got {type(track).__name__}")
    real, pred = normalised(track)
    speech, _ = track.parts()
    n, fps = track.n_frames, track.fps
    bil_c = closure_segments(track.phones)[0] if track.phones is not None else []
    wins = [w for w, _ in _windows(bil_c, n, fps, speech)]
    hit = _closes(track.predicted, closed_level(track.predicted, speech), wins)
    t = np.arange(n) / fps
    with report_figure(path, width=width, height_in=2.6) as fig:
        ax = fig.subplots()
        for k in np.flatnonzero(~speech):
            ax.axvspan(t[k] - 0.5 / fps, t[k] + 0.5 / fps, color="0.9", lw=0)
        for c, ok in zip(bil_c, hit):
            ax.axvspan(c - HALF_WINDOW_S, c + HALF_WINDOW_S, color="#2ca02c" if ok else
                       "#d62728", alpha=0.25, lw=0)
        ax.plot(t, real, c="0.2", lw=1.3, label="real")
        ax.plot(t, pred, c="#1f77b4", lw=1.3, label="predicted")
        ax.set_xlim(t[0], t[-1])
        ax.set_xlabel("time (s)")
        ax.set_ylabel("lip opening (z, speech frames)")
        ax.set_title(title or f"{track.clip} ({track.speaker})", wrap=True)
        ax.grid(alpha=0.3)
        fig.legend(loc="outside lower center", ncol=2)
    return path
