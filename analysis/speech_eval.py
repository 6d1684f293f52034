"""A trained mapping scored on real speech (issue 12, part 5): the gate's frame accuracy, lip
closure at /p b m/, labiodental contact at /f v/, and the correlation of the predicted lip
opening with the generator's own reference trajectory drawn from the real phone labels.

Frames. Frame k sits at k / fps seconds (the corpus convention); its true phone is the labelled
segment holding that instant (:func:`phone_frames`).

Lip opening. ``face_model.layout.mouth_opening`` of the markers the run's animator draws from
the predicted MUPs (:class:`mapping.animator.FaceAnimator`, as ``talkingface animate`` does):
inner lower lip minus inner upper lip, pixels.

Closed-lip threshold (:func:`closed_threshold`). The generator draws two closed mouths: the
bilabial press (closure = 1: about 0 px on the layout's face, the lips pressed together) and the
rest face that silences and the mapping's silence rule draw ("a closed, neutral mouth": 2.1 px on
the layout's face, the inner contours just touching in the drawing). The threshold is the larger
of the two — the rest opening of the face being animated — so the lips *meet* in a frame when
they are no further apart than in the generator's own closed neutral mouth. Every open sound of
the generator lies well above it (``s`` 4.3 px, ``t`` 5.1, ``uw`` 5.0, ``iy`` 5.6, ``aa`` 16.2).

(a) Gate accuracy: the gate's class per frame (``GatedMLP.gate_classes``) against the labelled
phone's class after the model's own small-class merges (as ``mapping.phone_gate.gate_accuracy``
measures it in-domain); viseme accuracy compares the visemes
(``i a o f u m neutral``; silence is neutral) of the chosen class and of the labelled phone. A gate
of 8 groups gives the viseme accuracy only; one group (or every class merged into one, or a
method without a gate) neither.

(b) Bilabial closure: a /p b m/ segment is *closed* when the opening falls to the threshold in
some frame whose 1/fps span overlaps the segment (a segment shorter than a frame still has the
frame nearest its centre). The centre opening (linear interpolation at the segment's midpoint)
is reported relative to the median opening over frames labelled with a vowel.

(c) Labiodental contact: the same for /f v/. In the generator the lower lip tucks up under the
upper teeth (``lower_tuck``), which drives the inner opening *below* the bilabial press
(about −2.4 px), so contact is the same test against the same threshold.

(d) Reference correlation: Pearson's r between the predicted opening and the opening of the
generator's face for speaker 0 of the run's synth config, driven by
``data_synth.articulation.coarticulate`` of the real phone labels (no expression, no brows, no
head motion, no noise).
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from analysis.figures import phone_labels, report_figure
from analysis.speech_set import PARTS
from data_synth.articulation import coarticulate
from data_synth.backends import ESPEAK_SPEAKER, voice_speaker
from data_synth.config import SynthConfig
from data_synth.face import articulate, make_speaker
from data_synth.flite import VOICE as FLITE_VOICE
from face_model.corpus import read_manifest
from face_model.layout import mouth_opening
from face_model.phones import BILABIALS, PHONE_INDEX, PHONES, VISEMES, viseme
from groundwork.errors import ParameterError
from mapping.animator import FaceAnimator

VOWELS = frozenset("iy ih ey eh ae aa ah ax ay aw ao ow oy uw uh er".split())
LABIODENTALS = frozenset({"f", "v"})
_VISEME_OF_PHONE = np.array([VISEMES.index(viseme(p)) for p in PHONES])


def phone_frames(segments, times: np.ndarray) -> np.ndarray:
    """Phone index (into ``PHONES``) of the segment holding each time; times past the last
    segment take the last one."""
    ends = np.array([s.end_s for s in segments])
    idx = np.minimum(np.searchsorted(ends, np.asarray(times), side="right"), len(segments) - 1)
    return np.array([PHONE_INDEX[segments[i].phone] for i in idx], dtype=int)


def viseme_index(phone_idx: np.ndarray) -> np.ndarray:
    """Viseme (index into ``VISEMES``) of each phone index."""
    return _VISEME_OF_PHONE[np.asarray(phone_idx, dtype=int)]


def group_viseme(name: str) -> int:
    """Viseme index of a gate class name: a phone, or a group of the 8-class gate
    (``other`` and ``sil`` are neutral)."""
    if name in PHONE_INDEX:
        return int(_VISEME_OF_PHONE[PHONE_INDEX[name]])
    return VISEMES.index(name if name in VISEMES else "neutral")


def frame_accuracy(true: np.ndarray, pred: np.ndarray) -> float:
    """Fraction of frames where ``pred`` equals ``true`` (NaN for no frames)."""
    true, pred = np.asarray(true), np.asarray(pred)
    return float(np.mean(true == pred)) if len(true) else float("nan")


@dataclass(frozen=True)
class Contact:
    """Per-segment result of :func:`segment_contact`: whether the lips met and the opening at
    the segment's centre (px), one entry per segment of the chosen phones."""

    met: np.ndarray
    centre_opening: np.ndarray

    @property
    def n(self) -> int:
        return len(self.met)

    @property
    def fraction(self) -> float:
        return float(self.met.mean()) if self.n else float("nan")


def segment_contact(opening: np.ndarray, fps: float, segments, phones, threshold: float
                    ) -> Contact:
    """For each segment whose phone is in ``phones``: do the lips meet (``opening`` ≤
    ``threshold`` in a frame whose span [t − 1/2fps, t + 1/2fps) overlaps the segment, or in the
    frame nearest the centre of a shorter segment), and the opening at its centre (linear
    interpolation). ``opening`` (n_frames,) pixels, frame k at k / fps s."""
    opening = np.asarray(opening, dtype=np.float64)
    times = np.arange(len(opening)) / fps
    half = 0.5 / fps
    met, centre = [], []
    for s in segments:
        if s.phone not in phones:
            continue
        c = 0.5 * (s.start_s + s.end_s)
        inside = (times + half > s.start_s) & (times - half < s.end_s)
        k = np.flatnonzero(inside)
        if len(k) == 0:
            k = [int(np.clip(round(c * fps), 0, len(opening) - 1))]
        met.append(bool(np.min(opening[k]) <= threshold))
        centre.append(float(np.interp(c, times, opening)))
    return Contact(np.array(met, dtype=bool), np.array(centre))


def vowel_median(opening: np.ndarray, phone_idx: np.ndarray) -> float:
    """Median opening over the frames labelled with a vowel (NaN if there are none)."""
    sel = np.isin(np.asarray(phone_idx), [PHONE_INDEX[p] for p in VOWELS])
    return float(np.median(np.asarray(opening)[sel])) if sel.any() else float("nan")


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson's r of two equal-length tracks (NaN when either is constant)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if len(a) != len(b):
        raise ParameterError(f"tracks of {len(a)} and {len(b)} frames cannot be correlated")
    if len(a) < 2 or np.std(a) == 0 or np.std(b) == 0:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1])


def closed_threshold(neutral: np.ndarray) -> float:
    """The closed-lip threshold (px): the rest opening of the face ``neutral`` (79, 2), the
    larger of the generator's two closed mouths (see the module docstring)."""
    return float(mouth_opening(np.asarray(neutral)[None])[0])


def reference_opening(segments, n_frames: int, fps: float, synth: SynthConfig, seed: int
                      ) -> np.ndarray:
    """Opening (n_frames,) px of the generator's face, speaker 0 of ``synth`` and ``seed``,
    articulating the phone ``segments`` with its own coarticulation model."""
    times = np.arange(n_frames) / fps
    artic = coarticulate(segments, times, theta_anticipation=synth.theta_anticipation,
                         theta_carryover=synth.theta_carryover, power=synth.dominance_power)
    face = articulate(make_speaker(0, synth, seed), artic, np.zeros(n_frames),
                      expression="neutral", envelope=np.zeros(n_frames), cfg=synth)
    return mouth_opening(face)


def training_speakers(corpus_dir) -> frozenset:
    """The real source speakers (``arctic_slt`` …) of the voices the corpus at ``corpus_dir``
    was synthesised with: its manifest's ``voice`` column (``engine:voice``), or, without one,
    the single voice of its ``backend`` (``corpus.json``: espeak's formant voice is built from
    no real speaker, flite's default is :data:`data_synth.flite.VOICE`), through
    :func:`data_synth.backends.voice_speaker`. A folder without a manifest is a
    :class:`~groundwork.errors.CorpusError` saying the manifest is needed."""
    root = Path(corpus_dir)
    rows = read_manifest(root / "manifest.csv", (), not_found="the training corpus's manifest "
                         "is needed to tell seen from unseen speakers")
    voices = {row.get("voice") or "" for row in rows}
    if "" in voices:
        info = json.loads((root / "corpus.json").read_text(encoding="utf-8"))
        backend = (info.get("settings") or {}).get("backend", "espeak")
        voices = (voices - {""}) | {f"flite:{FLITE_VOICE}" if backend == "flite"
                                    else "espeak:en-us"}
    return frozenset(s for s in map(voice_speaker, voices) if s != ESPEAK_SPEAKER)


# -- one model on the set ---------------------------------------------------------------------
@dataclass
class FileScores:
    """A model's scores on one recording, with the per-frame tracks the figure and the pooled
    figures need."""

    id: str
    speaker_source: str
    seen: bool
    seconds: float
    part: str  # "dev" or "test" (analysis.speech_set)
    labels: str  # "independent" of both recognisers, or "aligned" by pocketsphinx
    phone_acc: float
    viseme_acc: float
    bilabial: Contact
    labiodental: Contact
    vowel_median_px: float
    r_reference: float
    n_frames: int
    tracks: dict = field(repr=False, default_factory=dict)

    def row(self) -> dict:
        b, f = self.bilabial, self.labiodental
        return {"id": self.id, "speaker_source": self.speaker_source,
                "split": "seen" if self.seen else "unseen", "part": self.part,
                "labels": self.labels,
                "seconds": round(self.seconds, 3),
                "frames": self.n_frames, "phone_acc": self.phone_acc,
                "viseme_acc": self.viseme_acc, "bilabial_segments": b.n,
                "bilabial_closed": int(b.met.sum()), "bilabial_closed_frac": b.fraction,
                "bilabial_centre_px": _median(b.centre_opening),
                "labiodental_segments": f.n, "labiodental_contact": int(f.met.sum()),
                "labiodental_contact_frac": f.fraction,
                "labiodental_centre_px": _median(f.centre_opening),
                "vowel_median_px": self.vowel_median_px,
                "bilabial_centre_rel_vowel": _median(b.centre_opening) / self.vowel_median_px,
                "r_reference": self.r_reference}


def _median(x) -> float:
    return float(np.median(x)) if len(x) else float("nan")


def gate_tracks(mapping, y: np.ndarray, sr: int, true_phone: np.ndarray):
    """``(phone_acc, viseme_acc, gated class names)`` of the mapping's gate on one recording
    (NaN where the gate cannot say: 8 groups give no phone accuracy, 1 group or no gate
    neither)."""
    mapper = mapping.mapper
    # no gate, or every class merged into one (a corpus too small for more): nothing to score
    if not hasattr(mapper, "gate_classes") or len(set(mapper.group_of_phone_.tolist())) == 1:
        return float("nan"), float("nan"), None
    gated = mapping.gate_classes(y, sr)[:len(true_phone)]
    names = [mapper.class_names_[g] for g in gated]
    true = true_phone[:len(gated)]
    vis = frame_accuracy(viseme_index(true), [group_viseme(n) for n in names])
    phone = (frame_accuracy(mapper.group_of_phone_[true], gated)
             if len(mapper.class_names_) == len(PHONES) else float("nan"))
    return phone, vis, names


def score_file(animator: FaceAnimator, item, synth: SynthConfig, seed: int, *, seen: bool,
               threshold: float) -> FileScores:
    """Every measure of the module docstring on one recording (``analysis.speech_set``)."""
    m = animator.mapping
    mups = m.predict_audio(item.audio, item.sr)
    opening = mouth_opening(animator.markers(mups)).astype(np.float64)
    n, fps = len(opening), m.fps
    true = phone_frames(item.phones, np.arange(n) / fps)
    phone_acc, vis_acc, gated = gate_tracks(m, item.audio, item.sr, true)
    ref = reference_opening(item.phones, n, fps, synth, seed)
    return FileScores(
        id=item.id, speaker_source=item.speaker_source, seen=seen, seconds=item.duration_s,
        part=item.part, labels="independent" if item.independent else "aligned",
        phone_acc=phone_acc, viseme_acc=vis_acc,
        bilabial=segment_contact(opening, fps, item.phones, BILABIALS, threshold),
        labiodental=segment_contact(opening, fps, item.phones, LABIODENTALS, threshold),
        vowel_median_px=vowel_median(opening, true), r_reference=correlation(opening, ref),
        n_frames=n, tracks={"opening": opening, "reference": ref, "true": true, "gated": gated,
                            "fps": fps})


def pooled(scores: list, split: str) -> dict:
    """The figures of ``scores`` pooled over files: frame accuracies over all frames, closure
    and contact over all segments, centre openings over all segments relative to the median
    of every vowel frame, and the mean of the per-file correlations."""
    if not scores:
        return {"split": split, "files": 0}
    frames = np.array([s.n_frames for s in scores])

    def weighted(attr):
        v = np.array([getattr(s, attr) for s in scores])
        return float(np.sum(v * frames) / frames.sum()) if np.isfinite(v).all() else float("nan")

    bil = np.concatenate([s.bilabial.met for s in scores])
    lab = np.concatenate([s.labiodental.met for s in scores])
    bc = np.concatenate([s.bilabial.centre_opening for s in scores])
    lc = np.concatenate([s.labiodental.centre_opening for s in scores])
    vowels = np.concatenate([s.tracks["opening"][np.isin(s.tracks["true"], [
        PHONE_INDEX[p] for p in VOWELS])] for s in scores])
    vmed = _median(vowels)
    rs = np.array([s.r_reference for s in scores])
    return {"split": split, "files": len(scores),
            "seconds": round(float(sum(s.seconds for s in scores)), 2),
            "speakers": len({s.speaker_source for s in scores}),
            "phone_acc": weighted("phone_acc"), "viseme_acc": weighted("viseme_acc"),
            "bilabial_segments": len(bil), "bilabial_closed_frac":
                float(bil.mean()) if len(bil) else float("nan"),
            "bilabial_centre_rel_vowel": _median(bc) / vmed,
            "labiodental_segments": len(lab), "labiodental_contact_frac":
                float(lab.mean()) if len(lab) else float("nan"),
            "labiodental_centre_rel_vowel": _median(lc) / vmed,
            "vowel_median_px": vmed, "r_reference": float(np.nanmean(rs)) if
                np.isfinite(rs).any() else float("nan")}


@dataclass
class ModelScores:
    """One model on the set: per-file scores and the pooled rows (seen, unseen, all)."""

    model: str
    threshold_px: float
    files: list
    summary: list

    def per_file_rows(self) -> list:
        return [{"model": self.model, **f.row()} for f in self.files]

    def summary_rows(self) -> list:
        return [{"model": self.model, "threshold_px": self.threshold_px, **r}
                for r in self.summary]


def synth_of(mapping) -> tuple[SynthConfig, int]:
    """The synth settings and seed the mapping's corpus was made with (its file's metadata;
    the defaults when the file does not say)."""
    cfg = mapping.metadata.get("config") or {}
    known = {f.name for f in dataclasses.fields(SynthConfig)}
    synth = {k: tuple(v) if isinstance(v, list) else v
             for k, v in (cfg.get("synth") or {}).items() if k in known}
    return SynthConfig(**synth), int(mapping.metadata.get("seed", cfg.get("seed", 2002)))


def score_model(name: str, mapping, units, items, seen_sources=frozenset()) -> ModelScores:
    """Score ``mapping`` (an AudioMapping) with its Motion Units ``units`` on the recordings
    ``items``; a recording is *seen* when its ``speaker_source`` is in ``seen_sources``."""
    animator = FaceAnimator(mapping, units)
    synth, seed = synth_of(mapping)
    threshold = closed_threshold(animator.neutral)
    files = [score_file(animator, it, synth, seed, seen=it.speaker_source in seen_sources,
                        threshold=threshold) for it in items]
    summary = [pooled([f for f in files if f.seen], "seen"),
               pooled([f for f in files if not f.seen], "unseen"), pooled(files, "all"),
               *[pooled([f for f in files if not f.seen and f.part == p], f"unseen-{p}")
                 for p in PARTS],
               *[pooled([f for f in files if not f.seen and f.part == "test"
                         and f.labels == lab], f"unseen-test-{lab}")
                 for lab in ("independent", "aligned")]]
    return ModelScores(name, threshold, files, summary)


def opening_figure(scores: FileScores, segments, path, *, title: str = "",
                   width: float = 1.0) -> Path:
    """Predicted vs reference lip opening over time on one recording, its phones written
    along the top and its /p b m/ and /f v/ segments shaded."""
    tr = scores.tracks
    t = np.arange(len(tr["opening"])) / tr["fps"]
    with report_figure(path, width=width, height_in=2.7) as fig:
        ax = fig.subplots()
        for s in segments:
            if s.phone in BILABIALS or s.phone in LABIODENTALS:
                ax.axvspan(s.start_s, s.end_s, color="#d62728" if s.phone in BILABIALS
                           else "#2ca02c", alpha=0.15, lw=0)
        phone_labels(ax, [(s.start_s, s.end_s, s.phone) for s in segments], y=1.01, dy=0.08)
        ax.plot(t, tr["reference"], c="0.4", lw=1.3, ls="--",
                label="reference (generator's coarticulation of the real labels)")
        ax.plot(t, tr["opening"], c="#1f77b4", lw=1.4, label="predicted from the audio")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("inner-lip opening (px)")
        ax.set_title(title or scores.id, pad=22, wrap=True)
        ax.grid(alpha=0.3)
        fig.legend(loc="outside lower center", ncol=2)
    return Path(path)
