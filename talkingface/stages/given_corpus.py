"""A given corpus (``corpus.source``, ``--corpus DIR``) as the run's corpus.

The ``corpus`` stage takes a corpus folder in the corpus contract (DESIGN.md) instead of
synthesising one: the folder is validated by the one reader (:func:`face_model.corpus.load_corpus`)
before anything of the run is written (the stage's key reads it: :func:`corpus_inputs`), then
its files are hard-linked into the run's ``corpus/`` folder (copied where a link cannot be made,
e.g. across file systems). The stage is built in a partial folder and renamed into place only
when complete (:func:`talkingface.stages.base.run_stage`), so an interrupted copy leaves nothing
behind under ``corpus/``.

The stage's key is ``corpus.source`` (not the ``synth`` settings, which a given corpus does not
read), its :func:`face_model.corpus.corpus_hash` (the manifest and the audio, markers and phones
it lists) and a SHA-256 of the other files taken (``corpus.json``, a corpus from video's
``quality/`` files): a changed corpus is copied again, with everything downstream of it; an
unchanged one is reused. A corpus is read and hashed once per process however often
its key is asked for, while its files keep their sizes and modification times
(:func:`_signature`). The real speaker's corpus (``real_speaker.corpus``,
:mod:`talkingface.stages.real_speaker`) is checked by the same :func:`check_folder`, under its
own setting's name.

Hard links share the files with the source folder: edit a given corpus by writing new files
(as the project's writers do), never in place.
"""
from __future__ import annotations

import csv
import hashlib
import json
import os
import shutil
from pathlib import Path

from face_model.corpus import corpus_hash, load_corpus, read_manifest
from groundwork.atomic import atomic_file
from groundwork.errors import CorpusError
from talkingface.paths import RunPaths
from talkingface.stages.applies import expression_note, given

# manifest columns that never name a file; every other column's cells that name a file inside
# the corpus folder are taken (audio, markers, phones, a corpus from video's ``quality``, ...)
_VALUE_COLUMNS = ("utt_id", "speaker", "expression", "text", "n_frames", "fps", "sample_rate",
                  "voice")
_HASHED = ("audio", "markers", "phones")  # what corpus_hash reads besides the manifest
INFO = "corpus.json"
MANIFEST = "manifest.csv"

_checked: dict = {}  # (folder, signature) -> what check_source found


def source_folder(cfg) -> Path:
    """The given corpus folder of ``cfg`` (``corpus.source``), as an absolute path."""
    return Path(cfg.corpus.source).expanduser().absolute()


def _refuse(src: Path, problem: str, setting: str = "corpus.source") -> CorpusError:
    return CorpusError(f"{setting} {src}: {problem}")


def corpus_files(root: Path) -> list[Path]:
    """The files of the corpus at ``root`` that the run takes, relative to it: ``manifest.csv``,
    ``corpus.json`` (when there is one), every file the manifest names and each utterance's
    word times (``words/<utt_id>.csv``) when there are some.

    Raises
    ------
    CorpusError
        A manifest cell names a path outside the corpus folder.
    """
    rows = read_manifest(root / MANIFEST, ("utt_id",))
    out = [Path(MANIFEST)] + ([Path(INFO)] if (root / INFO).is_file() else [])
    inside = root.resolve()
    for line, row in enumerate(rows, start=2):
        for column, value in row.items():
            if column in _VALUE_COLUMNS or not value or column is None:
                continue
            rel = Path(value)
            if not (root / rel).is_file():
                continue  # not a file name (the reader refuses a missing audio, markers, phones)
            if rel.is_absolute() or not (root / rel).resolve().is_relative_to(inside):
                raise CorpusError(f"{root / MANIFEST}, line {line}: {column} {value!r} is "
                                  "outside the corpus folder; allowed: paths relative to it, "
                                  "inside it")
            out.append(rel)
        words = Path("words") / f"{row['utt_id']}.csv"
        if (root / words).is_file():
            out.append(words)
    return list(dict.fromkeys(out))


def _signature(root: Path) -> tuple | None:
    """Size, modification time and inode of every file the run takes (None: unreadable; the
    reader then says why)."""
    try:
        return tuple((str(rel), st.st_size, st.st_mtime_ns, st.st_ino)
                     for rel in corpus_files(root) for st in [(root / rel).stat()])
    except (OSError, CorpusError):
        return None


def check_source(cfg) -> dict:
    """:func:`check_folder` of the given corpus of ``cfg`` (``corpus.source``)."""
    return check_folder(source_folder(cfg), "corpus.source",
                        also="or empty to synthesise the corpus")


def check_folder(src: Path, setting: str, *, also: str = "") -> dict:
    """Validate the corpus folder ``src``, which the config setting ``setting`` names, with
    :func:`face_model.corpus.load_corpus` and sum it up: ``corpus_hash``, ``other_files`` (the
    hash of the files ``corpus_hash`` does not read), ``expressions`` (with utterances, in
    manifest order), ``n_utterances``. Read once per process while its files are unchanged
    (a real speaker's corpus is checked before a run starts, then taken by its nested run).
    ``also``: what else the setting allows, for the message of a folder not found.

    Raises
    ------
    CorpusError
        One line naming the setting, the folder and the problem: not found, not a folder, or
        the reader's refusal (naming the file).
    """
    src = Path(src).expanduser().absolute()
    if not src.exists():
        raise _refuse(src, "folder not found; allowed: a corpus folder (manifest.csv, audio/, "
                           "markers/, phones/)" + (f" {also}" if also else ""), setting)
    if not src.is_dir():
        raise _refuse(src, "is a file; allowed: a corpus folder (manifest.csv, audio/, "
                           "markers/, phones/)", setting)
    sig = _signature(src)
    found = _checked.get((src.resolve(), sig)) if sig is not None else None
    if found is None:
        try:
            corpus = load_corpus(src)
            corpus_files(src)
        except CorpusError as exc:
            raise _refuse(src, f"not a valid corpus: {exc}", setting) from None
        expressions = list(dict.fromkeys(u.expression for u in corpus.utterances))
        found = {"corpus_hash": corpus_hash(src), "other_files": _other_files_hash(src),
                 "expressions": expressions, "n_utterances": len(corpus)}
        del corpus
        if sig is not None and _signature(src) == sig:  # unchanged while it was read
            _checked[(src.resolve(), sig)] = found
    return dict(found)


def _other_files_hash(root: Path) -> str:
    """SHA-256 over the names and contents of the files the run takes that
    :func:`face_model.corpus.corpus_hash` does not read (``corpus.json``, ``quality/`` files,
    ...), in the order of :func:`corpus_files`."""
    hashed = {Path(r[k]) for r in read_manifest(root / MANIFEST, ("utt_id",)) for k in _HASHED
              if r.get(k)}
    h = hashlib.sha256()
    for rel in corpus_files(root):
        if rel != Path(MANIFEST) and rel not in hashed:
            h.update(str(rel).encode() + b"\0" + (root / rel).read_bytes())
    return h.hexdigest()


def corpus_config(cfg) -> tuple:
    """The config keys the corpus depends on: ``corpus.source`` for a given corpus, else the
    seed and the synthesis settings."""
    return ("corpus.source",) if given(cfg) else ("seed", "synth")


def corpus_inputs(paths: RunPaths, cfg) -> dict:
    """The corpus stage's inputs outside the run (:class:`talkingface.stages.base.Stage`):
    a given corpus's ``corpus_hash`` and the hash of its other files (``corpus.json``,
    ``quality/``), validating it; nothing for a synthesised one."""
    if not given(cfg):
        return {}
    found = check_source(cfg)
    return {"corpus_hash": found["corpus_hash"], "other_files": found["other_files"]}


def link_or_copy(src: Path, dst: Path) -> bool:
    """``dst`` as a hard link to ``src``, or a copy where a link cannot be made (another file
    system, links not supported or not allowed). Returns whether it is a link."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
        return True
    except OSError:
        shutil.copy2(src, dst)
        return False


def take_given_corpus(paths: RunPaths, cfg) -> dict:
    """The given corpus of ``cfg`` validated and linked (or copied) into the run's corpus
    folder; returns what ``done.json`` records: ``source`` (the folder), ``corpus_hash``,
    ``expressions``, ``n_utterances``, ``linked`` and ``copied`` (files) and, when the corpus
    lacks smile or sad, the ``note`` of what is skipped.

    Raises
    ------
    CorpusError
        As :func:`check_source`; or the source changed while it was being copied.
    """
    src = source_folder(cfg)
    found = check_source(cfg)
    before = _signature(src)
    linked = copied = 0
    for rel in corpus_files(src):
        if link_or_copy(src / rel, paths.corpus / rel):
            linked += 1
        else:
            copied += 1
    if _signature(src) != before:
        raise _refuse(src, "changed while it was being copied; run the command again when "
                           "nothing writes to it")
    record = {"source": str(src), **found, "linked": linked, "copied": copied}
    note = expression_note(found["expressions"])
    if note:
        record["note"] = note
    return record


def combine_corpora(parts: list, dst: Path) -> Path:
    """A corpus folder ``dst`` of the rows of several corpora: ``parts`` is a list of
    ``(source folder, utterance ids to keep or None for all, subfolder)``; each kept row's files
    are hard-linked (:func:`link_or_copy`) under ``dst/<subfolder>/`` (its file cells prefixed
    so; ``""``: ``dst`` itself), the rows listed in ``parts``' order under the union of their columns (empty where a
    part has none), ``corpus.json`` says where each part came from (``parts``: its folder, its
    source and its own ``corpus.json``, or None, so that a reader of speakers applies each
    part's rule: :func:`analysis.speech_eval.training_speakers`) and carries the first part's
    licence, a part's ``NOTICE.md`` is kept as ``<subfolder>/NOTICE.md``. The
    manifest is written last, so a folder with one is complete (a resumed build keeps it).

    Raises
    ------
    CorpusError
        Two parts list the same utterance id.
    """
    dst = Path(dst)
    if (dst / MANIFEST).is_file():
        return dst
    fields, rows, seen, info = [], [], set(), {"parts": []}
    for src, keep, sub in parts:
        src = Path(src)
        with open(src / MANIFEST, newline="", encoding="utf-8-sig") as f:
            reader = csv.DictReader(f)
            fields += [c for c in reader.fieldnames if c not in fields]
            part = [r for r in reader if keep is None or r["utt_id"] in keep]
        for row in part:
            if row["utt_id"] in seen:
                raise CorpusError(f"{src / MANIFEST}: utterance {row['utt_id']!r} is in two "
                                  "of the corpora combined into " + str(dst))
            seen.add(row["utt_id"])
            for column, cell in row.items():
                if column not in _VALUE_COLUMNS and cell and (src / cell).is_file():
                    link_or_copy(src / cell, dst / sub / cell)
                    row[column] = f"{sub}/{cell}" if sub else cell
        rows += part
        src_info = json.loads((src / INFO).read_text(encoding="utf-8")) \
            if (src / INFO).is_file() else None
        info["parts"].append({"folder": sub, "source": str(src.resolve()),
                              "utterances": len(part), "info": src_info})
        info.setdefault("licence", (src_info or {}).get("licence", ""))
        if (src / "NOTICE.md").is_file():
            link_or_copy(src / "NOTICE.md", dst / sub / "NOTICE.md")
    (dst / INFO).write_text(json.dumps(info, indent=1) + "\n", encoding="utf-8")
    with atomic_file(dst / MANIFEST) as tmp, open(tmp, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=fields, restval="")
        writer.writeheader()
        writer.writerows(rows)
    return dst
