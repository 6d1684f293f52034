"""Rendered faces to an MP4 file: the one video writer of the project.

H.264 (``libx264``, ``yuv420p``) through the ``ffmpeg`` that ``imageio_ffmpeg`` ships, frame k at
k/``fps`` s, with an optional audio track muxed as AAC. Used by ``talkingface animate`` (a face
with its speech) and by the perception study's stimuli (silent videos, :mod:`study.stimuli`).

The file is written under a temporary name and renamed into place only when ffmpeg has exited
with status 0 and what it wrote is a whole MP4 (:func:`check_mp4`): a full disk, a killed
encoder or a broken pipe leave the previous file untouched and raise :class:`VideoError`, one
line with ffmpeg's own last words ("No space left on device").
"""
from __future__ import annotations

import os
import subprocess
import tempfile
from fractions import Fraction
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from groundwork.atomic import atomic_file
from groundwork.errors import TalkingFaceError

FFMPEG_EXIT_TIMEOUT_S = 600  # ffmpeg's wait for the last frames to be encoded and muxed


class VideoError(TalkingFaceError):
    """ffmpeg could not write a video (its exit status, or a file that is not a whole MP4)."""


def ffmpeg_command(path, size, *, fps: int, audio_path, quality: int,
                   macro_block_size: int) -> list[str]:
    """ffmpeg's arguments: raw RGB frames on stdin, H.264 (and AAC) into ``path`` — the command
    ``imageio_ffmpeg.write_frames`` builds for the same settings.

    Parameters
    ----------
    path : path-like
        The output file.
    size : (width, height)
        Frame size in pixels.
    fps, audio_path, quality, macro_block_size
        As for :func:`write_mp4`.

    Returns
    -------
    list of str
        The command line, starting with ``imageio_ffmpeg``'s ffmpeg executable.
    """
    import imageio_ffmpeg  # ffmpeg: an optional, heavy dependency, imported when used

    w, h = int(size[0]), int(size[1])
    cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-f", "rawvideo", "-vcodec", "rawvideo",
           "-s", f"{w}x{h}", "-pix_fmt", "rgb24", "-r", str(Fraction(fps).limit_denominator()),
           "-i", "-"]
    cmd += ["-an"] if audio_path is None else ["-i", str(audio_path)]
    cmd += ["-vcodec", "libx264", "-pix_fmt", "yuv420p",
            "-crf", str(int((1 - quality / 10.0) * 51))]
    if macro_block_size > 1 and (w % macro_block_size or h % macro_block_size):
        pad = lambda n: n + (-n) % macro_block_size  # noqa: E731
        cmd += ["-vf", f"scale={pad(w)}:{pad(h)}"]
    cmd += ["-v", "error"]
    if audio_path is not None:
        cmd += ["-acodec", "aac", "-map", "0:v:0", "-map", "1:a:0"]
    return [*cmd, str(path)]


def check_mp4(path) -> None:
    """Refuse a file that is not a whole MP4: its top-level boxes must span the file exactly
    and hold a ``moov`` (the index ffmpeg writes last) and an ``mdat``.

    Raises
    ------
    VideoError
        Naming the file and its size.
    """
    path = Path(path)
    size = path.stat().st_size
    kinds, pos = set(), 0
    with open(path, "rb") as f:
        while pos < size:
            f.seek(pos)
            head = f.read(16)
            if len(head) < 8:
                break
            n, kind = int.from_bytes(head[:4], "big"), head[4:8]
            if n == 1 and len(head) == 16:
                n = int.from_bytes(head[8:16], "big")
            elif n == 0:
                n = size - pos
            if n < 8:
                break
            kinds.add(kind)
            pos += n
    if pos != size or not {b"moov", b"mdat"} <= kinds:
        raise VideoError(f"{path}: ffmpeg left an incomplete MP4 ({size} bytes)")


def write_mp4(path, frames_iter, n_frames: int | None, size, *, fps: int, audio_path,
              progress: bool = True, quality: int = 7, macro_block_size: int = 16) -> Path:
    """Write RGB frames to an H.264 MP4, with the audio of ``audio_path`` muxed as AAC.

    Parameters
    ----------
    path : path
        The MP4 file (its folder is created). It is replaced only by a whole video.
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
        Quality, 1 (worst) to 10 (best): the constant rate factor 51 · (1 − quality / 10).
    macro_block_size : int
        Frame sizes are scaled up to a multiple of this (1 disables it).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    VideoError
        ffmpeg exited with an error (its last line of stderr is in the message) or left an
        incomplete file; ``path`` is then as it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path) as tmp, tempfile.TemporaryFile() as log:
        cmd = ffmpeg_command(tmp, size, fps=fps, audio_path=audio_path, quality=quality,
                             macro_block_size=macro_block_size)
        proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                stderr=log)
        broken = False
        try:
            for frame in tqdm(frames_iter, total=n_frames, desc="render", unit="frame",
                              disable=not progress):
                try:
                    proc.stdin.write(np.ascontiguousarray(frame, dtype=np.uint8).tobytes())
                except BrokenPipeError:  # ffmpeg has stopped: its status and words say why
                    broken = True
                    break
            try:
                proc.stdin.close()
            except BrokenPipeError:
                broken = True
            try:
                status = proc.wait(timeout=FFMPEG_EXIT_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                raise VideoError(f"{path}: ffmpeg did not finish within "
                                 f"{FFMPEG_EXIT_TIMEOUT_S} s of the last frame") from None
        finally:
            if proc.poll() is None:  # an exception above (or Ctrl-C): no half-made video
                proc.kill()
                proc.wait()
        if status != 0 or broken:
            log.seek(0)
            words = [ln.strip() for ln in log.read().decode("utf-8", "replace").splitlines()
                     if ln.strip()]
            why = words[-1] if words else f"exit status {status}"
            raise VideoError(f"{path}: ffmpeg could not write the video: {why}")
        check_mp4(tmp)
    return path
