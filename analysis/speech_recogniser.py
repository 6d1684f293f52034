"""The front ends on real speech: each phone recogniser of ``mapping.recogniser`` read as
visemes frame by frame, whole-utterance and streaming, and its look-ahead curve (issue 29).

pocketsphinx (FIELD_NOTES, "Real speech available offline"): the wheel's en-US acoustic model
with its phone language model, ``allphone`` search, ``lw=2.0``, ``beam=pbeam=1e-20``, no
best-path pass. Whole utterance: the final hypothesis after all the audio. Streaming: the audio
is fed in blocks of one video frame (frame boundaries at ``round(k·sr/fps)`` samples); frame t
is labelled from the partial hypothesis (``Decoder.seg()``) as soon as the audio reaches t +
the look-ahead, and the frames still open at the end from the final hypothesis. A frame no
segment covers yet is silence. Phones are the 39 ARPAbet phones plus ``SIL`` (noise fillers
are silence).

hama (:mod:`mapping.hama_front`): whole utterance, one decode of all the audio; streaming, the
:class:`~mapping.hama_front.HamaStream` the gate uses, one decode of the last second every three
frames. Its decodes do not depend on the look-ahead, so one stream's decodes give every point of
the look-ahead curve (:func:`mapping.hama_front.labels_at_delays`, tested equal to a stream per
look-ahead).

Every figure is pooled (:mod:`analysis.speech_pooling`) over seen / unseen speakers, the unseen
development and test parts, and within the test part separately over recordings whose labels
are independent of both recognisers (``analysis.speech_set``: HTS, TextGrid, GRID word
alignments, FSDD word spans) and those labelled by pocketsphinx's own alignment — which favours
pocketsphinx — with the speakers and recordings behind each row and speaker-level intervals.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from analysis.figures import report_figure
from analysis.speech_eval import rate_audio
from analysis.speech_pooling import SPLITS, summarise
from analysis.speech_scores import (chance_scores, fit_frames, label_frames, phone_frames,
                                    viseme_index)
from face_model.phones import PHONE_INDEX
from groundwork.audio import resample
from groundwork.cache import content_key
from groundwork.errors import ParameterError
from mapping import causal_front, hama_front
from mapping.recogniser import (RECOGNISER_FPS as FRAMES_PER_S,
                                RECOGNISER_RATE as SAMPLE_RATE, audio_digest, heard_entry,
                                new_decoder, phone_index, recogniser_name, recogniser_speakers,
                                split_recogniser, to_pcm16)

LOOKAHEAD_FRAMES = (0, 1, 2, 3, 4, 5, 6)  # the look-ahead curve, video frames (0–200 ms)
LABELS = ("independent", "aligned")  # the test part by where its labels came from
# the recognisers scored by default: pocketsphinx, hama and the shipped causal front end (a run
# scores its own front end's model file instead: "causal:<file>", mapping.recogniser)
RECOGNISERS = ("pocketsphinx", "hama", "causal")


class PhoneRecogniser:
    """pocketsphinx allphone decoding of 16 kHz mono audio into phone indices per video frame
    (a fresh decoder per utterance: its live cepstral mean would carry over)."""

    def __init__(self, fps: int = 30):
        self.fps = int(fps)
        self.decoder = None

    @staticmethod
    def _pcm(y: np.ndarray, sr: int) -> np.ndarray:
        if sr != SAMPLE_RATE:
            raise ParameterError(f"the recogniser needs {SAMPLE_RATE} Hz audio, got {sr} Hz")
        return np.frombuffer(to_pcm16(y), dtype="<i2")

    def _segments(self) -> list:
        segs = self.decoder.seg()
        return [] if segs is None else [(s.start_frame, s.end_frame, phone_index(s.word))
                                        for s in segs]

    def _label(self, segs: list, k: int) -> int:
        f = int(np.floor(k / self.fps * FRAMES_PER_S))
        for start, end, p in segs:
            if start <= f <= end:
                return p
        return PHONE_INDEX["sil"]

    def n_frames(self, n_samples: int) -> int:
        return int(np.ceil(n_samples * self.fps / SAMPLE_RATE))

    def whole(self, y: np.ndarray, sr: int) -> np.ndarray:
        """Phone index per frame (frame k at k / fps s) from the final hypothesis."""
        pcm = self._pcm(y, sr)
        d = self.decoder = new_decoder()
        d.start_utt()
        d.process_raw(pcm.tobytes(), full_utt=True)
        d.end_utt()
        segs = self._segments()
        return np.array([self._label(segs, k) for k in range(self.n_frames(len(pcm)))])

    def streaming(self, y: np.ndarray, sr: int, delay_s: float) -> np.ndarray:
        """Phone index per frame, frame t decided when the audio reaches t + ``delay_s``."""
        if delay_s < 0:
            raise ParameterError(f"delay_s must be >= 0, got {delay_s}")
        return self.streaming_delays(y, sr, (delay_s,))[0]

    def streaming_delays(self, y: np.ndarray, sr: int, delays_s) -> list[np.ndarray]:
        """:meth:`streaming` for every look-ahead of ``delays_s`` from one decoding (the
        partial hypotheses do not depend on the look-ahead)."""
        pcm = self._pcm(y, sr)
        n = self.n_frames(len(pcm))
        outs = [np.full(n, -1) for _ in delays_s]
        done = [0] * len(delays_s)
        d = self.decoder = new_decoder()
        d.start_utt()
        for b in range(n):
            lo, hi = round(b * SAMPLE_RATE / self.fps), round((b + 1) * SAMPLE_RATE / self.fps)
            if len(pcm[lo:hi]):  # the last frame's block may hold no sample
                d.process_raw(pcm[lo:hi].tobytes(), full_utt=False)
            reached = min(hi, len(pcm)) / SAMPLE_RATE
            segs = None
            for i, delay in enumerate(delays_s):
                while done[i] < n and done[i] / self.fps + delay <= reached + 1e-9:
                    segs = self._segments() if segs is None else segs
                    outs[i][done[i]] = self._label(segs, done[i])
                    done[i] += 1
        d.end_utt()
        segs = self._segments()
        for i, out in enumerate(outs):
            for k in range(done[i], n):
                out[k] = self._label(segs, k)
        return outs


def recognised(recogniser: str, y: np.ndarray, sr: int, fps: int = 30) -> tuple:
    """``(whole-utterance phones, {look-ahead frames: streaming phones})`` of one recording by
    ``recogniser`` (pocketsphinx | hama | causal[:<model file>]), per video frame; audio at
    another rate than 16 kHz is resampled to it first (as each front end does live). The causal
    front end has no whole-utterance reading of its own: its "whole" is its stream at its
    largest look-ahead. Read from (and written to) the cache of
    :func:`mapping.recogniser.hearing_cache` when one is set (:func:`recognised_key`)."""
    split_recogniser(recogniser)  # an unknown one is refused in one line
    job = Recognised(recogniser, np.asarray(y, np.float32), int(sr), int(fps))
    arrays = heard_entry(job.key(), job.compute, job.names)
    return arrays["whole"], {k: arrays[f"stream_{k}"] for k in LOOKAHEAD_FRAMES}


def _recognised_now(recogniser: str, y: np.ndarray, sr: int, fps: int) -> tuple:
    if sr != SAMPLE_RATE:
        y, sr = resample(np.asarray(y, np.float32), sr_in=int(sr), sr_out=SAMPLE_RATE), \
            SAMPLE_RATE
    kind, model = split_recogniser(recogniser)
    if kind == "pocketsphinx":
        rec = PhoneRecogniser(fps)
        streams = rec.streaming_delays(y, sr, [k / fps for k in LOOKAHEAD_FRAMES])
        return rec.whole(y, sr), dict(zip(LOOKAHEAD_FRAMES, streams))
    if kind == "causal":
        streams = causal_front.labels_at_delays(y, sr, fps, LOOKAHEAD_FRAMES, model=model)
        return streams[LOOKAHEAD_FRAMES[-1]], streams
    n = int(np.ceil(len(y) * fps / sr))
    return (hama_front.whole_utterance(y, n, fps),
            hama_front.labels_at_delays(y, sr, fps, LOOKAHEAD_FRAMES))


# bump when what :func:`recognised` gives for the same audio changes (its entries are then
# heard again)
RECOGNISED_VERSION = 1


@dataclass(frozen=True, eq=False)
class Recognised:
    """One recording for :func:`recognised` (a job of :func:`mapping.hearing.hear_all`): mono
    float32 ``y`` at ``sr`` Hz, heard by ``recogniser`` at ``fps``."""

    recogniser: str
    y: np.ndarray = field(repr=False)
    sr: int
    fps: int = 30
    names = ("whole", *(f"stream_{k}" for k in LOOKAHEAD_FRAMES))

    @property
    def seconds(self) -> float:
        return len(self.y) / self.sr

    def key(self) -> str:
        """The SHA-256 of the audio (:func:`mapping.recogniser.audio_digest`), the
        recogniser's name and version, ``fps``, the look-aheads and
        :data:`RECOGNISED_VERSION`."""
        return content_key("recognised", RECOGNISED_VERSION, recogniser_name(self.recogniser),
                           audio_digest(self.y, self.sr),
                           {"fps": self.fps, "lookahead_frames": list(LOOKAHEAD_FRAMES)})

    def compute(self) -> dict:
        whole, streams = _recognised_now(self.recogniser, self.y, self.sr, self.fps)
        return {"whole": np.asarray(whole),
                **{f"stream_{k}": np.asarray(streams[k]) for k in LOOKAHEAD_FRAMES}}


def recogniser_jobs(items, *, recognisers=RECOGNISERS, rates=("native",),
                    fps: int = 30) -> list[Recognised]:
    """The :class:`Recognised` jobs :func:`recogniser_scores` hears (each recogniser, rate
    and recording), for :func:`mapping.hearing.hear_all`."""
    out = []
    for recogniser in recognisers:
        for rate in rates:
            for it in items:
                y, sr, _ = rate_audio(it, rate)
                out.append(Recognised(recogniser, np.asarray(y, np.float32), int(sr), int(fps)))
    return out


def recogniser_scores(items, seen=frozenset(), *, delay_s: float = 0.1, fps: int = 30,
                      recognisers=RECOGNISERS, rates=("native",), summary: bool = True,
                      progress: bool = True) -> tuple[list, list, list]:
    """``(per-file rows, pooled rows, look-ahead rows)`` of each recogniser on the recordings
    ``items`` (``analysis.speech_set``) at each input rate of ``rates``
    (:func:`analysis.speech_eval.rate_audio`): phone and viseme frame accuracy of the whole
    utterance, viseme accuracy streaming with ``delay_s`` of look-ahead, and viseme accuracy
    streaming at every look-ahead of :data:`LOOKAHEAD_FRAMES` (native rate only). A recording
    is *seen* when its ``speaker`` is in ``seen``. Phone accuracy counts the 44 classes;
    ``ax dx el en`` labels are never recognised by pocketsphinx (only the 39 ARPAbet phones),
    so it is a lower bound there (``summary=False``: no pooled rows, for a caller that pools
    every system together). Each per-file row carries its numerators (``*_hits``) and the
    chance baseline of its whole-utterance visemes (:func:`analysis.speech_scores.chance_scores`)
    for :mod:`analysis.speech_pooling`. ``progress``: a bar of the recordings heard (each
    recogniser at each rate) on stderr; the rows are the same either way."""
    key = f"viseme_acc_stream_{round(1000 * delay_s)}ms"
    delay_frames = round(delay_s * fps)
    if delay_frames not in LOOKAHEAD_FRAMES or abs(delay_frames / fps - delay_s) > 1e-9:
        raise ParameterError(f"delay_s {delay_s} is not one of the look-aheads "
                             f"{[round(k / fps, 3) for k in LOOKAHEAD_FRAMES]} s")
    files, curve_hits = [], {}
    for recogniser in recognisers:
        split_recogniser(recogniser)  # an unknown one is refused before any work
    with tqdm(total=len(recognisers) * len(rates) * len(items), desc="recognisers",
              unit="recording", file=sys.stderr, disable=not progress) as bar:
        for recogniser in recognisers:
            name = recogniser_name(recogniser)
            own = seen | recogniser_speakers(recogniser)  # its own training speakers too
            bar.set_postfix_str(recogniser, refresh=False)
            for rate in rates:
                for it in items:
                    y, sr, note = rate_audio(it, rate)
                    n = label_frames(len(y), sr, fps)
                    whole, streams = recognised(recogniser, y, sr, fps)
                    what = f"{name} on {it.id} at {rate}"
                    whole = fit_frames(whole, n, what=what)
                    streams = {k: fit_frames(s, n, what=what) for k, s in streams.items()}
                    true = phone_frames(it.phones, np.arange(n) / fps)
                    vtrue = viseme_index(true)
                    vis = viseme_index(whole)
                    hits = {"phone": true == whole, "viseme": vtrue == vis,
                            **{k: vtrue == viseme_index(s) for k, s in streams.items()}}
                    chance = chance_scores(true, fps, it.phones, visemes=vis)
                    row = {"model": name, "id": it.id, "speaker": it.speaker,
                           "split": "seen" if it.speaker in own else "unseen", "part": it.part,
                           "kind": it.kind, "labels": LABELS[0] if it.independent else LABELS[1],
                           "input_rate": str(rate), "rate_note": note,
                           "seconds": round(len(y) / sr, 3), "frames": n,
                           "phone_acc": float(hits["phone"].mean()),
                           "phone_hits": int(hits["phone"].sum()),
                           "viseme_acc": float(hits["viseme"].mean()),
                           "viseme_hits": int(hits["viseme"].sum()),
                           key: float(hits[delay_frames].mean()),
                           "viseme_stream_hits": int(hits[delay_frames].sum()),
                           "chance_viseme_hits": chance.viseme_hits / chance.n_shifts}
                    files.append(row)
                    if str(rate) == "native":
                        curve_hits.setdefault(name, []).append((row, hits))
                    bar.update()
    curve = []
    for name, pairs in curve_hits.items():
        for split, keep in SPLITS.items():
            sel = [h for r, h in pairs if keep(r)]
            if not sel:
                continue
            for k in LOOKAHEAD_FRAMES:
                curve.append({"model": name, "split": split, "lookahead_frames": k,
                              "lookahead_ms": round(1000 * k / fps, 1),
                              "viseme_acc": float(np.mean(np.concatenate(
                                  [h[k] for h in sel])))})
    return files, (summarise(files, key) if summary else []), curve


def lookahead_figure(curve: list[dict], path, *, width: float = 0.8) -> Path:
    """Streaming viseme accuracy against look-ahead (0–200 ms) of each recogniser on the unseen
    test speakers: solid on the recordings with independent labels, dashed on those labelled
    by pocketsphinx's alignment (``curve``: :func:`recogniser_scores`' look-ahead rows)."""
    with report_figure(path, width=width, height_in=2.6) as fig:
        ax = fig.subplots()
        for i, name in enumerate(dict.fromkeys(r["model"] for r in curve)):
            for lab, style in zip(LABELS, ("-", "--")):
                pts = [(r["lookahead_ms"], r["viseme_acc"]) for r in curve
                       if r["model"] == name and r["split"] == f"unseen-test-{lab}"]
                if pts:
                    x, y = zip(*pts)
                    ax.plot(x, y, style, marker="o", ms=3, color=f"C{i}",
                            label=f"{name.split()[0]}, {lab} labels")
        ax.axvline(100, color="0.6", lw=0.8)
        ax.set_xlabel("look-ahead (ms)")
        ax.set_ylabel("viseme accuracy, streaming")
        ax.grid(alpha=0.3)
        ax.legend()
    return Path(path)
