"""A stream of :mod:`mapping.recogniser` fed as a caller may cut its chunks (the recognisers' tests)."""
from __future__ import annotations

import numpy as np


def feed(stream, y, sizes):
    """Push ``y`` to ``stream`` in chunks of ``sizes`` (cycled until the audio is used up), then
    flush; the windows returned, in order."""
    out, i, j = [], 0, 0
    while i < len(y):
        n = int(sizes[j % len(sizes)])
        out += stream.push_windows(y[i:i + n])
        i, j = i + n, j + 1
    out += stream.flush_windows()
    return np.asarray(out, np.int64).reshape(-1, stream.back + 1 + stream.delay)
