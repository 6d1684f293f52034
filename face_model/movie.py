"""Rendered faces to an MP4 file: the one video writer of the project.

H.264 (``libx264``, ``yuv420p``) through ``imageio_ffmpeg``, frame k at k/``fps`` s, with an
optional audio track muxed as AAC. Used by ``talkingface animate`` (a face with its speech) and
by the perception study's stimuli (silent videos, :mod:`study.stimuli`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from face_model.atomic import atomic_file


def write_mp4(path, frames_iter, n_frames: int | None, size, *, fps: int, audio_path,
              progress: bool = True, quality: int = 7, macro_block_size: int = 16) -> Path:
    """Write RGB frames to an H.264 MP4, with the audio of ``audio_path`` muxed as AAC.

    Parameters
    ----------
    path : path
        The MP4 file (its folder is created).
    frames_iter : iterable of ndarray (h, w, 3) uint8
        RGB frames, consumed once (a generator is fine).
    n_frames : int or None
        The number of frames, for the progress bar only.
    size : (width, height)
        Frame size in pixels.
    fps : int
        Frame rate (Hz).
    audio_path : path or None
        A sound file to mux as AAC; None writes a silent video (no audio stream).
    progress : bool
        Show a progress bar.
    quality : int
        ``imageio_ffmpeg`` quality, 0 (worst) to 10 (best).
    macro_block_size : int
        Frame sizes are padded to a multiple of this (``imageio_ffmpeg``; 1 disables it).

    Returns
    -------
    Path
        ``path``.
    """
    import imageio_ffmpeg  # ffmpeg: an optional, heavy dependency, imported when used

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    audio = {} if audio_path is None else {"audio_path": str(audio_path), "audio_codec": "aac"}
    with atomic_file(path) as tmp:  # a killed render never leaves a short MP4 under the name
        writer = imageio_ffmpeg.write_frames(str(tmp), size, fps=fps, codec="libx264",
                                             pix_fmt_in="rgb24", pix_fmt_out="yuv420p",
                                             quality=quality, macro_block_size=macro_block_size,
                                             **audio)
        writer.send(None)
        try:
            for frame in tqdm(frames_iter, total=n_frames, desc="render", unit="frame",
                              disable=not progress):
                writer.send(np.ascontiguousarray(frame))
        finally:
            writer.close()
    return path
