"""The reference bar on real speech: pocketsphinx's phone recogniser (trained on real speech)
read as visemes frame by frame, whole-utterance and streaming.

Settings (FIELD_NOTES, "Real speech available offline"): the wheel's en-US acoustic model with
its phone language model, ``allphone`` search, ``lw=2.0``, ``beam=pbeam=1e-20``, no best-path
pass. Whole utterance: the final hypothesis after all the audio. Streaming: the audio is fed in
blocks of one video frame (frame boundaries at ``round(k·sr/fps)`` samples); frame t is labelled
from the partial hypothesis (``Decoder.seg()``) as soon as the audio reaches t + ``delay_s``, and
the frames still open at the end from the final hypothesis. A frame no segment covers yet is
silence. Phones are the 39 ARPAbet phones plus ``SIL`` (noise fillers are silence).
"""
from __future__ import annotations

import numpy as np

from analysis.speech_eval import phone_frames, viseme_index
from analysis.speech_set import PARTS
from face_model.phones import PHONE_INDEX
from groundwork.errors import ParameterError
from mapping.recogniser import (RECOGNISER_FPS as FRAMES_PER_S, RECOGNISER_NAME,
                                RECOGNISER_RATE as SAMPLE_RATE, new_decoder, phone_index, to_pcm16)


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
        pcm = self._pcm(y, sr)
        n = self.n_frames(len(pcm))
        out = np.full(n, -1)
        d = self.decoder = new_decoder()
        d.start_utt()
        done = 0
        for b in range(n):
            lo, hi = round(b * SAMPLE_RATE / self.fps), round((b + 1) * SAMPLE_RATE / self.fps)
            d.process_raw(pcm[lo:hi].tobytes(), full_utt=False)
            reached = min(hi, len(pcm)) / SAMPLE_RATE
            segs = None
            while done < n and done / self.fps + delay_s <= reached + 1e-9:
                segs = self._segments() if segs is None else segs
                out[done] = self._label(segs, done)
                done += 1
        d.end_utt()
        segs = self._segments()
        for k in range(done, n):
            out[k] = self._label(segs, k)
        return out


def recogniser_scores(items, seen_sources=frozenset(), *, delay_s: float = 0.1,
                      fps: int = 30) -> tuple[list, list]:
    """``(per-file rows, rows pooled over seen / unseen / all files)`` of the recogniser on the
    recordings ``items`` (``analysis.speech_set``): phone and viseme frame accuracy of the whole
    utterance, and viseme frame accuracy streaming with ``delay_s`` of look-ahead. Phone
    accuracy counts the 44 classes; ``ax dx el en`` labels are never recognised (pocketsphinx
    has only the 39 ARPAbet phones), so it is a lower bound."""
    rec = PhoneRecogniser(fps)
    files, pooled = [], {"seen": [], "unseen": [], **{f"unseen-{p}": [] for p in PARTS}}
    for it in items:
        whole = rec.whole(it.audio, it.sr)
        stream = rec.streaming(it.audio, it.sr, delay_s)
        true = phone_frames(it.phones, np.arange(len(whole)) / fps)
        hits = {"phone": true == whole, "viseme": viseme_index(true) == viseme_index(whole),
                "stream": viseme_index(true) == viseme_index(stream)}
        split = "seen" if it.speaker_source in seen_sources else "unseen"
        pooled[split].append(hits)
        if split == "unseen":
            pooled[f"unseen-{it.part}"].append(hits)
        files.append({"model": RECOGNISER_NAME, "id": it.id,
                      "speaker_source": it.speaker_source, "split": split, "part": it.part,
                      "seconds": round(it.duration_s, 3), "frames": len(true),
                      "phone_acc": float(hits["phone"].mean()),
                      "viseme_acc": float(hits["viseme"].mean()),
                      f"viseme_acc_stream_{round(1000 * delay_s)}ms":
                          float(hits["stream"].mean())})
    pooled["all"] = pooled["seen"] + pooled["unseen"]
    summary = []
    for split in ("seen", "unseen", "all", *[f"unseen-{p}" for p in PARTS]):
        hits = pooled[split]
        row = {"model": RECOGNISER_NAME, "split": split, "files": len(hits)}
        if hits:
            for key, name in (("phone", "phone_acc"), ("viseme", "viseme_acc"),
                              ("stream", f"viseme_acc_stream_{round(1000 * delay_s)}ms")):
                row[name] = float(np.mean(np.concatenate([h[key] for h in hits])))
        summary.append(row)
    return files, summary
