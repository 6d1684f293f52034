"""Transcripts of recorded clips: GRID ``.align`` files, one-line ``.txt`` files and a CSV table.

=============  =================================================================================
``.align``     GRID word alignment: one ``start end word`` per line, times in 1/25000 s
               (:data:`ALIGN_UNITS_PER_S`), in order and not overlapping; ``sil`` and ``sp`` are
               silence and are left out of the text. Gives the words' times too.
``.txt``       one line of text (blank lines around it are ignored)
words file     a corpus's ``words/<utt_id>.csv``: ``start_s,end_s,word`` in seconds, silences
               left out (:func:`read_words`, :func:`write_words_csv`; written from an ``.align``)
CSV            columns ``clip,text`` (others ignored), one row per clip: ``clip`` is the
               video's file name without its extension
=============  =================================================================================

:func:`find_transcript` finds a clip's transcript beside its video, in an ``align/`` folder next
to the video's folder (GRID's layout: ``grid-s1/video/x.mpg`` ↔ ``grid-s1/align/x.align``), in
a folder given, or in a CSV table. Every malformed file is refused with one line naming the
file, the line and what is allowed.
"""
from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from groundwork.errors import CorpusError

ALIGN_UNITS_PER_S = 25000  # GRID's .align time unit
SILENCE_WORDS = frozenset({"sil", "sp"})
END_TOLERANCE_S = 0.1  # how far a transcript may end after its audio
CSV_COLUMNS = ("clip", "text")
WORDS_COLUMNS = ("start_s", "end_s", "word")  # a corpus's words/<utt_id>.csv
_ALIGN_FORMAT = f"'start end word' with times in 1/{ALIGN_UNITS_PER_S} s"
_SILENCES = ", ".join(sorted(SILENCE_WORDS))


@dataclass(frozen=True)
class WordSegment:
    """One line of a words file: ``word`` spoken from ``start_s`` to ``end_s``, seconds from the
    start of the audio."""

    start_s: float
    end_s: float
    word: str


@dataclass(frozen=True)
class Transcript:
    """A clip's transcript.

    Attributes
    ----------
    text : str
        The words spoken, separated by single spaces (no ``sil``/``sp``).
    source : str
        Where it was read (a file, or a CSV file and clip), for messages.
    words : tuple of (start_s, end_s, word)
        The words' times when the file gives them (``.align``), else empty.
    end_s : float or None
        Where the file's last entry (silence included) ends, when it gives times.
    """

    text: str
    source: str
    words: tuple = ()
    end_s: float | None = None

    def check_word_times(self, duration_s: float, *, source: str = "") -> None:
        """Refuse word times that cannot be this sentence's on this audio: what is checked of a
        transcript that comes with the source's own word times, instead of its acoustic match.

        Parameters
        ----------
        duration_s : float
            The audio's length, seconds.
        source : str
            The recording, for the message (default: the transcript's file).

        Raises
        ------
        CorpusError
            No word times; the words, in time order, are not the text's words in order (case
            aside); a word ending before it starts or starting before the previous one ends;
            a word not inside the audio (from 0 to ``duration_s``).
        """
        which = f"{source}: the transcript {self.source}" if source else \
            f"{self.source}: the transcript"
        if not self.words:
            raise CorpusError(f"{which} gives no word times")
        said, timed = self.text.lower().split(), [w.lower() for _, _, w in self.words]
        if timed != said:
            raise CorpusError(f"{which} times the words {' '.join(timed)!r} but its sentence "
                              f"is {self.text!r}; allowed: the sentence's words in order")
        prev_end = 0.0
        for i, (s, e, w) in enumerate(self.words, 1):
            if not 0 <= s < e:
                raise CorpusError(f"{which}: word {i} {w!r} from {s:.3f} s to {e:.3f} s; "
                                  "allowed: 0 <= start < end")
            if s < prev_end - 1e-9:
                raise CorpusError(f"{which}: word {i} {w!r} starts at {s:.3f} s, before the "
                                  f"previous word ends ({prev_end:.3f} s); allowed: words in "
                                  "time order, not overlapping")
            if e > duration_s + 1e-9:
                raise CorpusError(f"{which}: word {i} {w!r} ends at {e:.3f} s, after the audio "
                                  f"({duration_s:.3f} s); allowed: every word inside the audio")
            prev_end = e

    def check_duration(self, duration_s: float, *, source: str = "") -> None:
        """Refuse a transcript whose times run past the end of its audio.

        Parameters
        ----------
        duration_s : float
            The audio's length.
        source : str
            The recording, for the message (default: the transcript's file).

        Raises
        ------
        CorpusError
            The transcript ends more than :data:`END_TOLERANCE_S` after the audio.
        """
        if self.end_s is not None and self.end_s > duration_s + END_TOLERANCE_S:
            which = f"{source}: the transcript {self.source}" if source else \
                f"{self.source}: the transcript"
            raise CorpusError(
                f"{which} ends at {self.end_s:.3f} s but the audio lasts {duration_s:.3f} s "
                f"(allowed: up to {END_TOLERANCE_S:g} s after its end); it does not match the "
                f"audio")


def _read_text(path: Path) -> str:
    if not path.is_file():
        raise CorpusError(f"{path}: transcript file not found")
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise CorpusError(f"{path}: not UTF-8 text (byte {exc.start}); a transcript is a "
                          f"UTF-8 text file") from None


def _time(path: Path, line_no: int, name: str, value: str) -> float:
    try:
        t = float(value)
    except ValueError:
        t = math.nan
    if not math.isfinite(t) or t < 0:
        raise CorpusError(f"{path}, line {line_no}: {name} time {value!r} is not a number of "
                          f"0 or more; each line is {_ALIGN_FORMAT}")
    return t / ALIGN_UNITS_PER_S


def read_align(path) -> Transcript:
    """A GRID ``.align`` word alignment.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    Transcript
        ``words`` in seconds, without ``sil``/``sp``; ``end_s`` where the last line ends.

    Raises
    ------
    CorpusError
        Naming the file and line: not three fields, a time that is not a number of 0 or more,
        an end not after its start, a line starting before the previous one ends, or no words
        other than ``sil``/``sp``.
    """
    path = Path(path)
    words, prev_end, n_lines = [], 0.0, 0
    for line_no, line in enumerate(_read_text(path).splitlines(), 1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) != 3:
            raise CorpusError(f"{path}, line {line_no}: {line.strip()!r} has {len(parts)} "
                              f"fields; each line is {_ALIGN_FORMAT}")
        start = _time(path, line_no, "start", parts[0])
        end = _time(path, line_no, "end", parts[1])
        if end <= start:
            raise CorpusError(f"{path}, line {line_no}: end {parts[1]} is not after start "
                              f"{parts[0]}; a word must end after it starts")
        if start < prev_end - 1e-9:
            raise CorpusError(f"{path}, line {line_no}: start {parts[0]} is before the end of "
                              f"the previous line ({prev_end * ALIGN_UNITS_PER_S:g}); times "
                              f"must increase line by line")
        prev_end, n_lines = end, n_lines + 1
        if parts[2].lower() not in SILENCE_WORDS:
            words.append((start, end, parts[2]))
    if not words:
        what = "no lines" if n_lines == 0 else "only silence (sil, sp)"
        raise CorpusError(f"{path}: {what}; a transcript needs the words spoken, one "
                          f"{_ALIGN_FORMAT} per line")
    return Transcript(" ".join(w for _, _, w in words), str(path), tuple(words), prev_end)


def read_txt(path) -> Transcript:
    """A one-line text transcript.

    Raises
    ------
    CorpusError
        The file is empty or blank, holds more than one line of text, or is not UTF-8.
    """
    path = Path(path)
    lines = [(n, line.strip()) for n, line in enumerate(_read_text(path).splitlines(), 1)
             if line.strip()]
    if not lines:
        raise CorpusError(f"{path}: empty; a transcript file holds one line of text, the "
                          f"words spoken")
    if len(lines) > 1:
        raise CorpusError(f"{path}, line {lines[1][0]}: a second line of text; a transcript "
                          f"file holds one line, the words spoken")
    return Transcript(" ".join(lines[0][1].split()), str(path))


def read_transcript(path) -> Transcript:
    """A ``.align`` or ``.txt`` transcript, by its extension.

    Raises
    ------
    CorpusError
        Another extension, or a malformed file (see :func:`read_align`, :func:`read_txt`).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".align":
        return read_align(path)
    if suffix == ".txt":
        return read_txt(path)
    raise CorpusError(f"{path}: transcript extension {path.suffix!r}; allowed: .align (GRID "
                      f"word alignment) or .txt (one line of text)")


def read_transcript_csv(path) -> dict[str, str]:
    """A table of transcripts: ``{clip: text}``.

    Parameters
    ----------
    path : path-like
        CSV with a header holding ``clip`` and ``text`` (other columns ignored).

    Raises
    ------
    CorpusError
        Naming the file and line: no header or no rows, a missing column, a row with another
        number of fields than the header, an empty clip or text, or a clip listed twice.
    """
    path = Path(path)
    reader = csv.reader(io.StringIO(_read_text(path), newline=""))
    header = next(reader, None)
    if header is None or not any(h.strip() for h in header):
        raise CorpusError(f"{path}: empty; a transcript table is a CSV with columns "
                          f"{','.join(CSV_COLUMNS)}, one row per clip")
    names = [h.strip().lower() for h in header]
    missing = [c for c in CSV_COLUMNS if c not in names]
    if missing:
        raise CorpusError(f"{path}, line 1: header {','.join(header)!r} lacks "
                          f"{', '.join(missing)}; required columns: {','.join(CSV_COLUMNS)}")
    i_clip, i_text = names.index("clip"), names.index("text")
    table: dict[str, str] = {}
    for row in reader:
        line = reader.line_num
        if not any(f.strip() for f in row):
            continue
        if len(row) != len(header):
            raise CorpusError(f"{path}, line {line}: {len(row)} fields, the header has "
                              f"{len(header)}; quote a text holding commas (\"a, b\")")
        clip, text = row[i_clip].strip(), " ".join(row[i_text].split())
        if not clip or not text:
            raise CorpusError(f"{path}, line {line}: empty {'clip' if not clip else 'text'}; "
                              f"every row names a clip and the words spoken")
        if clip in table:
            raise CorpusError(f"{path}, line {line}: clip {clip!r} is listed twice; one row "
                              f"per clip")
        table[clip] = text
    if not table:
        raise CorpusError(f"{path}: no rows; a transcript table has one row per clip under "
                          f"the header {','.join(CSV_COLUMNS)}")
    return table


def read_words(path, *, duration_s: float, text: str | None = None) -> tuple:
    """A corpus's words file (``words/<utt_id>.csv`` of :mod:`face_model.corpus`:
    ``start_s,end_s,word``).

    Parameters
    ----------
    path : path-like
        The words file.
    duration_s : float
        The audio's duration, seconds (a word may end up to
        :data:`END_TOLERANCE_S` after it, as the import allows).
    text : str, optional
        The manifest's text: the words in order must be its words (case aside).

    Returns
    -------
    tuple of WordSegment
        In time order.

    Raises
    ------
    CorpusError
        One line naming the file, the line and what is allowed: a wrong header or number of
        fields, times that are not numbers, a word ending before it starts or starting before
        the previous one ends, a silence token or an empty word, a word after the audio, no
        words, or words other than the text's.
    """
    path = Path(path)
    if not path.is_file():
        raise CorpusError(f"{path}: words file not found")
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            rows = list(csv.reader(f))
    except UnicodeDecodeError as exc:
        raise CorpusError(f"{path}: not UTF-8 text (byte {exc.start}); allowed: a UTF-8 CSV "
                          f"with the header {','.join(WORDS_COLUMNS)}") from None
    header = ",".join(c.strip() for c in rows[0]) if rows else ""
    if header != ",".join(WORDS_COLUMNS):
        raise CorpusError(f"{path}, line 1: header {header!r}; allowed: "
                          f"{','.join(WORDS_COLUMNS)} (times in seconds, one word per line)")
    words: list[WordSegment] = []
    lines: list[int] = []
    for line, row in enumerate(rows[1:], start=2):
        if not any(c.strip() for c in row):
            continue
        where = f"{path}, line {line}"
        if len(row) != len(WORDS_COLUMNS):
            raise CorpusError(f"{where}: {len(row)} fields {','.join(row)!r}; allowed: 3, "
                              "start_s,end_s,word")
        try:
            s, e = float(row[0]), float(row[1])
        except ValueError:
            s = e = float("nan")
        if not (math.isfinite(s) and math.isfinite(e)) or s < 0 or e <= s:
            raise CorpusError(f"{where}: times {row[0]!r}, {row[1]!r}; allowed: numbers of "
                              "seconds with 0 <= start_s < end_s")
        if words and s < words[-1].end_s - 1e-6:
            raise CorpusError(f"{where}: starts at {s:g} s, before the previous word ends "
                              f"({words[-1].end_s:g} s); allowed: words in time order, not "
                              "overlapping")
        word = row[2].strip()
        if not word or len(word.split()) != 1 or word.lower() in SILENCE_WORDS:
            raise CorpusError(f"{where}: word {row[2]!r}; allowed: one word per line, "
                              f"silences ({_SILENCES}) left out")
        if e > duration_s + END_TOLERANCE_S:
            raise CorpusError(f"{where}: word {word!r} ends at {e:g} s, after the audio "
                              f"({duration_s:.3f} s); allowed: up to {END_TOLERANCE_S:g} s "
                              "after its end")
        words.append(WordSegment(s, e, word))
        lines.append(line)
    if not words:
        raise CorpusError(f"{path}: no words under the header; allowed: one line per word "
                          "spoken (a corpus without word times has no words file)")
    if text is not None:
        said = text.lower().split()
        for i, (w, line) in enumerate(zip(words, lines)):
            if i >= len(said) or w.word.lower() != said[i]:
                wanted = f"word {i + 1} {said[i]!r}" if i < len(said) else \
                    f"only {len(said)} words"
                raise CorpusError(f"{path}, line {line}: word {w.word!r}, but the manifest's "
                                  f"text {text!r} has {wanted} there; allowed: the text's "
                                  "words in order, one per line")
        if len(words) < len(said):
            raise CorpusError(f"{path}: {len(words)} words, but the manifest's text {text!r} "
                              f"has {len(said)}; allowed: the text's words in order, one per "
                              "line")
    return tuple(words)


def write_words_csv(path, words) -> None:
    """Write a words file (``start_s,end_s,word``, times rounded to 10 µs).

    Parameters
    ----------
    path : path-like
        The file; its folder must exist.
    words : iterable of WordSegment or (start_s, end_s, word)
        In time order, silences left out (e.g. :attr:`Transcript.words`).
    """
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(WORDS_COLUMNS)
        for s, e, word in ((x.start_s, x.end_s, x.word) if isinstance(x, WordSegment) else x
                           for x in words):
            w.writerow([f"{s:.5f}", f"{e:.5f}", word])


def find_transcript(video_path, transcripts_dir=None, csv_map=None) -> Transcript | None:
    """The transcript of the clip ``video_path``, or None if there is none.

    Looked for, in this order: ``<stem>.align`` then ``<stem>.txt`` in ``transcripts_dir``; the
    clip's row of ``csv_map``; ``<stem>.align`` / ``<stem>.txt`` beside the video; the same in
    an ``align/`` folder next to the video's folder (GRID: ``video/x.mpg`` ↔ ``align/x.align``).

    Parameters
    ----------
    video_path : path-like
    transcripts_dir : path-like, optional
        A folder of ``.align`` / ``.txt`` files named after the clips.
    csv_map : mapping or path-like, optional
        ``{clip: text}`` (from :func:`read_transcript_csv`) or the CSV file itself.

    Returns
    -------
    Transcript or None

    Raises
    ------
    CorpusError
        The transcript found is malformed (or the CSV file is).
    """
    video = Path(video_path)
    stem = video.stem
    folders = [Path(transcripts_dir)] if transcripts_dir is not None else []
    for folder in folders:
        found = _in_folder(folder, stem)
        if found is not None:
            return found
    if csv_map is not None:
        where = "transcript table" if isinstance(csv_map, Mapping) else str(csv_map)
        table = csv_map if isinstance(csv_map, Mapping) else read_transcript_csv(csv_map)
        if stem in table:
            return Transcript(" ".join(str(table[stem]).split()), f"{where}, clip {stem}")
    for folder in (video.parent, video.parent.parent / "align"):
        found = _in_folder(folder, stem)
        if found is not None:
            return found
    return None


def _in_folder(folder: Path, stem: str) -> Transcript | None:
    for suffix in (".align", ".txt"):
        candidate = folder / f"{stem}{suffix}"
        if candidate.is_file():
            return read_transcript(candidate)
    return None
