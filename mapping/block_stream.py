"""What every phone stream of :mod:`mapping.recogniser` shares (pocketsphinx's
:class:`~mapping.recogniser.PhoneStream`, hama's :class:`~mapping.hama_front.HamaStream`, our
:class:`~mapping.causal_front.CausalStream`): audio pushed in chunks of any length is cut into
blocks of one video frame (block k starts at sample round(k · sample_rate / fps)), each stream
hears the blocks in order and decides frames; ``push``/``flush`` give the phones of the frames
newly decided, ``push_windows``/``flush_windows`` their windows of phones (frames k − back …
k + delay_frames), and ``windows``/``labels`` every decision so far. Because the blocks never
depend on how the caller cut its chunks, neither do the decisions.
"""
from __future__ import annotations

import numpy as np

from groundwork.errors import ParameterError


def check_stream_args(sample_rate, fps, delay_frames, back) -> None:
    """Refuse a stream's rate, fps (positive integers), look-ahead and past frames (integers
    ≥ 0) in one line."""
    if isinstance(sample_rate, bool) or not isinstance(sample_rate, (int, np.integer)) \
            or sample_rate <= 0 or isinstance(fps, bool) \
            or not isinstance(fps, (int, np.integer)) or fps <= 0:
        raise ParameterError(f"sample rate and fps must be positive integers, got "
                             f"{sample_rate!r} Hz and {fps!r} fps")
    for name, v in (("delay_frames", delay_frames), ("back", back)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ParameterError(f"{name} must be an integer ≥ 0, got {v!r}")


class BlockStream:
    """The shared part of a phone stream (see the module docstring); a subclass calls
    :meth:`_start` and defines ``push_windows`` and ``flush_windows``."""

    sample_rate: int
    fps: int
    delay: int
    back: int

    def _start(self, sample_rate: int, fps: int, delay_frames: int, back: int) -> None:
        self.sample_rate, self.fps = int(sample_rate), int(fps)
        self.delay, self.back = int(delay_frames), int(back)
        self._pending = np.zeros(0, np.float32)  # samples of the block not yet complete
        self._blocks = 0  # whole blocks heard
        self._n_samples = 0
        self._windows: list[list[int]] = []  # per decided frame: phones of k - back .. k + delay
        self._done = False

    def _boundary(self, k: int) -> int:
        """The sample at which block k starts: round(k · sample_rate / fps)."""
        return (2 * k * self.sample_rate + self.fps) // (2 * self.fps)

    def _blocks_of(self, chunk: np.ndarray) -> list[np.ndarray]:
        """The whole blocks ``chunk`` completes (after the samples pending), in order; the rest
        waits for the next chunk. Refuses a chunk after the end, or one that is not mono and
        finite."""
        if self._done:
            raise ParameterError("the phone stream has ended; start a new one")
        chunk = np.asarray(chunk, dtype=np.float32)
        if chunk.ndim != 1 or not np.all(np.isfinite(chunk)):
            raise ParameterError("the audio chunk must be mono and finite")
        self._n_samples += len(chunk)
        audio = np.concatenate([self._pending, chunk])
        blocks, used, k = [], 0, self._blocks
        while True:
            size = self._boundary(k + 1) - self._boundary(k)
            if len(audio) - used < size:
                break
            blocks.append(audio[used:used + size])
            used, k = used + size, k + 1
        self._pending = audio[used:]
        return blocks

    def _end(self) -> np.ndarray | None:
        """Mark the end of the audio; the samples still pending (None: ended already)."""
        if self._done:
            return None
        self._done = True
        return self._pending

    @property
    def n_total(self) -> int:
        """The frames of the audio pushed so far: ceil(n_samples · fps / sample_rate)."""
        return -(-self._n_samples * self.fps // self.sample_rate)

    def push(self, chunk: np.ndarray) -> list[int]:
        """Add mono samples (any length); return the phones of the frames newly decided (their
        windows: ``push_windows``)."""
        return [w[self.back] for w in self.push_windows(chunk)]

    def flush(self) -> list[int]:
        """End of the audio: the phones of the remaining frames (:attr:`n_total` in all;
        their windows: ``flush_windows``)."""
        return [w[self.back] for w in self.flush_windows()]

    @property
    def windows(self) -> np.ndarray:
        """Every window decided so far (n_decided, back + 1 + delay_frames), frame 0 first."""
        return np.asarray(self._windows, dtype=np.int64).reshape(-1, self.back + 1 + self.delay)

    @property
    def labels(self) -> np.ndarray:
        """Every phone decided so far, frame 0 first."""
        return self.windows[:, self.back]
