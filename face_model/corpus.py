"""Reading, validating and writing a corpus folder (the contract in DESIGN.md).

::

    corpus/
      corpus.json            generator settings, seed, layout version, package versions
      manifest.csv           utt_id, speaker, expression, text, n_frames, fps, sample_rate,
                             audio, markers, phones   (paths relative to corpus/)
                             [+ voice: "engine:voice" of the audio, when the corpus draws
                              voices per utterance]
                             [+ quality: quality/<utt_id>.csv, in a corpus made from video]
      audio/<utt_id>.wav     mono PCM16 (any lossless format the reader reads, e.g. FLAC)
      markers/<utt_id>.npy   float32 (n_frames, 79, 2), pixels, head motion included
      phones/<utt_id>.csv    start_s, end_s, phone   (44-class set)
      quality/<utt_id>.csv   frame, confidence, interpolated   (one row per frame: the landmark
                             detector's confidence, 1 where the frame's face was interpolated)
      words/<utt_id>.csv     start_s, end_s, word   (optional: the words' times, when the source
                             gives them, e.g. GRID's .align; silences sil/sp left out; the words
                             in order are the manifest's text)

:func:`load_corpus` validates every file before returning: a corpus either loads whole or fails
with a :class:`CorpusError` naming the file and the problem. A ``words/`` file is found by its
name (no manifest column: a corpus without one, or a copy of some of its rows, stays valid) and
read whenever it is there (:func:`face_model.transcripts.read_words`); an utterance without one
has ``words = None``.
"""
from __future__ import annotations

import csv
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from face_model.layout import N_MARKERS
from face_model.phones import PHONE_INDEX, PHONES
from face_model.transcripts import WordSegment, read_words, write_words_csv  # noqa: F401
from groundwork.audio import read_wav, resample, write_wav
from groundwork.errors import CorpusError, ParameterError

EXPRESSIONS = ("neutral", "smile", "sad")
MANIFEST_COLUMNS = ("utt_id", "speaker", "expression", "text", "n_frames", "fps",
                    "sample_rate", "audio", "markers", "phones")
OPTIONAL_COLUMNS = ("voice", "quality")  # written only when some row has it
QUALITY_COLUMNS = ("frame", "confidence", "interpolated")
WORDS_DIR = "words"  # words/<utt_id>.csv, optional
_FILE_COLUMNS = ("audio", "markers", "phones")  # the columns that name an utterance's files
FPS = 30
# Rates with an integer hop at 30 fps; anything else is refused or resampled to DEFAULT_SR.
SUPPORTED_SR = (22050, 44100, 48000, 24000, 32000, 96000)
DEFAULT_SR = 22050


@dataclass(frozen=True)
class PhoneSegment:
    """One line of a phone file: ``phone`` (one of the 44 classes) from ``start_s`` to
    ``end_s``, seconds from the start of the audio."""

    start_s: float
    end_s: float
    phone: str


@dataclass
class Utterance:
    """One validated utterance; arrays are loaded and checked.

    Attributes
    ----------
    utt_id, speaker, expression, text : str
        The manifest's fields (``expression`` one of :data:`EXPRESSIONS`).
    fps : int
        Video frame rate, 30.
    sample_rate : int
        Audio sample rate, Hz.
    audio : ndarray of float32, shape (n_samples,)
        Mono speech in [-1, 1].
    markers : ndarray of float32, shape (n_frames, 79, 2)
        Marker positions, image pixels, head motion included; frame k at k / fps s.
    phones : list of PhoneSegment
        In time order.
    voice : str
        The manifest's optional ``voice`` (``engine:voice``), "" when absent.
    quality : ndarray, shape (n_frames, 2), or None
        From video: per frame the detector's confidence and 1 where the face was interpolated
        (the manifest's optional ``quality`` file); None for a synthetic corpus.
    words : tuple of WordSegment, or None
        The words' times (``words/<utt_id>.csv``), in order; None when the corpus keeps none.
    """

    utt_id: str
    speaker: str
    expression: str
    text: str
    fps: int
    sample_rate: int
    audio: np.ndarray = field(repr=False)  # (n_samples,) float32
    markers: np.ndarray = field(repr=False)  # (n_frames, 79, 2) float32
    phones: list = field(repr=False)  # list[PhoneSegment]
    voice: str = ""  # the manifest's optional voice column ("engine:voice"; "" if absent)
    quality: np.ndarray | None = field(default=None, repr=False)  # (n_frames, 2) or None
    words: tuple | None = field(default=None, repr=False)  # tuple[WordSegment] or None

    @property
    def n_frames(self) -> int:
        return int(self.markers.shape[0])

    def phone_per_frame(self) -> np.ndarray:
        """Phone-class index (into :data:`PHONES`) of each video frame, shape (n_frames,).

        Frame k is at k / fps seconds; a frame outside every segment is ``sil``.
        """
        t = np.arange(self.n_frames) / self.fps
        out = np.full(self.n_frames, PHONE_INDEX["sil"], dtype=np.int64)
        for seg in self.phones:
            out[(t >= seg.start_s) & (t < seg.end_s)] = PHONE_INDEX[seg.phone]
        return out


@dataclass
class Corpus:
    """A loaded corpus (:func:`load_corpus`).

    Attributes
    ----------
    root : pathlib.Path
        Its folder.
    info : dict
        ``corpus.json`` (empty when the folder has none).
    utterances : list of Utterance
        In manifest order; ``corpus[utt_id]`` finds one by id.
    """

    root: Path
    info: dict
    utterances: list  # list[Utterance]

    def __len__(self) -> int:
        return len(self.utterances)

    def __getitem__(self, utt_id: str) -> Utterance:
        for u in self.utterances:
            if u.utt_id == utt_id:
                return u
        raise KeyError(f"{utt_id!r} is not in the corpus at {self.root}")

    @property
    def n_frames(self) -> int:
        return sum(u.n_frames for u in self.utterances)

    def by_expression(self, expression: str) -> list:
        return [u for u in self.utterances if u.expression == expression]


def read_phones(path: Path, duration_s: float, fps: int = 30) -> list[PhoneSegment]:
    """A phone file of the corpus contract (``start_s,end_s,phone``): segments in time order,
    44-class phones, finite times, no overlap, ending by one frame after the audio.

    Parameters
    ----------
    path : pathlib.Path
        The phone file.
    duration_s : float
        The audio's duration, seconds.
    fps : int
        Video frame rate (the last segment may end up to one frame after the audio).

    Returns
    -------
    list of PhoneSegment

    Raises
    ------
    CorpusError
        Naming the file (and the line): missing, wrong header, unknown phone, bad times.
    """
    if not path.is_file():
        raise CorpusError(f"{path}: phone file not found")
    segs: list[PhoneSegment] = []
    with open(path, newline="", encoding="utf-8-sig") as f:
        reader = csv.DictReader(f)
        if reader.fieldnames is None or list(reader.fieldnames)[:3] != ["start_s", "end_s", "phone"]:
            raise CorpusError(f"{path}: header must be 'start_s,end_s,phone', got {reader.fieldnames}")
        for line, row in enumerate(reader, start=2):
            phone = row["phone"]
            if phone not in PHONE_INDEX:
                raise CorpusError(f"{path}, line {line}: unknown phone {phone!r}; allowed are the "
                                  f"44 classes: {' '.join(PHONES)}")
            try:
                s, e = float(row["start_s"]), float(row["end_s"])
            except (TypeError, ValueError) as exc:
                raise CorpusError(f"{path}, line {line}: times must be numbers, got "
                                  f"{row['start_s']!r}, {row['end_s']!r}") from exc
            if not (np.isfinite(s) and np.isfinite(e)) or s < 0 or e <= s:
                raise CorpusError(f"{path}, line {line}: need 0 <= start_s < end_s, got {s}, {e}")
            if segs and s < segs[-1].end_s - 1e-6:
                raise CorpusError(f"{path}, line {line}: segment starts at {s} s, before the "
                                  f"previous one ends ({segs[-1].end_s} s)")
            segs.append(PhoneSegment(s, e, phone))
    if not segs:
        raise CorpusError(f"{path}: no phone segments")
    if segs[-1].end_s > duration_s + 1.0 / fps:
        raise CorpusError(f"{path}: last phone ends at {segs[-1].end_s:.3f} s, after the audio "
                          f"({duration_s:.3f} s)")
    return segs


def _read_markers(path: Path) -> np.ndarray:
    if not path.is_file():
        raise CorpusError(f"{path}: marker file not found")
    try:
        m = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise CorpusError(f"{path}: not a readable .npy array ({exc})") from exc
    if m.ndim != 3 or m.shape[1:] != (N_MARKERS, 2):
        raise CorpusError(f"{path}: markers must have shape (n_frames, {N_MARKERS}, 2), "
                          f"got {m.shape}")
    if m.dtype not in (np.float32, np.float64):
        raise CorpusError(f"{path}: markers must be float32 (or float64), got dtype {m.dtype}")
    if m.shape[0] == 0:
        raise CorpusError(f"{path}: markers hold no frames")
    bad = ~np.isfinite(m)
    if bad.any():
        frame, marker, _ = np.argwhere(bad)[0]
        raise CorpusError(f"{path}: {int(bad.sum())} non-finite values (NaN/inf), the first at "
                          f"frame {frame}, marker {marker}")
    return m.astype(np.float32, copy=False)


def _load_utterance(root: Path, row: dict, line: int, resample_to: int | None) -> Utterance:
    where = f"{root / 'manifest.csv'}, line {line}"
    if row["expression"] not in EXPRESSIONS:
        raise CorpusError(f"{where}: expression {row['expression']!r}; allowed: "
                          f"{', '.join(EXPRESSIONS)}")
    try:
        fps, n_frames, sr_declared = int(row["fps"]), int(row["n_frames"]), int(row["sample_rate"])
    except (TypeError, ValueError) as exc:
        raise CorpusError(f"{where}: fps, n_frames and sample_rate must be integers") from exc
    if fps != FPS:
        raise CorpusError(f"{where}: fps {fps}; the corpus format requires {FPS}")
    paths = {k: root / row[k] for k in _FILE_COLUMNS}
    for k, p in paths.items():
        if not p.is_file():
            raise CorpusError(f"{where}: {k} file {p} not found")
    y, sr = read_wav(paths["audio"])
    if sr != sr_declared:
        raise CorpusError(f"{paths['audio']}: sample rate {sr} Hz, the manifest says {sr_declared}")
    if sr not in SUPPORTED_SR:
        if resample_to is None:
            raise CorpusError(
                f"{paths['audio']}: sample rate {sr} Hz gives no integer hop at {FPS} fps; "
                f"allowed: {', '.join(map(str, SUPPORTED_SR))} (or load with resample_to=)")
        y, sr = resample(y, sr_in=sr, sr_out=resample_to), resample_to
    markers = _read_markers(paths["markers"])
    if markers.shape[0] != n_frames:
        raise CorpusError(f"{paths['markers']}: {markers.shape[0]} frames, the manifest says "
                          f"{n_frames}")
    audio_frames = len(y) * fps / sr
    if abs(audio_frames - n_frames) > 1.0:
        raise CorpusError(f"{paths['audio']}: audio lasts {len(y) / sr:.3f} s = "
                          f"{audio_frames:.2f} frames, but {paths['markers'].name} has {n_frames} "
                          "frames (more than one frame apart)")
    phones = read_phones(paths["phones"], len(y) / sr, fps)
    quality = _read_quality(root, row, where, n_frames) if row.get("quality") else None
    words_file = words_path(root, row["utt_id"])
    words = (read_words(words_file, duration_s=len(y) / sr, text=row["text"])
             if words_file.is_file() else None)
    return Utterance(row["utt_id"], row["speaker"], row["expression"], row["text"], fps, sr,
                     y, markers, phones, voice=row.get("voice") or "", quality=quality,
                     words=words)


def _read_quality(root: Path, row: dict, where: str, n_frames: int) -> np.ndarray:
    """The ``quality`` file of a row: (n_frames, 2) confidence in [0, 1], interpolated 0/1."""
    path = root / row["quality"]
    if not path.is_file():
        raise CorpusError(f"{where}: quality file {path} not found")
    rows = read_manifest(path, QUALITY_COLUMNS, not_found="a corpus made from video")
    try:
        q = np.array([[float(r["confidence"]), float(r["interpolated"])] for r in rows])
    except ValueError as exc:
        raise CorpusError(f"{path}: {exc}; confidence and interpolated must be numbers") from None
    if len(q) != n_frames:
        raise CorpusError(f"{path}: {len(q)} frames, the manifest says {n_frames}")
    if len(q) and (not np.all((q[:, 0] >= 0) & (q[:, 0] <= 1))
                   or not np.all(np.isin(q[:, 1], (0, 1)))):
        raise CorpusError(f"{path}: confidence must be in [0, 1] and interpolated 0 or 1")
    return q.reshape(n_frames, 2)


def words_path(root, utt_id: str) -> Path:
    """Where an utterance's optional words file is: ``root/words/<utt_id>.csv``."""
    return Path(root) / WORDS_DIR / f"{utt_id}.csv"


def write_words(root, utt_id: str, words) -> str:
    """Write ``root/words/<utt_id>.csv`` (:func:`face_model.transcripts.write_words_csv`: times
    rounded to 10 µs); return its path relative to ``root``.

    Parameters
    ----------
    root : path-like
        The corpus folder.
    utt_id : str
        The utterance.
    words : iterable of WordSegment or (start_s, end_s, word)
        In time order, silences left out.
    """
    path = words_path(root, utt_id)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_words_csv(path, words)
    return f"{WORDS_DIR}/{utt_id}.csv"


def read_manifest(path, columns=MANIFEST_COLUMNS, *,
                  not_found: str = "is its folder a corpus folder?",
                  error: type = CorpusError) -> list[dict]:
    """The rows of a ``manifest.csv``: the one reader of the file, for a corpus and for every
    other folder of recordings listed the same way (the real-speech set).

    Parameters
    ----------
    path : path-like
        The manifest file.
    columns : tuple of str
        The columns it must have (others are kept as they are).
    not_found : str
        What the refusal of a missing file suggests, in parentheses.
    error : type
        The exception raised (a :class:`~groundwork.errors.TalkingFaceError`): the caller's
        own kind of refusal, e.g. ``ParameterError`` for the study's stimulus list.

    Returns
    -------
    list of dict
        One ``{column: text}`` per line after the header, in file order.

    Raises
    ------
    CorpusError (or ``error``)
        The file is missing, or a required column is.
    """
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: manifest not found ({not_found})")
    with open(path, newline="", encoding="utf-8-sig") as f:
        reader = csv.DictReader(f)
        missing = [c for c in columns if c not in (reader.fieldnames or [])]
        if missing:
            raise error(f"{path}: missing columns {missing}; required: {', '.join(columns)}")
        return list(reader)


def load_corpus(root, *, resample_to: int | None = None) -> Corpus:
    """Load and validate a whole corpus folder.

    Parameters
    ----------
    root : path-like
        The corpus folder (holding ``manifest.csv``).
    resample_to : int, optional
        Resample audio whose rate has no integer hop at 30 fps to this rate (Hz) instead of
        refusing it.

    Returns
    -------
    Corpus

    Raises
    ------
    CorpusError
        Naming the file (and manifest line) of the first problem found.
    """
    root = Path(root)
    manifest = root / "manifest.csv"
    rows = read_manifest(manifest, MANIFEST_COLUMNS,
                         not_found=f"is {root} a corpus folder?")
    info_path = root / "corpus.json"
    info = {}
    if info_path.is_file():
        try:
            info = json.loads(info_path.read_text(encoding="utf-8"))
        except (ValueError, UnicodeDecodeError) as exc:
            raise CorpusError(f"{info_path}: not valid JSON ({exc}); restore it or make the "
                              "corpus again") from None
        if not isinstance(info, dict):
            raise CorpusError(f"{info_path}: expected a JSON object, got {type(info).__name__}")
    if not rows:
        raise CorpusError(f"{manifest}: no utterances listed")
    seen: set[str] = set()
    utts = []
    for line, row in enumerate(rows, start=2):
        if row["utt_id"] in seen:
            raise CorpusError(f"{manifest}, line {line}: duplicate utt_id {row['utt_id']!r}")
        seen.add(row["utt_id"])
        utts.append(_load_utterance(root, row, line, resample_to))
    return Corpus(root=root, info=info, utterances=utts)


def write_utterance(root, *, utt_id: str, audio: np.ndarray, sr: int, markers: np.ndarray,
                    phones: list) -> dict:
    """Write one utterance's three files under ``root``.

    Parameters
    ----------
    root : path-like
        The corpus folder (``audio/``, ``markers/``, ``phones/`` are created in it).
    utt_id : str
        Names the files.
    audio : ndarray, shape (n_samples,)
        Mono speech in [-1, 1], written as PCM16.
    sr : int
        Sample rate, Hz.
    markers : array_like, shape (n_frames, 79, 2)
        Marker positions, pixels (written as float32).
    phones : list of PhoneSegment
        Written with times rounded to 10 µs.

    Returns
    -------
    dict
        The manifest's path fields ``audio``, ``markers``, ``phones`` (relative to ``root``).

    Raises
    ------
    ParameterError
        Markers of another shape.
    """
    root = Path(root)
    markers = np.asarray(markers, dtype=np.float32)
    if markers.ndim != 3 or markers.shape[1:] != (N_MARKERS, 2):
        raise ParameterError(f"markers for {utt_id} must be (n_frames, 79, 2), got {markers.shape}")
    rel = {"audio": f"audio/{utt_id}.wav", "markers": f"markers/{utt_id}.npy",
           "phones": f"phones/{utt_id}.csv"}
    for sub in _FILE_COLUMNS:
        (root / sub).mkdir(parents=True, exist_ok=True)
    write_wav(root / rel["audio"], audio, sr)
    np.save(root / rel["markers"], markers, allow_pickle=False)
    with open(root / rel["phones"], "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["start_s", "end_s", "phone"])
        for seg in phones:
            w.writerow([f"{seg.start_s:.5f}", f"{seg.end_s:.5f}", seg.phone])
    return rel


def write_manifest(root, rows: list[dict]) -> None:
    """Write ``manifest.csv`` in ``root``.

    Parameters
    ----------
    root : path-like
        The corpus folder.
    rows : list of dict
        One per utterance, in order; each holds the :data:`MANIFEST_COLUMNS` (other keys are
        left out), and the :data:`OPTIONAL_COLUMNS` that any row has are written after them
        (blank where a row lacks one).
    """
    optional = tuple(c for c in OPTIONAL_COLUMNS if any(c in r for r in rows))
    with open(Path(root) / "manifest.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=MANIFEST_COLUMNS + optional, lineterminator="\n")
        w.writeheader()
        for r in rows:
            w.writerow({**{k: r[k] for k in MANIFEST_COLUMNS},
                        **{k: r.get(k, "") for k in optional}})


def corpus_hash(root) -> str:
    """SHA-256 over the manifest and every file it lists (in manifest order).

    Parameters
    ----------
    root : path-like
        The corpus folder.

    Returns
    -------
    str
        The digest, 64 hexadecimal characters.

    Raises
    ------
    FileNotFoundError
        The manifest or a file it lists is missing.
    CorpusError
        The manifest lacks one of the ``audio``, ``markers``, ``phones`` columns.
    """
    root = Path(root)
    h = hashlib.sha256()
    manifest = root / "manifest.csv"
    h.update(manifest.read_bytes())
    for row in read_manifest(manifest, _FILE_COLUMNS):
        for k in _FILE_COLUMNS:
            h.update((root / row[k]).read_bytes())
    return h.hexdigest()
