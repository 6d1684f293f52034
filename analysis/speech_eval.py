"""A trained mapping scored on real speech (issue 12, part 5; issue 37): the gate's frame
accuracy, lip closure at /p b m/, labiodental contact at /f v/, and the correlation of the
predicted lip opening with the generator's own reference trajectory drawn from the real phone
labels — each beside its chance baseline, on recordings whose speaker is the unit
(DESIGN.md, "Evaluation on real data"). The frame-level scores are :mod:`analysis.speech_scores`;
pooling, splits, intervals and the per-speaker table are :mod:`analysis.speech_pooling`.

Seen and unseen. A model's *training speakers* (:func:`training_speakers`) are the speaker ids
of its training corpus: the real speakers its synthetic voices were built from (flite's ``slt``
is ``arctic-slt``; espeak's formant voices are ``espeak``), and for a corpus given from
recordings (``corpus.json`` names its ``source``) the manifest's own speakers (``grid-s1``).
A recording is *seen* iff its ``speaker`` is one of them.

Lip opening. ``face_model.layout.mouth_opening`` of the markers the run's animator draws from
the predicted MUPs (:class:`mapping.animator.FaceAnimator`, as ``talkingface animate`` does):
inner lower lip minus inner upper lip, pixels.

Closed-lip threshold (:func:`closed_threshold`). The generator draws two closed mouths: the
bilabial press (about 0 px on the layout's face) and the rest face that silences and the
mapping's silence rule draw ("a closed, neutral mouth": 2.1 px on the layout's face). The
threshold is the larger of the two — the rest opening of the face being animated — so the lips
*meet* in a frame when they are no further apart than in the generator's own closed neutral
mouth. Every open sound of the generator lies well above it (``s`` 4.3 px, ``aa`` 16.2).

(a) Gate accuracy: the gate's class per frame (``GatedMLP.gate_classes``) against the labelled
phone's class after the model's own small-class merges; viseme accuracy compares the visemes
(``i a o f u m neutral``; silence is neutral). A gate of 8 groups gives the viseme accuracy
only; one group (or a method without a gate) neither. Streaming: the gate of a frame model
decides frame k from the same features offline and live (:mod:`mapping.animator`: "its frames
equal the offline frames"), after its algorithmic look-ahead (:func:`stream_lookahead_s`), so
its streaming accuracy *is* the offline one — checked on one recording per model
(:func:`stream_matches`; a model whose live markers differ gets no streaming figure). The
column is named after the targets' look-ahead (``targets.lookahead_ms``); the model's own
look-ahead is recorded beside it (its context plus half its analysis window).

(b) Bilabial closure and (c) labiodental contact: :func:`analysis.speech_scores.segment_contact`
against the threshold; the centre opening relative to the median vowel opening.

(d) Reference correlation: r between the predicted opening and the opening of the generator's
face for speaker 0 of the run's synth config driven by the real phone labels, on speech frames,
clips centred and scaled before pooling (:func:`analysis.speech_scores.speech_r_terms`); the
silence frames' median opening is reported apart, relative to the vowel median.

Input rate. Each recording is scored as its file holds it (``native``) and, for the rate
variants, resampled down to 16 kHz or 8 kHz and given at that rate (:func:`rate_audio`); a
recording already at or below a variant's rate is not resampled and its row says so
(``rate_note``).
"""
from __future__ import annotations

import dataclasses
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from analysis.figures import phone_labels, report_figure
from analysis.speech_scores import (LABIODENTALS, VOWELS, ChanceTerms, Contact,  # noqa: F401
                                    chance_scores, correlation, fit_frames, frame_accuracy,
                                    group_viseme, label_frames, phone_frames, segment_contact,
                                    silence_opening, speech_r_terms, viseme_index, vowel_median)
from data_synth.articulation import articulation_model, coarticulate
from data_synth.backends import voice_speaker
from data_synth.config import SynthConfig
from data_synth.face import articulate, make_speaker
from data_synth.flite import VOICE as FLITE_VOICE
from face_model.corpus import read_manifest
from face_model.layout import mouth_opening
from face_model.phones import BILABIALS, PHONES
from groundwork.audio import read_wav, resample
from mapping.animator import FaceAnimator, StreamingAnimator
from mapping.features import algorithmic_latency_s
from mapping.hearing import Windows

NATIVE = "native"
RATES = (NATIVE, 16000, 8000)  # the input rates every score is given at


def closed_threshold(neutral: np.ndarray) -> float:
    """The closed-lip threshold (px): the rest opening of the face ``neutral`` (79, 2), the
    larger of the generator's two closed mouths (see the module docstring)."""
    return float(mouth_opening(np.asarray(neutral)[None])[0])


def reference_opening(segments, n_frames: int, fps: float, synth: SynthConfig, seed: int
                      ) -> np.ndarray:
    """Opening (n_frames,) px of the generator's face, speaker 0 of ``synth`` and ``seed``,
    articulating the phone ``segments`` with its own coarticulation model."""
    times = np.arange(n_frames) / fps
    artic = coarticulate(segments, times, articulation_model(synth))
    face = articulate(make_speaker(0, synth, seed), artic, np.zeros(n_frames),
                      expression="neutral", envelope=np.zeros(n_frames), cfg=synth)
    return mouth_opening(face)


def training_speakers(corpus_dir) -> frozenset:
    """The speaker ids of the corpus at ``corpus_dir``.

    A synthetic corpus (``corpus.json`` without ``source``): the real speakers of its voices
    (the manifest's ``voice`` column, ``engine:voice``, or without one the single voice of its
    ``backend``: espeak's accents are ``espeak``, flite's default is
    :data:`data_synth.flite.VOICE`), through :func:`data_synth.backends.voice_speaker`. A given
    corpus (``corpus.json`` names its ``source``, or there is no ``corpus.json``): its
    manifest's ``speaker`` ids (lowercase), and the speakers of any ``voice`` it lists too.
    Corpora combined into one (``corpus.json``'s ``parts``, each with its ``folder`` and its
    own ``info``: :func:`talkingface.stages.given_corpus.combine_corpora`): the union over the
    parts, each part's rows (their audio under its folder) by its own rule.

    Raises
    ------
    CorpusError
        The folder has no manifest (it is needed to tell seen from unseen speakers).
    """
    root = Path(corpus_dir)
    rows = read_manifest(root / "manifest.csv", (), not_found="the training corpus's manifest "
                         "is needed to tell seen from unseen speakers")
    info_file = root / "corpus.json"
    info = json.loads(info_file.read_text(encoding="utf-8")) if info_file.is_file() else None
    return _speakers(rows, info)


def _speakers(rows: list, info: dict | None) -> frozenset:
    """:func:`training_speakers` of manifest ``rows`` under their corpus's ``corpus.json``
    ``info`` (None: the corpus has none, so it is a given one); corpora combined (``parts``),
    each part's rows — their audio under its folder, the folder taken off — by its own
    ``info``, which may itself be combined."""
    if info and info.get("parts"):
        out = set()
        for part in info["parts"]:
            prefix = f"{part['folder']}/" if part.get("folder") else ""
            mine = [{**r, "audio": (r.get("audio") or "")[len(prefix):]} for r in rows
                    if (r.get("audio") or "").startswith(prefix)]
            out |= _speakers(mine, part.get("info"))
        return frozenset(out)
    given = info is None or bool(info.get("source"))
    info = info or {}
    out = set()
    if given:
        out |= {(r.get("speaker") or "").strip().lower() for r in rows} - {""}
    voices = {(r.get("voice") or "").strip() for r in rows}
    if "" in voices and not given:
        backend = (info.get("settings") or {}).get("backend") or info.get("backend", "espeak")
        voices.add(f"flite:{FLITE_VOICE}" if backend == "flite" else "espeak:en-us")
    out |= {voice_speaker(v) for v in voices - {""}}
    return frozenset(out)


def rate_audio(item, rate) -> tuple[np.ndarray, int, str]:
    """``(audio, sr, note)`` of recording ``item`` at input ``rate``: ``native`` reads the file
    at its own rate; 16000 or 8000 resamples it down to that rate, or, when the file's rate is
    already at most ``rate``, gives it as it is with a note saying so."""
    native_sr = int(getattr(item, "native_sr", item.sr))
    if native_sr == item.sr:
        y, sr = np.asarray(item.audio, np.float32), int(item.sr)
    else:
        y, sr = read_wav(item.wav)
    if rate == NATIVE:
        return y, sr, ""
    if sr <= int(rate):
        return y, sr, f"native {sr} Hz <= {int(rate)} Hz: scored once, as recorded"
    return resample(y, sr_in=sr, sr_out=int(rate)).astype(np.float32), int(rate), ""


# -- one model on one recording ---------------------------------------------------------------
@dataclass
class FileScores:
    """A model's scores on one recording, with the per-frame tracks the figure and the pooled
    figures need."""

    id: str
    speaker: str
    seen: bool
    seconds: float
    part: str  # "dev" or "test" (analysis.speech_set)
    kind: str  # "sentences" or "digits" (analysis.speech_set.SpeechItem.kind)
    labels: str  # "independent" of both recognisers, or "aligned" by pocketsphinx
    input_rate: str  # "native", "16000" or "8000"
    rate_note: str
    phone_acc: float
    viseme_acc: float
    stream: bool  # the streaming accuracy at the targets' look-ahead is the offline one
    bilabial: Contact
    labiodental: Contact
    vowel_median_px: float
    r_reference: float
    r_terms: float
    speech_frames: int
    silence_px: np.ndarray
    chance: ChanceTerms
    n_frames: int
    tracks: dict = field(repr=False, default_factory=dict)

    def row(self, stream_key: str) -> dict:
        b, f, n = self.bilabial, self.labiodental, self.n_frames
        c, k = self.chance, max(self.chance.n_shifts, 1)
        vis_hits = self.viseme_acc * n
        return {"id": self.id, "speaker": self.speaker,
                "split": "seen" if self.seen else "unseen", "part": self.part,
                "kind": self.kind, "labels": self.labels, "input_rate": self.input_rate,
                "rate_note": self.rate_note, "seconds": round(self.seconds, 3),
                "frames": n, "speech_frames": self.speech_frames,
                "phone_acc": self.phone_acc, "phone_hits": self.phone_acc * n,
                "viseme_acc": self.viseme_acc, "viseme_hits": vis_hits,
                stream_key: self.viseme_acc if self.stream else float("nan"),
                "viseme_stream_hits": vis_hits if self.stream else float("nan"),
                "bilabial_segments": b.n, "bilabial_closed": int(b.met.sum()),
                "bilabial_closed_frac": b.fraction,
                "bilabial_centre_px": _median(b.centre_opening),
                "labiodental_segments": f.n, "labiodental_contact": int(f.met.sum()),
                "labiodental_contact_frac": f.fraction,
                "labiodental_centre_px": _median(f.centre_opening),
                "vowel_median_px": self.vowel_median_px,
                "bilabial_centre_rel_vowel": _median(b.centre_opening) / self.vowel_median_px,
                "r_reference": self.r_reference, "r_terms": self.r_terms,
                "silence_frames": len(self.silence_px),
                "silence_px": _median(self.silence_px),
                "chance_viseme_hits": c.viseme_hits / k if np.isfinite(vis_hits) else np.nan,
                "chance_closed": c.closed / k, "chance_r_terms": c.r_terms / k}


def _median(x) -> float:
    return float(np.median(x)) if len(x) else float("nan")


def gate_tracks(mapping, y: np.ndarray, sr: int, true_phone: np.ndarray, what: str):
    """``(phone_acc, viseme_acc, gated class names, gated visemes)`` of the mapping's gate on
    one recording (NaN and None where the gate cannot say: 8 groups give no phone accuracy, 1
    group or no gate neither)."""
    mapper = mapping.mapper
    # no gate, or every class merged into one (a corpus too small for more): nothing to score
    if not hasattr(mapper, "gate_classes") or len(set(mapper.group_of_phone_.tolist())) == 1:
        return float("nan"), float("nan"), None, None
    gated = fit_frames(mapping.gate_classes(y, sr), len(true_phone), what=what)
    names = [mapper.class_names_[g] for g in gated]
    visemes = np.array([group_viseme(n) for n in names])
    vis = frame_accuracy(viseme_index(true_phone), visemes)
    phone = (frame_accuracy(mapper.group_of_phone_[true_phone], gated)
             if len(mapper.class_names_) == len(PHONES) else float("nan"))
    return phone, vis, names, visemes


def stream_lookahead_s(mapping) -> float | None:
    """Seconds of audio after frame k that the model's live stream waits for before frame k
    (``mapping.features.algorithmic_latency_s`` of its context); None for a model that cannot
    stream (whole-utterance models, deltas)."""
    mapper = mapping.mapper
    if getattr(mapping, "deltas", False) or not hasattr(mapper, "predict_stacked") or \
            getattr(mapper, "sequence", False) or not hasattr(mapper, "context_"):
        return None
    return algorithmic_latency_s(mapper.context_.forward, mapping.sample_rate, mapping.fps,
                                 getattr(mapping, "window_align", "centre"))


def stream_matches(animator: FaceAnimator, y: np.ndarray, sr: int) -> float:
    """Largest difference (px) between the markers the live stream emits for ``y`` (pushed in
    10 ms chunks at the model's rate) and the offline markers: 0 when offline = live."""
    m = animator.mapping
    y_m = m.at_model_rate(y, sr)
    stream = StreamingAnimator(animator)
    step = max(1, m.sample_rate // 100)
    frames = [f for i in range(0, len(y_m), step) for f in stream.push(y_m[i:i + step])]
    frames += stream.flush()
    live = np.stack([f.markers for f in frames])
    offline = animator.markers(m.predict_audio(y_m, m.sample_rate))
    if live.shape != offline.shape:
        return float("inf")
    return float(np.max(np.abs(live - offline)))


def score_file(animator: FaceAnimator, item, synth: SynthConfig, seed: int, *, seen: bool,
               threshold: float, rate=NATIVE, stream: bool = False) -> FileScores:
    """Every measure of the module docstring, and its chance baseline, on one recording
    (``analysis.speech_set``) given to the model at input ``rate``."""
    m = animator.mapping
    y, sr, note = rate_audio(item, rate)
    fps = m.fps
    n = label_frames(len(y), sr, fps)
    what = f"{item.id} at {rate}"
    mups = m.predict_audio(y, sr)
    opening = fit_frames(mouth_opening(animator.markers(mups)).astype(np.float64), n, what=what)
    true = phone_frames(item.phones, np.arange(n) / fps)
    phone_acc, vis_acc, gated, visemes = gate_tracks(m, y, sr, true, what)
    ref = reference_opening(item.phones, n, fps, synth, seed)
    terms, n_speech = speech_r_terms(opening, ref, true)
    sel = true != PHONES.index("sil")
    return FileScores(
        id=item.id, speaker=item.speaker, seen=seen, seconds=len(y) / sr, part=item.part,
        kind=item.kind, labels="independent" if item.independent else "aligned", input_rate=str(rate),
        rate_note=note, phone_acc=phone_acc, viseme_acc=vis_acc, stream=stream,
        bilabial=segment_contact(opening, fps, item.phones, BILABIALS, threshold),
        labiodental=segment_contact(opening, fps, item.phones, LABIODENTALS, threshold),
        vowel_median_px=vowel_median(opening, true),
        r_reference=correlation(opening[sel], ref[sel]), r_terms=terms, speech_frames=n_speech,
        silence_px=silence_opening(opening, true),
        chance=chance_scores(true, fps, item.phones, visemes=visemes, opening=opening,
                             reference=ref, threshold=threshold),
        n_frames=n, tracks={"opening": opening, "reference": ref, "true": true,
                            "gated": gated, "visemes": visemes, "fps": fps})


def model_jobs(mapping, items, rates=(NATIVE,)) -> list:
    """The recordings :func:`score_model` has ``mapping``'s recogniser front end hear (each
    rate of ``rates`` and recording of ``items``, at the model's rate, as
    :meth:`mapping.checkpoint.AudioMapping.recognised_phones` hears them): jobs of
    :func:`mapping.hearing.hear_all`; none for a model whose gate reads no recogniser."""
    m = mapping.mapper
    if not mapping.needs_phones or getattr(m, "gate_front_end", "") == "labels":
        return []
    return [Windows(mapping.at_model_rate(*rate_audio(it, rate)[:2]), mapping.sample_rate,
                    mapping.fps, m.context_forward, m.context_back,
                    getattr(m, "recogniser", "pocketsphinx"))
            for rate in rates for it in items]


def synth_of(mapping) -> tuple[SynthConfig, int]:
    """The synth settings and seed the mapping's corpus was made with (its file's metadata;
    the defaults when the file does not say)."""
    cfg = mapping.metadata.get("config") or {}
    known = {f.name for f in dataclasses.fields(SynthConfig)}
    synth = {k: tuple(v) if isinstance(v, list) else v
             for k, v in (cfg.get("synth") or {}).items() if k in known}
    return SynthConfig(**synth), int(mapping.metadata.get("seed", cfg.get("seed", 2002)))


@dataclass
class ModelScores:
    """One model on the set: its per-file scores at each input rate, its threshold, and
    whether its streaming output equals its offline output (``stream``: the look-ahead and the
    largest marker difference on one recording)."""

    model: str
    threshold_px: float
    files: list
    stream: dict

    def per_file_rows(self, stream_key: str) -> list:
        return [{"model": self.model, **f.row(stream_key)} for f in self.files]


def score_model(name: str, mapping, units, items, seen=frozenset(), *, rates=(NATIVE,),
                lookahead_s: float = 0.1, check_item=None, progress: bool = True
                ) -> ModelScores:
    """Score ``mapping`` (an AudioMapping) with its Motion Units ``units`` on the recordings
    ``items`` at each input rate of ``rates``; a recording is *seen* when its ``speaker`` is in
    ``seen``. The streaming column (named after the targets' ``lookahead_s``) holds the model's
    live output when it can stream, at its own look-ahead (``stream["lookahead_s"]``: its
    context plus half its analysis window, e.g. 112.5 ms for 3 frames and a 25 ms window;
    the report states it); ``check_item``: the recording on which the live and offline
    markers are compared (a model whose live output differs gets no streaming figure);
    ``progress``: a bar of the recordings scored on stderr (the scores are the same either
    way)."""
    animator = FaceAnimator(mapping, units)
    synth, seed = synth_of(mapping)
    threshold = closed_threshold(animator.neutral)
    la = stream_lookahead_s(mapping)
    streams = la is not None
    check = {"lookahead_s": la, "target_lookahead_s": lookahead_s,
             "max_marker_diff_px": None, "checked_on": None}
    if streams and check_item is not None:
        check["max_marker_diff_px"] = stream_matches(animator, check_item.audio, check_item.sr)
        check["checked_on"] = check_item.id
        streams = check["max_marker_diff_px"] < 1e-3
    check["stream_equals_offline"] = bool(streams)
    jobs = [(rate, it) for rate in rates for it in items]
    files = [score_file(animator, it, synth, seed, seen=it.speaker in seen,
                        threshold=threshold, rate=rate, stream=streams)
             for rate, it in tqdm(jobs, desc=name, unit="recording", file=sys.stderr,
                                  disable=not progress)]
    return ModelScores(name, threshold, files, check)


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
