"""The real-speech evaluation set shipped in ``analysis/real_speech/``: its manifest, its loader
and the converters from the sources' own phone labels to the 44 classes.

The folder holds real recordings found in package archives (CMU ARCTIC ``slt`` and ``awb``, the
pocketsphinx test recordings, praatio's "bobby"; 16 kHz mono PCM16 WAV), 40 GRID speaker s1
sentences whose audio is the built-in real corpus's FLAC (``face_model/real_faces/grid-s1``, read
through a relative path) and spoken digits of the six FSDD speakers (8 kHz PCM16 WAV), each with
a phone file in the corpus format (``start_s, end_s, phone``; phones in the 44-class set of
:mod:`face_model.phones`). Audio of another rate or format (any that soundfile reads) is
resampled to :data:`SAMPLE_RATE` when loaded (up or down); the file's own rate is kept as
``SpeechItem.native_sr``. ``manifest.csv`` has one row per recording:

=================  ==========================================================================
``id``             a short name (``slt_a0009``)
``wav``            the audio, relative to the set folder
``labels``         the phone file, relative to the set folder
``speaker``        the speaker id, lowercase ``<collection>-<speaker>`` (:data:`SPEAKER_ID`:
                   ``arctic-slt``, ``grid-s1``, ``fsdd-jackson`` …), the scheme of
                   :func:`data_synth.backends.voice_speakers`: a training voice built from the
                   same speaker (flite's ``slt`` is ``arctic-slt``) makes the recording *seen*
``label_source``   ``hts`` (the HTS labels shipped with it), ``textgrid`` (its own TextGrid),
                   ``pocketsphinx-5.1.1 forced alignment`` (``tools/align_real_speech.py``) or
                   ``grid word alignment + espeak-ng in-word durations`` (GRID's own ``.align``
                   word times, phones inside a word timed by espeak-ng:
                   ``tools/grid_speech_labels.py``) or ``fsdd word span + espeak-ng in-word
                   durations`` (the FSDD file is the word: ``tools/fsdd_speech_labels.py``);
                   all but the aligner's are :data:`INDEPENDENT_SOURCES`
``label_origin``   the original annotation file in the set (hts, textgrid, GRID), else empty
``part``           ``dev`` or ``test`` (optional; ``test`` when absent): the development speakers
                   a configuration may be chosen on, and the test speakers it is reported on;
                   a ``dev`` recording must have independent labels
``transcript``     the words spoken
``licence``        the licence notice of the recording (the full texts sit beside the files)
=================  ==========================================================================

``README.md`` in the folder gives each file's package, version, path inside it and SHA-256.
A manifest of the older layout, with a ``speaker_source`` column, is refused: that column is now
``speaker``.
"""
from __future__ import annotations

import csv
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from face_model.corpus import PhoneSegment, read_phones
from face_model.corpus import read_manifest as read_manifest_rows
from face_model.forced_align import ALIGNER_NAME, tidy_segments
from face_model.phones import phone_class
from groundwork.audio import read_wav, resample
from groundwork.errors import CorpusError, ParameterError

SET_DIR = Path(__file__).resolve().parent / "real_speech"
MANIFEST = "manifest.csv"
MANIFEST_COLUMNS = ("id", "wav", "labels", "speaker", "label_source", "label_origin",
                    "transcript", "licence")
ALIGNED = ALIGNER_NAME
GRID_WORDS = "grid word alignment + espeak-ng in-word durations"
FSDD_WORDS = "fsdd word span + espeak-ng in-word durations"
LABEL_SOURCES = ("hts", "textgrid", ALIGNED, GRID_WORDS, FSDD_WORDS)
# Labels made without either recogniser compared on the set (pocketsphinx, hama).
INDEPENDENT_SOURCES = frozenset({"hts", "textgrid", GRID_WORDS, FSDD_WORDS})
# A speaker id: lowercase <collection>-<speaker> (arctic-slt, grid-s1, fsdd-jackson), or
# ``espeak`` (synthetic voices with no real speaker).
SPEAKER_ID = re.compile(r"^(?:espeak|[a-z][a-z0-9]*-[a-z0-9]+)$")
PARTS = ("dev", "test")  # the optional ``part`` column
SAMPLE_RATE = 16000


@dataclass(frozen=True)
class SpeechItem:
    """One recording of the set, loaded and checked. ``audio`` float32 (n_samples,) at ``sr``
    (always :data:`SAMPLE_RATE`); ``native_sr`` is the rate the file was recorded at (Hz)."""

    id: str
    wav: Path
    labels: Path
    speaker: str  # the speaker id (SPEAKER_ID); seen when a training voice's source is it
    label_source: str
    label_origin: str
    transcript: str
    licence: str
    sr: int
    audio: np.ndarray = field(repr=False)
    phones: tuple = field(repr=False)  # PhoneSegment, contiguous from 0 to the end of the audio
    part: str = "test"  # "dev" or "test"
    native_sr: int = SAMPLE_RATE  # the file's own sample rate (Hz), before resampling

    @property
    def duration_s(self) -> float:
        return len(self.audio) / self.sr

    @property
    def kind(self) -> str:
        """``digits`` for an isolated spoken word (``label_source`` :data:`FSDD_WORDS`: the file is
        the word), else ``sentences`` (continuous speech): the two kinds of recording the
        development rule weighs apart (:mod:`analysis.dev_rule`)."""
        return "digits" if self.label_source == FSDD_WORDS else "sentences"

    @property
    def independent(self) -> bool:
        """Its labels were made independently of both phone recognisers compared on the set
        (``label_source`` in :data:`INDEPENDENT_SOURCES`)."""
        return self.label_source in INDEPENDENT_SOURCES


def hts_segments(path, duration_s: float) -> list[PhoneSegment]:
    """Phones of an HTS full-context label file (times in 100 ns; the centre phone sits between
    ``-`` and ``+``), festival symbols mapped to the 44 classes (``ax`` stays ``ax``)."""
    segs = []
    for line_no, line in enumerate(Path(path).read_text(encoding="utf-8").splitlines(), 1):
        parts = line.split()
        if not parts:
            continue
        m = re.search(r"-([^+]+)\+", parts[2]) if len(parts) >= 3 else None
        if m is None:
            raise CorpusError(f"{path}, line {line_no}: not an HTS full-context label")
        segs.append((int(parts[0]) / 1e7, int(parts[1]) / 1e7,
                     phone_class(m.group(1), source=f"{path}, line {line_no}")))
    return tidy_segments(segs, duration_s)


def textgrid_segments(path, duration_s: float, tier: str = "phone") -> list[PhoneSegment]:
    """Phones of the interval tier ``tier`` of a Praat TextGrid (long text format), ARPAbet with
    stress. An empty interval is silence; the one merged label ``PT`` (praatio's "bobby":
    "ripped the") is split into /p/ and /t/ of equal length (a modification of the labels)."""
    text = Path(path).read_text(encoding="utf-8-sig")
    m = re.search(rf'name = "{re.escape(tier)}"(.*?)(?:item \[\d+\]:|\Z)', text, re.S)
    if m is None:
        raise CorpusError(f"{path}: no interval tier named {tier!r}")
    segs = []
    for s, e, label in re.findall(r'xmin = ([\d.eE+-]+)\s*xmax = ([\d.eE+-]+)\s*text = "([^"]*)"',
                                  m.group(1)):
        s, e = float(s), float(e)
        if label.upper() == "PT":
            mid = 0.5 * (s + e)
            segs += [(s, mid, "p"), (mid, e, "t")]
        else:
            segs.append((s, e, phone_class(label, source=str(path))))
    return tidy_segments(segs, duration_s)


def write_labels(path, segs) -> Path:
    """A phone file in the corpus format."""
    path = Path(path)
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["start_s", "end_s", "phone"])
        for seg in segs:
            w.writerow([f"{seg.start_s:.4f}", f"{seg.end_s:.4f}", seg.phone])
    return path


def read_labels(path, duration_s: float) -> tuple[PhoneSegment, ...]:
    """The phone file at ``path``: contiguous segments from 0 to the end of the audio.

    Raises
    ------
    CorpusError
        Naming the file and line: a wrong header, an unknown phone, bad times, a gap or an
        overlap, or an end more than 10 ms away from the audio's.
    """
    path = Path(path)
    segs = read_phones(path, duration_s)  # the corpus's phone files, then the stricter rules
    expected = 0.0
    for line, seg in enumerate(segs, start=2):  # one segment per line after the header
        if abs(seg.start_s - expected) > 1e-6:
            raise CorpusError(f"{path}, line {line}: segment {seg.start_s}–{seg.end_s} s must "
                              f"start where the previous one ends ({expected} s)")
        expected = seg.end_s
    if abs(segs[-1].end_s - duration_s) > 0.01:
        raise CorpusError(f"{path}: the last phone ends at {segs[-1].end_s:.4f} s but the audio "
                          f"lasts {duration_s:.4f} s")
    return tuple(segs)


def read_manifest(set_dir=SET_DIR) -> list[dict]:
    """The manifest's rows, with every column present and non-empty (``label_origin`` may be
    empty), ids unique, ``speaker`` a :data:`SPEAKER_ID`, ``label_source`` one of
    :data:`LABEL_SOURCES`, ``part`` one of :data:`PARTS`, and every ``dev`` row independently
    labelled (:data:`INDEPENDENT_SOURCES`).

    Raises
    ------
    CorpusError
        Naming the file (and line): any of the above broken, or the old ``speaker_source``
        column present.
    """
    path = Path(set_dir) / MANIFEST
    rows = read_manifest_rows(path, MANIFEST_COLUMNS,
                              not_found=f"--set-dir must be a folder holding {MANIFEST}")
    if rows and "speaker_source" in rows[0]:
        raise CorpusError(f"{path}: has the old column speaker_source; the speaker id is now "
                          "the column speaker (lowercase <collection>-<speaker>, e.g. "
                          "arctic-slt): drop speaker_source and write its id in speaker")
    if not rows:
        raise CorpusError(f"{path}: no recordings listed")
    seen = set()
    for line, row in enumerate(rows, start=2):
        empty = [c for c in MANIFEST_COLUMNS if c != "label_origin" and not (row[c] or "").strip()]
        if empty:
            raise CorpusError(f"{path}, line {line}: empty {', '.join(empty)}")
        if row["id"] in seen:
            raise CorpusError(f"{path}, line {line}: id {row['id']!r} is listed twice")
        seen.add(row["id"])
        if row["label_source"] not in LABEL_SOURCES:
            raise CorpusError(f"{path}, line {line}: label_source {row['label_source']!r}; "
                              f"allowed: {', '.join(LABEL_SOURCES)}")
        if not SPEAKER_ID.match(row["speaker"]):
            raise CorpusError(f"{path}, line {line}: speaker {row['speaker']!r}; allowed: a "
                              "lowercase id <collection>-<speaker> (e.g. arctic-slt, grid-s1) "
                              "or espeak")
        row["part"] = (row.get("part") or "test").strip()
        if row["part"] not in PARTS:
            raise CorpusError(f"{path}, line {line}: part {row['part']!r}; allowed: "
                              f"{', '.join(PARTS)} (or empty: test)")
        if row["part"] == "dev" and row["label_source"] not in INDEPENDENT_SOURCES:
            raise CorpusError(f"{path}, line {line}: dev recording {row['id']!r} has labels "
                              f"from {row['label_source']!r}, a recogniser the set compares; "
                              "a dev recording needs independent labels ("
                              f"{', '.join(sorted(INDEPENDENT_SOURCES))}) or part test")
    return rows


def _load_item(set_dir: Path, row: dict) -> SpeechItem:
    wav = set_dir / row["wav"]
    if not wav.is_file():
        raise CorpusError(f"{wav}: audio file of {row['id']!r} not found")
    # WAV, FLAC, ... ; a file it cannot read, empty or not mono is an AudioFileError naming it
    y, native_sr = read_wav(wav)
    duration_s = len(y) / native_sr  # the labels are checked against the file's own length
    sr = native_sr
    if sr != SAMPLE_RATE:  # up (8 kHz FSDD) or down (22,050 Hz GRID FLAC)
        y, sr = resample(y, sr_in=sr, sr_out=SAMPLE_RATE), SAMPLE_RATE
    phones = read_labels(set_dir / row["labels"], duration_s)
    return SpeechItem(id=row["id"], wav=wav, labels=set_dir / row["labels"],
                      speaker=row["speaker"],
                      label_source=row["label_source"], label_origin=row["label_origin"] or "",
                      transcript=row["transcript"], licence=row["licence"], sr=sr,
                      audio=np.asarray(y, dtype=np.float32), phones=phones, part=row["part"],
                      native_sr=int(native_sr))


def subset_rows(rows: list, per_speaker: int = 0) -> list:
    """The first ``per_speaker`` of ``rows`` (manifest rows, :func:`read_manifest`) of each
    speaker in each part, in their order; every row when ``per_speaker`` is 0 (the setting
    ``speech_set.per_speaker``, :class:`analysis.config.SpeechSetConfig`). A speaker and part
    with fewer rows gives all it has, so every speaker and part of ``rows`` is kept.

    Raises
    ------
    ParameterError
        ``per_speaker`` not an integer >= 0.
    """
    if isinstance(per_speaker, bool) or not isinstance(per_speaker, int) or per_speaker < 0:
        raise ParameterError(f"speech_set.per_speaker is {per_speaker!r}; allowed: an integer "
                             ">= 0 (0: every recording)")
    if per_speaker == 0:
        return list(rows)
    taken: dict = {}
    out = []
    for r in rows:
        group = (r["speaker"], r.get("part") or "test")
        if taken.get(group, 0) < per_speaker:
            taken[group] = taken.get(group, 0) + 1
            out.append(r)
    return out


def load_speech_set(set_dir=SET_DIR, ids=None, per_speaker: int = 0) -> list[SpeechItem]:
    """Every recording of the set (or those in ``ids``; of those, the first ``per_speaker``
    of each speaker and part when it is not 0: :func:`subset_rows`), loaded and checked (see
    :func:`read_manifest` and :func:`read_labels`); errors name the file."""
    set_dir = Path(set_dir)
    rows = read_manifest(set_dir)
    if ids is not None:
        unknown = sorted(set(ids) - {r["id"] for r in rows})
        if unknown:
            raise CorpusError(f"{set_dir / MANIFEST}: no recordings {unknown}")
        rows = [r for r in rows if r["id"] in set(ids)]
    return [_load_item(set_dir, r) for r in subset_rows(rows, per_speaker)]
