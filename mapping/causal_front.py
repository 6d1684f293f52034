"""A small causal phone front end of our own, taught by hama (issue 40): the inference side.

The net reads 16 kHz audio as log-mel energies and gives, every 10 ms (a *step*), the phone
class (one of the 44 of :data:`face_model.phones.PHONES`) of recent instants, one *head* per
look-ahead; it is trained by :mod:`mapping.front_training` on hama's whole-utterance phones
(:mod:`mapping.hama_front`) and runs here in numpy alone, one step at a time.

The network, its features and its model file are :mod:`mapping.front_net`'s; the audio at any
rate goes to 16 kHz through one ``soxr.ResampleStream`` of quality "QQ" (no filter delay),
fed block by block.

Streaming (:class:`CausalStream`, the interface of :class:`mapping.recogniser.PhoneStream` and
:class:`mapping.hama_front.HamaStream`). The audio is cut into blocks of one video frame (block
k starts at sample round(k · sample_rate / fps)); after each block every step whose window has
been heard is computed. Frame k (instant k / fps) sits at step s_k = ⌊100 · k / fps⌋ (the
instant rounded down to the 10-ms grid) and is decided once k + ``delay_frames`` blocks are fed
(with no look-ahead, once block k is: audio follows its instant), by head
l = min(⌊100 · delay_frames / fps⌋, L) at step s_k + l — or by the largest head h ≤ l whose step
s_k + h has been computed, should the resampler not yet have given the last samples of step
s_k + l. Its window of frames k − back … k + delay_frames: past frames keep the phone they were
decided with, frames < 0 are silence, and a future frame j reads what is known now, the largest
head h ≤ l with step s_j + h computed (silence when step s_j itself is not). At the end of the
audio (flush) the resampler is drained, every step whose window ends inside the audio is
computed, and each remaining frame reads the largest head h ≤ l the audio allows (a frame whose
instant lies after the last step reads head 0 of the last step). Every decision reads only the
blocks fed, and the steps are computed block by block whatever the chunks, so offline
(:func:`mapping.recogniser.recognise_windows`) and live give the same windows bit for bit, and
frame k depends on no audio after block k + ``delay_frames`` − 1 (block k with no look-ahead).

:func:`labels_at_delays` gives the phones of every look-ahead from one pass (the heads of one
run); a look-ahead longer than L frames' worth reads head L.
"""
from __future__ import annotations

import numpy as np
import soxr

from groundwork.errors import ParameterError
from mapping.block_stream import BlockStream, check_stream_args
from mapping.front_net import (HOP, MARGIN, N_CLASSES, RATE, RESAMPLE_QUALITY, SILENCE,
                               STEPS_PER_S, WIN, Front, frames_log_mel, load)


# -- streaming -------------------------------------------------------------------------------------

class _Steps:
    """Audio (at ``sample_rate``) in blocks → 16 kHz → steps → each step's best class per
    head; ``keep`` keeps every step (else those no frame reads again are dropped) and its
    scores (``logits``)."""

    def __init__(self, front: Front, sample_rate: int, keep: bool = False):
        self.front = front
        self._resampler = (None if sample_rate == RATE else
                           soxr.ResampleStream(sample_rate, RATE, 1, dtype="float32",
                                               quality=RESAMPLE_QUALITY))
        self._buf = np.zeros(WIN + MARGIN, np.float32)  # 16 kHz audio from sample _b0 on
        self._b0 = -(WIN + MARGIN)
        self._fed = 0  # 16 kHz samples heard
        self.done = 0  # steps computed (0 … done − 1)
        self._s0 = 0  # the first step kept in _best
        self._best = np.zeros((0, front.heads), np.int64)
        self._state = front.new_state()
        self.keep = keep
        self.logits: list = []

    def feed(self, block: np.ndarray, last: bool = False) -> None:
        x = (block if self._resampler is None
             else self._resampler.resample_chunk(block, last=last))
        if len(x):
            self._buf = np.concatenate([self._buf, np.asarray(x, np.float32)])
            self._fed += len(x)
        top = (self._fed + MARGIN) // HOP  # the last step whose window has been heard
        if top < self.done:
            return
        starts = HOP * np.arange(self.done, top + 1) - MARGIN - WIN - self._b0
        frames = self._buf[starts[:, None] + np.arange(WIN)]
        logits = self.front.forward(self.front.normalise(
            frames_log_mel(frames, self.front.arrays["mel_filters"])), self._state)
        self._best = np.concatenate([self._best, logits.argmax(axis=2)])
        if self.keep:
            self.logits.append(logits)
        self.done = top + 1
        cut = HOP * self.done - MARGIN - WIN - self._b0  # the next step's first sample
        self._buf, self._b0 = self._buf[cut:], self._b0 + cut

    def forget(self, before: int) -> None:
        """Drop the best classes of steps before ``before`` (never read again)."""
        drop = min(max(0, before - self._s0), len(self._best))
        if drop > 256 and not self.keep:
            self._best, self._s0 = self._best[drop:], self._s0 + drop

    def best(self, step: int, head: int) -> int:
        return int(self._best[step - self._s0, head])


def _frame_step(j: int, fps: int) -> int:
    """The step of frame j's instant j / fps, rounded down to the 10-ms grid."""
    return (j * STEPS_PER_S) // fps


def _label(steps: _Steps, j: int, fps: int, head: int, at_end: bool,
           done: int | None = None) -> int:
    """Frame j's phone from the first ``done`` steps (None: those computed): the largest head
    h ≤ ``head`` whose step s_j + h is among them; silence when s_j is not (at the end: head
    0 of the last step)."""
    s = _frame_step(j, fps)
    last = (steps.done if done is None else done) - 1
    if last < s:
        return steps.best(last, 0) if at_end and last >= 0 else SILENCE
    h = min(head, last - s)
    return steps.best(s + h, h)


def _head(front: Front, delay_frames: int, fps: int) -> int:
    """The head a look-ahead of ``delay_frames`` video frames reads: ⌊100 · delay / fps⌋
    steps, at most the longest head."""
    return min((int(delay_frames) * STEPS_PER_S) // int(fps), front.heads - 1)


class CausalStream(BlockStream):
    """Recognised phones per video frame of one audio stream (see the module docstring); the
    interface of :class:`mapping.recogniser.PhoneStream`.

    Parameters
    ----------
    sample_rate : int
        The rate of the audio pushed (Hz); block k ends at sample round((k + 1) · rate / fps).
    fps : int
        Video frames per second.
    delay_frames : int
        Frames of look-ahead before a frame's phone is decided (≥ 0).
    back : int
        Past frames in each decision's window (≥ 0).
    model : str, Path, Front or None
        The model file (None: :data:`SHIPPED`) or a loaded :class:`Front`.
    """

    def __init__(self, sample_rate: int, fps: int = 30, delay_frames: int = 3, back: int = 0,
                 model=None):
        check_stream_args(sample_rate, fps, delay_frames, back)
        self.front = load(model)
        self._start(sample_rate, fps, delay_frames, back)
        self.head = _head(self.front, self.delay, self.fps)
        self._steps = _Steps(self.front, self.sample_rate)

    def _decide_due(self, until: int, at_end: bool = False) -> list[list[int]]:
        out = []
        while len(self._windows) < until:
            k = len(self._windows)
            window = [SILENCE if j < 0 else self._windows[j][self.back] if j < k else
                      _label(self._steps, j, self.fps, self.head, at_end)
                      for j in range(k - self.back, k + self.delay + 1)]
            self._windows.append(window)
            out.append(window)
        self._steps.forget(_frame_step(len(self._windows), self.fps))
        return out

    def push_windows(self, chunk: np.ndarray) -> list[list[int]]:
        """Add mono samples (any length); return the windows of the frames newly decided."""
        out = []
        for block in self._blocks_of(chunk):
            self._steps.feed(block)
            self._blocks += 1
            out += self._decide_due(min(self._blocks - self.delay + 1, self._blocks))
        return out

    def flush_windows(self) -> list[list[int]]:
        """End of the audio: the windows of the remaining frames, each from the largest head
        the audio allows."""
        rest = self._end()
        if rest is None:
            return []
        self._steps.feed(rest, last=True)
        return self._decide_due(self.n_total, True)


def _run(front: Front, y: np.ndarray, sample_rate: int, fps: int) -> tuple:
    """``(steps, steps computed after each number of whole blocks, whole blocks)``: audio
    ``y`` fed as a stream feeds it, block by block, then drained; every step kept."""
    check_stream_args(sample_rate, fps, 0, 0)
    y = np.asarray(y, np.float32)
    if y.ndim != 1 or not np.all(np.isfinite(y)):
        raise ParameterError("the audio must be mono and finite")
    sr, fps = int(sample_rate), int(fps)
    steps = _Steps(front, sr, keep=True)
    done_after, k = [0], 0
    while (2 * (k + 1) * sr + fps) // (2 * fps) <= len(y):
        steps.feed(y[(2 * k * sr + fps) // (2 * fps):(2 * (k + 1) * sr + fps) // (2 * fps)])
        done_after.append(steps.done)
        k += 1
    steps.feed(y[(2 * k * sr + fps) // (2 * fps):], last=True)
    return steps, done_after, k


def labels_at_delays(y: np.ndarray, sample_rate: int, fps: int, delays, *,
                     model=None) -> dict:
    """``{look-ahead frames: phone per video frame}``: for each look-ahead d of ``delays`` the
    phones a :class:`CausalStream` with ``delay_frames`` d decides on mono audio ``y``, from
    one pass (the steps do not depend on the look-ahead; the heads do). A look-ahead beyond
    the longest head's reads the longest head."""
    front = load(model)
    steps, done_after, n_blocks = _run(front, y, sample_rate, fps)
    n = -(-len(y) * int(fps) // int(sample_rate))
    out = {}
    for d in delays:
        head, labels = _head(front, d, fps), np.empty(n, np.int64)
        for k in range(n):
            b = k + max(int(d), 1)  # frame k is decided after b blocks (or at the end)
            labels[k] = (_label(steps, k, fps, head, False, done_after[b]) if b <= n_blocks
                         else _label(steps, k, fps, head, True))
        out[int(d)] = labels
    return out


def posteriors(y: np.ndarray, sample_rate: int, fps: int = 30, *, model=None) -> np.ndarray:
    """Every step's class probabilities per head (n_steps, heads, 44) float32 of mono audio
    ``y``, as a stream at ``fps`` computes them (softmax of the scores)."""
    front = load(model)
    steps = _run(front, y, sample_rate, fps)[0]
    logits = (np.concatenate(steps.logits) if steps.logits
              else np.zeros((0, front.heads, N_CLASSES), np.float32))
    e = np.exp(logits - logits.max(axis=2, keepdims=True))
    return e / e.sum(axis=2, keepdims=True)
