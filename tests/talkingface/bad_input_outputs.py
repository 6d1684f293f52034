"""The bad-input table's part: Outputs that exist already (evaluate-face, --keep-landmarks), clips with one name, sources
that are not videos.

``CASES`` are ``(argv, names)`` as in :mod:`tests.talkingface.bad_input_cases`;
:func:`add_inputs` makes the files they name in the suite's working folder.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

from tests.talkingface.bad_input_cases import GRID, TFMAP

SPEAKER = "s9/video"  # GRID's layout: every speaker's clips are in a folder named video
CLIP = "bbbf8p"


def _face(*args):
    return ["evaluate-face", "--model", TFMAP, *args]


def _import(*args, src=SPEAKER):
    return ["corpus", "from-video", src, "--out", "newv", *args]


CASES: list = [
    # -- evaluate-face: an earlier result is replaced only with --overwrite, a folder of other
    #    files never; the default folder is the source's own (face_eval/s9-video-<hash>)
    (_face(SPEAKER, "--out", "eval_done"), ["--out eval_done", "--overwrite"]),
    (_face(SPEAKER), ["face_eval/s9-video-", "already holds an evaluation", "--overwrite"]),
    (_face(SPEAKER, "--out", "eval_mine"), ["eval_mine", "not an evaluation's"]),
    (_face(SPEAKER, "--out", "eval_mine", "--overwrite"), ["eval_mine", "not an evaluation's"]),
    (_face(SPEAKER, "--out", "speech.wav"), ["--out speech.wav", "is a file"]),
    (_face(SPEAKER, "--workers", "0"), ["--workers", "0", "allowed: a whole number, 1 or more"]),
    (_face(SPEAKER, "--workers", "two"), ["--workers", "two", "1 or more"]),
    # -- corpus from-video --keep-landmarks: never over another import's landmark files
    (_import("--keep-landmarks", "lm_other"),
     ["--keep-landmarks lm_other", f"{CLIP}.npz", "holds 1 of this import's 1"]),
    (_import("--keep-landmarks", "speech.wav"), ["--keep-landmarks speech.wav", "is a file"]),
    # -- two clips with one name
    (_import(src="v_samename"), ["v_samename/clip.mp4", "v_samename/clip.mpg", "'clip'"]),
    (_face("v_samename"), ["v_samename/clip.mp4", "v_samename/clip.mpg"]),
    # -- audio given as a video
    (_import(src="speech.wav"), ["speech.wav is audio, not a video", ".mpg",
                                 "talkingface animate"]),
    (_face("speech.wav"), ["speech.wav is audio, not a video", "talkingface animate"]),
    (_import(src="wav_only"), ["wav_only", "no videos", "only audio", "talkingface animate"]),
    (_import("--workers", "-1"), ["--workers", "-1", "1 or more"]),
]


def _evaluation(folder: Path, source: Path) -> None:
    """An earlier evaluation's files in ``folder`` (their contents do not matter here)."""
    folder.mkdir(parents=True)
    (folder / "per_clip.csv").write_text("clip,speaker\n" f"{CLIP},s9\n")
    (folder / f"opening_{CLIP}.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    (folder / "scores.json").write_text(json.dumps(
        {"model": TFMAP, "source": str(source), "source_path": str(source.resolve())}) + "\n")


def add_inputs(root: Path) -> None:
    """Make the inputs of :data:`CASES` in ``root``: a GRID-like speaker folder ``s9/video``
    (one clip and its transcript), earlier evaluations of it (``eval_done`` and its default
    folder beside the run's model), a folder of other files (``eval_mine``), another import's
    landmarks (``lm_other``), two clips with one name (``v_samename``) and a folder of WAVs."""
    from talkingface.cli.faces import default_eval_folder

    video = root / SPEAKER
    video.mkdir(parents=True)
    shutil.copy(GRID / "video" / f"{CLIP}.mpg", video)
    (video / f"{CLIP}.txt").write_text("bin blue by f eight please\n")
    _evaluation(root / "eval_done", video)
    _evaluation(default_eval_folder(root / TFMAP, video), video)
    (root / "eval_mine").mkdir()
    (root / "eval_mine" / "notes.txt").write_text("the user's own notes\n")
    (root / "lm_other").mkdir()
    (root / "lm_other" / f"{CLIP}.npz").write_bytes(b"another speaker's landmarks")
    same = root / "v_samename"
    same.mkdir()
    for ext in (".mpg", ".mp4"):
        shutil.copy(GRID / "video" / f"{CLIP}.mpg", same / f"clip{ext}")
    (same / "clip.txt").write_text("bin blue by f eight please\n")
    (root / "wav_only").mkdir()
    shutil.copy(GRID / "audio" / "bbaf3s.wav", root / "wav_only")
