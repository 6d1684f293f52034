"""The bad-input table's part: Videos whose face is not one upright speaker's (two faces side by side, upside down) and
damaged videos.

``CASES`` are ``(argv, names)`` as in :mod:`tests.talkingface.bad_input_cases`;
:func:`add_inputs` makes the files they name in the suite's working folder: two GRID clips side
by side (``hstack``), one upside down (``vflip``), both 2 s long, and a GRID ``.mpg`` cut to
half its bytes beside its whole ``.align`` (each folder holds one clip, so the import refuses
it whole, exit 2).
"""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import imageio_ffmpeg

from tests.talkingface.bad_input_cases import GRID, TFMAP

TWO_FACES = ["v_twofaces/clip.mpg", "50 of 50 frames show more than one face",
             "crop the video to the speaker's face"]
UPSIDE_DOWN = ["v_upside/clip.mpg", "from upright", "allowed: at most 30°"]

CASES: list = [
    (["corpus", "from-video", "v_twofaces", "--out", "newv"], TWO_FACES),
    (["evaluate-face", "--model", TFMAP, "v_twofaces"], TWO_FACES),
    (["corpus", "from-video", "v_upside", "--out", "newv"], UPSIDE_DOWN),
    (["evaluate-face", "--model", TFMAP, "v_upside"], UPSIDE_DOWN),
    (["corpus", "from-video", "v_truncated", "--out", "newv"],
     ["v_truncated/clip.mpg", "truncated", "v_truncated/clip.align runs to 2.98 s"]),
]


def _encode(ffmpeg: str, args: list, out: Path) -> None:
    subprocess.run([ffmpeg, "-v", "error", *args, "-t", "2", "-c:v", "mpeg1video", "-q:v", "4",
                    "-c:a", "mp2", str(out)], check=True)


def add_inputs(root: Path) -> None:
    """Make the inputs of :data:`CASES` in ``root``."""
    ffmpeg = imageio_ffmpeg.get_ffmpeg_exe()
    video = GRID / "video"
    for name in ("v_twofaces", "v_upside", "v_truncated"):
        (root / name).mkdir()
    for name in ("v_twofaces", "v_upside"):
        (root / name / "clip.txt").write_text("bin blue by f eight please\n")
    _encode(ffmpeg, ["-i", str(video / "bbbf8p.mpg"), "-i", str(video / "lbbk4n.mpg"),
                     "-filter_complex", "[0:v][1:v]hstack=inputs=2[v]", "-map", "[v]",
                     "-map", "0:a"], root / "v_twofaces" / "clip.mpg")
    _encode(ffmpeg, ["-i", str(video / "bbbf8p.mpg"), "-vf", "vflip"],
            root / "v_upside" / "clip.mpg")
    whole = (video / "bbbf8p.mpg").read_bytes()
    (root / "v_truncated" / "clip.mpg").write_bytes(whole[:len(whole) // 2])
    shutil.copy(GRID / "align" / "bbbf8p.align", root / "v_truncated" / "clip.align")
