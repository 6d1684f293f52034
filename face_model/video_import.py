"""The whole import of a folder of videos into a corpus (:mod:`face_model.video_corpus` does
one clip): landmarks in parallel worker processes, then the clips' utterances in parallel
processes, a progress bar on each, a partial folder that resumes, and the corpus renamed into
place only once the corpus reader has passed it.

Nothing the user has is lost: the sources are checked before any work (:func:`check_sources`:
videos only, one clip per name), and the landmark files kept with ``keep_landmarks`` never
replace a file the import did not write (:func:`check_keep_landmarks` before any work, and an
exclusive move at the end).
"""
from __future__ import annotations

import csv
import json
import multiprocessing
import os
import shutil
from dataclasses import asdict
from pathlib import Path

import numpy as np
from tqdm import tqdm

from face_model.corpus import WORDS_DIR, load_corpus, words_path, write_manifest
from face_model.landmarks import MARKER_LANDMARKS, extract_landmarks
from face_model.layout import LAYOUT_VERSION
from face_model.transcripts import find_transcript, read_transcript_csv
from face_model.video_corpus import (ADMISSION_RULES, VIDEO_EXTENSIONS, FromVideoSettings,
                                     find_videos, make_utterance)
from groundwork.atomic import fresh_partial_folder, swap_in
from groundwork.errors import CorpusError, ParameterError, TalkingFaceError

JOB_FILE = "import.json"
LANDMARK_DIR = ".landmarks"
AUDIO_EXTENSIONS = (".wav", ".flac", ".mp3", ".ogg", ".oga", ".opus", ".m4a", ".aac", ".aif",
                    ".aiff", ".wma")
SPEECH_COMMANDS = ("for speech alone use `talkingface animate` (a face from a WAV file) or "
                   "`talkingface evaluate-speech`")
_SHOWN = 3  # clashing files named in a message
EVEN_WORDS = ("the aligner found no path within the word's interval (too short: fewer than "
              "three 10 ms frames per phone), so the word's dictionary phones divide it evenly")


def check_sources(src) -> list[Path]:
    """The videos of ``src`` (:func:`face_model.video_corpus.find_videos`), checked before any
    work: a file must have a video extension (an audio file is told so), a folder without videos
    but with audio files is told so, and no two videos may share a clip name (the file name
    without its extension: ``clip.mpg`` and ``clip.mp4`` would be one utterance).

    Parameters
    ----------
    src : path-like
        A video, or a folder of videos.

    Returns
    -------
    list of pathlib.Path
        The videos, sorted.

    Raises
    ------
    ParameterError
        One line naming the file(s) and what is allowed.
    """
    src = Path(src)
    allowed = f"allowed extensions: {' '.join(VIDEO_EXTENSIONS)}"
    if src.is_file() and src.suffix.lower() not in VIDEO_EXTENSIONS:
        if src.suffix.lower() in AUDIO_EXTENSIONS:
            raise ParameterError(f"{src} is audio, not a video ({allowed}); {SPEECH_COMMANDS}")
        raise ParameterError(f"{src} is not a video ({allowed})")
    if src.is_dir() and not any(p.suffix.lower() in VIDEO_EXTENSIONS for p in src.iterdir()
                                if p.is_file()):
        audio = sorted(p.name for p in src.iterdir()
                       if p.is_file() and p.suffix.lower() in AUDIO_EXTENSIONS)
        if audio:
            shown = ", ".join(audio[:_SHOWN]) + (", ..." if len(audio) > _SHOWN else "")
            raise ParameterError(f"{src}: no videos in this folder, only audio files ({shown}; "
                                 f"{allowed}); {SPEECH_COMMANDS}")
    videos = find_videos(src)
    by_name: dict = {}
    for v in videos:
        by_name.setdefault(v.stem, []).append(v)
    same = [group for group in by_name.values() if len(group) > 1]
    if same:
        more = f" (and {len(same) - 1} more names like it)" if len(same) > 1 else ""
        count = "two" if len(same[0]) == 2 else str(len(same[0]))
        raise ParameterError(f"{' and '.join(map(str, same[0]))} are {count} clips named "
                             f"'{same[0][0].stem}'{more}; a clip's name (its file name without "
                             "the extension) must be unique in a folder: rename or move one")
    return videos


def check_keep_landmarks(folder, videos: list) -> Path | None:
    """Refuse, before any work, a ``keep_landmarks`` folder that is a file or holds a landmark
    file of one of ``videos`` (``<clip>.npz``: clip names such as GRID's repeat across
    speakers); the folder itself may exist."""
    if folder is None:
        return None
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ParameterError(f"--keep-landmarks {folder} is a file; give a folder")
    clash = [f"{v.stem}.npz" for v in videos if os.path.lexists(folder / f"{v.stem}.npz")]
    if clash:
        raise ParameterError(_clash_message(folder, clash, len(videos)))
    return folder


def _clash_message(folder: Path, clash: list, total: int) -> str:
    shown = ", ".join(clash[:_SHOWN]) + (", ..." if len(clash) > _SHOWN else "")
    return (f"--keep-landmarks {folder} already holds {len(clash)} of this import's {total} "
            f"landmark files ({shown}), another import's; give a folder of its own (nothing "
            "is replaced)")


def keep_landmark_files(files: list, folder) -> None:
    """Move ``files`` into ``folder`` without replacing anything: each is created there
    exclusively (a hard link, or a copy across file systems); if one of the names has appeared
    meanwhile, the files placed by this call are removed again and the move refused.

    Raises
    ------
    ParameterError
        A name is taken in ``folder``; ``files`` are left where they were.
    """
    folder = Path(folder)
    made_folder = not folder.exists()
    folder.mkdir(parents=True, exist_ok=True)
    placed = []
    try:
        for f in files:
            _place_new(Path(f), folder / Path(f).name)
            placed.append(folder / Path(f).name)
    except FileExistsError:
        for p in placed:
            p.unlink()
        if made_folder and not any(folder.iterdir()):
            folder.rmdir()
        clash = [Path(f).name for f in files if os.path.lexists(folder / Path(f).name)]
        raise ParameterError(_clash_message(folder, clash, len(files))) from None
    for f in files:
        Path(f).unlink()


def _place_new(src: Path, dst: Path) -> None:
    """``src``'s contents under the new name ``dst`` (FileExistsError when ``dst`` exists)."""
    try:
        os.link(src, dst)
        return
    except FileExistsError:
        raise
    except OSError:  # another file system, or one without hard links
        pass
    with open(src, "rb") as r, open(dst, "xb") as w:
        try:
            shutil.copyfileobj(r, w)
        except BaseException:
            w.close()
            dst.unlink()
            raise


def _job(src: Path, videos: list, settings: FromVideoSettings, transcripts) -> dict:
    return {"source": str(src.resolve()), "videos": [v.name for v in videos],
            "settings": asdict(settings), "transcripts": str(transcripts or "")}


def _keep_partial(job: dict):
    def keep(partial: Path) -> bool:
        try:
            return json.loads((partial / JOB_FILE).read_text()) == job
        except (OSError, ValueError):
            return False
    return keep


def _clip_task(args):
    video, landmark_file, transcript, root, settings = args
    try:
        return make_utterance(video, landmark_file, transcript, root, settings), None
    except TalkingFaceError as exc:
        return None, (video.stem, str(exc))


def _bar(total: int, desc: str, progress: bool):
    return tqdm(total=total, desc=desc, unit="clip", disable=not progress, leave=False)


def corpus_from_video(src, out, *, settings: FromVideoSettings | None = None,
                      transcripts=None, workers: int = 2, licence: str = "",
                      progress: bool = True, keep_landmarks=None, source: str = "") -> dict:
    """Make a corpus at ``out`` from the videos of ``src``.

    Parameters
    ----------
    src : path-like
        A video, or a folder of them.
    out : path-like
        The corpus folder to make; it must not exist.
    settings : FromVideoSettings, optional
    transcripts : path-like, optional
        A CSV with columns ``clip,text``; without it each clip's transcript is its ``.align`` or
        ``.txt`` file, beside it or in an ``align/`` folder beside its folder (GRID's layout).
    workers : int
        Landmark workers and clip processes at once.
    licence : str
        The source's licence and attribution, kept in ``corpus.json``.
    progress : bool
        Show progress bars.
    keep_landmarks : path-like, optional
        Move the landmark files (one ``.npz`` per clip) to this folder afterwards.
    source : str
        Where the videos came from, for ``corpus.json`` (default: ``src``'s full path).

    Returns
    -------
    dict
        ``{"utterances", "refused": [(clip, reason)], "frames", "corpus": out}``. The corpus's
        ``corpus.json`` names the rule that admitted each clip (``admitted_by``: clip → rule;
        ``admission_rules``: each rule used, described; see
        :data:`face_model.video_corpus.ADMISSION_RULES`), and, when any, the words whose
        phones divide their interval evenly (``words_divided_evenly``).

    Raises
    ------
    ParameterError, CorpusError
        Bad arguments, no videos (:func:`check_sources`), ``out`` exists, ``keep_landmarks``
        holds a landmark file of one of the clips, or every clip refused (the first reason);
        nothing is written.
    """
    src, out = Path(src), Path(out)
    settings = (settings or FromVideoSettings()).check()
    videos = check_sources(src)
    if out.exists():
        raise ParameterError(f"{out} already exists; give a new --out folder (nothing is "
                             "overwritten)")
    if workers < 1:
        raise ParameterError(f"workers {workers}; allowed: 1 or more")
    keep_landmarks = check_keep_landmarks(keep_landmarks, videos)
    table = read_transcript_csv(transcripts) if transcripts else None
    texts = {}
    for v in videos:
        t = find_transcript(v, csv_map=table)
        if t is None:
            raise CorpusError(f"{v}: no transcript (a {v.stem}.align or {v.stem}.txt beside it "
                              "or in an align/ folder beside its folder, or a row of --transcripts "
                              "CSV)")
        texts[v] = t
    out.parent.mkdir(parents=True, exist_ok=True)
    job = _job(src, videos, settings, transcripts)
    partial = fresh_partial_folder(out, keep=_keep_partial(job))
    (partial / JOB_FILE).write_text(json.dumps(job, indent=1))
    lm_dir = partial / LANDMARK_DIR
    lm_dir.mkdir(exist_ok=True)
    jobs = [(v, lm_dir / f"{v.stem}.npz") for v in videos]
    with _bar(len(jobs), "landmarks", progress) as bar:
        replies = extract_landmarks(jobs, workers=workers, progress=bar.update)
    refused, tasks = [], []
    for v, lm_file in jobs:
        reply = replies[str(v)]
        if "error" in reply:
            refused.append((v.stem, reply["error"]))  # the worker names the file
            continue
        tasks.append((v, lm_file, texts[v], partial, settings))
    rows = []
    with _bar(len(tasks), "utterances", progress and bool(tasks)) as bar:
        ctx = multiprocessing.get_context("fork")
        with ctx.Pool(max(1, min(workers, len(tasks) or 1))) as pool:
            for row, refusal in pool.imap(_clip_task, tasks):
                if row:
                    rows.append(row)
                else:
                    refused.append(refusal)
                bar.update()
    if not rows:
        shutil.rmtree(partial, ignore_errors=True)
        first = refused[0][1] if refused else f"{src}: no clip could be imported"
        more = f" (and {len(refused) - 1} more clips refused)" if len(refused) > 1 else ""
        raise CorpusError(first + more)
    rows.sort(key=lambda r: r["utt_id"])
    write_manifest(partial, rows)
    _write_refusals(partial, refused, videos[0].parent)
    info = {"source": source or str(src.resolve()), "made_by": "talkingface corpus from-video",
            "detector": _detector(lm_dir, rows), "marker_correspondence":
            "face_model.landmarks.MARKER_LANDMARKS (tools/marker_correspondence.py)",
            "marker_layout_version": LAYOUT_VERSION, "licence": licence,
            "settings": asdict(settings), "clips": len(videos), "utterances": len(rows),
            "refused": len(refused), "expressions": sorted({r["expression"] for r in rows}),
            "correspondence_landmarks": {str(k): list(v[0]) for k, v in
                                         MARKER_LANDMARKS.items()}}
    rules = sorted({r["admitted_by"] for r in rows})
    info["admission_rules"] = {rule: ADMISSION_RULES[rule] for rule in rules}
    info["admitted_by"] = {r["utt_id"]: r["admitted_by"] for r in rows}
    even = {r["utt_id"]: r["even_words"] for r in rows if r["even_words"]}
    if even:
        info["words_divided_evenly"] = {"why": EVEN_WORDS, "clips": even}
    timed = sum(words_path(partial, r["utt_id"]).is_file() for r in rows)
    if timed:
        info["words"] = words_info(timed, "the clips' .align word times")
    (partial / "corpus.json").write_text(json.dumps(info, indent=1) + "\n")
    corpus = load_corpus(partial)
    if keep_landmarks:  # refused: the partial folder stays, and a new run resumes from it
        keep_landmark_files([f for _, f in jobs if f.is_file()], keep_landmarks)
    shutil.rmtree(lm_dir)
    (partial / JOB_FILE).unlink()
    swap_in(partial, out)
    return {"utterances": len(rows), "refused": refused, "frames": corpus.n_frames,
            "corpus": out}


def words_info(n: int, source: str) -> dict:
    """``corpus.json``'s ``words`` entry: ``n`` utterances keep their words' times, from
    ``source``, in ``words/<utt_id>.csv``."""
    return {"utterances": n, "files": f"{WORDS_DIR}/<utt_id>.csv (start_s,end_s,word; "
            "seconds; silences sil/sp left out)", "source": source}


def _detector(lm_dir: Path, rows: list) -> str:
    with np.load(lm_dir / f"{rows[0]['utt_id']}.npz") as d:
        return str(d["detector"])


def _write_refusals(root: Path, refused: list, folder: Path) -> None:
    """``refused.csv``: each refused clip and why (its file named within the source folder)."""
    if not refused:
        return
    refused = [(clip, reason.replace(f"{folder}/", "")) for clip, reason in refused]
    with open(root / "refused.csv", "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["clip", "reason"])
        w.writerows(sorted(refused))
