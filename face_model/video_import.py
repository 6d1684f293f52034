"""The whole import of a folder of videos into a corpus (:mod:`face_model.video_corpus` does
one clip): landmarks in parallel worker processes, then the clips' utterances in parallel
processes, a progress bar on each, a partial folder that resumes, and the corpus renamed into
place only once the corpus reader has passed it.
"""
from __future__ import annotations

import csv
import json
import multiprocessing
import shutil
from dataclasses import asdict
from pathlib import Path

import numpy as np
from tqdm import tqdm

from face_model.corpus import load_corpus, write_manifest
from face_model.landmarks import MARKER_LANDMARKS, extract_landmarks
from face_model.layout import LAYOUT_VERSION
from face_model.transcripts import find_transcript, read_transcript_csv
from face_model.video_corpus import ClipRefused, FromVideoSettings, find_videos, make_utterance
from groundwork.atomic import fresh_partial_folder, swap_in
from groundwork.errors import CorpusError, ParameterError, TalkingFaceError

JOB_FILE = "import.json"
LANDMARK_DIR = ".landmarks"


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
        ``{"utterances", "refused": [(clip, reason)], "frames", "corpus": out}``.

    Raises
    ------
    ParameterError, CorpusError
        Bad arguments, no videos, ``out`` exists, or every clip refused (the first reason);
        nothing is written.
    """
    src, out = Path(src), Path(out)
    settings = (settings or FromVideoSettings()).check()
    videos = find_videos(src)
    if out.exists():
        raise ParameterError(f"{out} already exists; give a new --out folder (nothing is "
                             "overwritten)")
    if workers < 1:
        raise ParameterError(f"workers {workers}; allowed: 1 or more")
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
    (partial / "corpus.json").write_text(json.dumps(info, indent=1) + "\n")
    if keep_landmarks:
        Path(keep_landmarks).mkdir(parents=True, exist_ok=True)
        for f in lm_dir.glob("*.npz"):
            shutil.move(str(f), Path(keep_landmarks) / f.name)
    shutil.rmtree(lm_dir)
    (partial / JOB_FILE).unlink()
    corpus = load_corpus(partial)
    swap_in(partial, out)
    return {"utterances": len(rows), "refused": refused, "frames": corpus.n_frames,
            "corpus": out}


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
