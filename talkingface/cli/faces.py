"""Real faces from video: ``talkingface corpus from-video`` and ``talkingface evaluate-face``.

    talkingface corpus from-video SRC --out DIR [--speaker S] [--transcripts CSV] [--workers N]
    talkingface evaluate-face [--model M] VIDEOS [--out DIR] [--overwrite] [--speaker S]
                              [--workers N] [--side-by-side DIR]

Both read video through MediaPipe Face Mesh in the face environment (``bash tools/setup.sh
face``; :mod:`face_model.landmarks`). ``evaluate-face`` also takes a corpus folder (one made
by ``corpus from-video``, whose markers need no decoding). Its results folder
(:data:`EVAL_FILES`) is by default ``face_eval/<source>-<8 hex digits of the source's full
path>`` beside the model (:func:`default_eval_folder`: never another source's); an existing
one is replaced only with ``--overwrite``, and then at once (built beside it, swapped in).
``--side-by-side DIR`` (videos only) also writes one MP4 per clip into ``DIR``: the video with
its tracked markers | the markers predicted from its audio | the model's animated face, with the
clip's audio (:mod:`talkingface.stages.side_by_side`); a ``DIR`` holding files is refused unless
``--overwrite`` (then only its ``.mp4`` files may be there, and a clip's video is replaced).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import re
import shutil
from pathlib import Path

from tqdm import tqdm

from analysis.face_eval import opening_strip_figure, write_scores_csv
from face_model.alignment import align_markers
from face_model.video_corpus import FromVideoSettings, default_speaker
from face_model.video_import import check_sources, corpus_from_video
from groundwork.atomic import fresh_partial_folder, swap_in
from groundwork.errors import ParameterError
from talkingface.stages.side_by_side import alignment_of, write_side_by_side
from talkingface.stages.face_scoring import (clips_from_corpus, clips_from_videos,
                                             model_neutrals, score_model)
from talkingface.stages.models import load_animator


def cmd_from_video(args) -> int:
    settings = FromVideoSettings(sample_rate=args.sample_rate, speaker=args.speaker
                                 or default_speaker(args.src), expression=args.expression,
                                 max_missing_fraction=args.max_missing,
                                 max_gap_s=args.max_gap, audio_format=args.audio_format)
    res = corpus_from_video(args.src, args.out, settings=settings,
                            transcripts=args.transcripts, workers=args.workers,
                            licence=args.licence, keep_landmarks=args.keep_landmarks)
    for clip, reason in res["refused"]:
        print(f"refused {clip}: {reason}")
    print(f"{res['corpus']}: {res['utterances']} utterances ({res['frames']} frames at 30 fps), "
          f"{len(res['refused'])} clips refused")
    return 0


def _model_corpus(tfmap: Path) -> Path | None:
    """The corpus folder of the run a model file belongs to, when there is one."""
    for parent in tfmap.parents:
        if (parent / "corpus" / "manifest.csv").is_file():
            return parent / "corpus"
    return None


EVAL_FILES = ("per_clip.csv", "scores.json", "opening_*.png")  # what evaluate-face writes


def default_eval_folder(tfmap, src) -> Path:
    """``face_eval/<name>`` beside the model file ``tfmap`` for the source ``src``: the name is
    the source's folder and name (``s1-video`` for ``.../s1/video``) and 8 hex digits of its
    full resolved path, so two sources never share a folder (every GRID speaker's folder is
    named ``video``) and one source always gets the same one."""
    path = Path(src).resolve()
    readable = re.sub(r"[^A-Za-z0-9._-]+", "_", f"{path.parent.name}-{path.name}").strip("._-")
    digest = hashlib.sha256(str(path).encode()).hexdigest()[:8]
    return Path(tfmap).parent / "face_eval" / f"{readable or 'source'}-{digest}"


def _evaluation_source(folder: Path) -> str | None:
    """The full path of the source an evaluation folder scored (None: not an evaluation's
    folder, i.e. it holds files other than :data:`EVAL_FILES`)."""
    entries = list(folder.iterdir())
    if not all(e.is_file() and any(e.match(pat) for pat in EVAL_FILES) for e in entries):
        return None
    try:
        record = json.loads((folder / "scores.json").read_text(encoding="utf-8"))
        return str(record.get("source_path") or record["source"])
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return "an unknown source"


def check_eval_folder(out: Path, src: Path, *, overwrite: bool, default: bool) -> Path:
    """Refuse, before any work, a results folder that is a file, holds an earlier evaluation
    (unless ``overwrite``), holds files that are not an evaluation's, or (the default folder)
    holds another source's evaluation."""
    what = "the default results folder" if default else "--out"
    if out.exists() and not out.is_dir():
        raise ParameterError(f"{what} {out} is a file; give a folder")
    if not out.is_dir() or not any(out.iterdir()):
        return out
    source = _evaluation_source(out)
    if source is None:
        raise ParameterError(f"{what} {out} holds files that are not an evaluation's; give "
                             "another --out (nothing is replaced)")
    if default and source != str(src.resolve()):
        raise ParameterError(f"{what} {out} holds an evaluation of {source}; give --out")
    if not overwrite:
        raise ParameterError(f"{what} {out} already holds an evaluation (of {source}); pass "
                             "--overwrite to replace it, or another --out")
    return out


def check_side_by_side(folder: Path, src: Path, *, corpus: bool, overwrite: bool) -> Path:
    """Refuse, before any work, ``--side-by-side`` with a corpus folder (no video to show), a
    folder that is a file, or one that holds files (unless ``overwrite``, and then only
    ``.mp4`` files: a clip's video is replaced, nothing else is touched)."""
    if corpus:
        raise ParameterError(f"--side-by-side {folder}: {src} is a corpus folder (markers, no "
                             "video); give the folder of videos it was made from")
    if folder.exists() and not folder.is_dir():
        raise ParameterError(f"--side-by-side {folder} is a file; give a folder")
    entries = list(folder.iterdir()) if folder.is_dir() else []
    if entries and not overwrite:
        raise ParameterError(f"--side-by-side {folder} already holds files; pass --overwrite "
                             "to replace its videos, or give another folder")
    if any(not (e.is_file() and e.suffix == ".mp4") for e in entries):
        raise ParameterError(f"--side-by-side {folder} holds files that are not videos (.mp4); "
                             "give another folder (nothing is replaced)")
    return folder


def write_side_by_sides(folder: Path, animator, clips: list, videos: list, training) -> list:
    """One side-by-side MP4 per clip in ``folder`` (``<clip>.mp4``), with the neutral faces
    the scores use (:func:`talkingface.stages.face_scoring.model_neutrals`)."""
    by_stem = {v.stem: v for v in videos}
    aligned = {c.clip: align_markers(c.markers, model=alignment_of(animator)) for c in clips}
    neutrals, _ = model_neutrals(animator, clips, aligned, training)
    written = []
    for c in tqdm(clips, desc="side by side", unit="clip", leave=False):
        written.append(write_side_by_side(folder / f"{c.clip}.mp4", by_stem[c.clip], c,
                                          animator, neutrals[c.speaker], progress=False))
    return written


def cmd_evaluate_face(args) -> int:
    """Score a model on real clips by the rules of :mod:`analysis.face_eval`: speech frames from
    the corpus's phones, or, for videos, from each clip's transcript forced-aligned (a clip
    without one is scored on all its valid frames, and the command says so)."""
    src = Path(args.videos)
    corpus = (src / "manifest.csv").is_file()
    if not corpus:
        check_sources(src)
    if args.out:
        check_eval_folder(Path(args.out), src, overwrite=args.overwrite, default=False)
    side = args.side_by_side
    if side is not None:
        check_side_by_side(side, src, corpus=corpus, overwrite=args.overwrite)
    animator, tfmap = load_animator(args.model, args.runs_dir)
    out = Path(args.out) if args.out else default_eval_folder(tfmap, src)
    if not args.out:
        check_eval_folder(out, src, overwrite=args.overwrite, default=True)
    if side is not None and out.resolve() in (side.resolve(), *side.resolve().parents):
        raise ParameterError(f"--side-by-side {side} is in the results folder {out}; give "
                             "another folder")
    if corpus:
        clips, refused, unaligned = clips_from_corpus(src), [], []
    else:
        clips, refused, unaligned = clips_from_videos(
            src, speaker=args.speaker or default_speaker(src), workers=args.workers)
    training = _model_corpus(Path(tfmap))
    scores = score_model(animator, clips, training_corpus=training, progress=True)
    record = {"model": str(tfmap), "source": str(src), "source_path": str(src.resolve()),
              "refused": refused, "no_speech_frames": unaligned, **scores.to_dict()}
    first = scores.tracks[0]
    figure = f"opening_{first.clip}.png"
    partial = fresh_partial_folder(out)
    try:
        write_scores_csv(scores, partial / "per_clip.csv")
        (partial / "scores.json").write_text(json.dumps(record, indent=1) + "\n")
        opening_strip_figure(first, partial / figure,
                             f"{first.clip}: real vs predicted inner-lip opening")
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    swap_in(partial, out)
    videos = ([] if side is None else
              write_side_by_sides(side, animator, clips, check_sources(src), training))
    p = scores.pooled
    for clip, reason in refused:
        print(f"refused {clip}: {reason}")
    for clip, reason in unaligned:
        print(f"no speech frames for {clip} ({reason}): all its valid frames scored")
    part = "speech frames" if p["speech_known"] else "all valid frames (speech frames unknown)"
    lve = f"; LVE {p['lve_px']:.2f} px" if p.get("lve_clips") else ""
    closures = (f"; /p b m/ closed {p['closures_hit']}/{p['bilabial_segments']} "
                f"({100 * p['closure_rate']:.0f} %, chance {100 * p['chance_closure_rate']:.0f} "
                f"%), false closures {100 * p['false_closure_rate']:.0f} % (chance "
                f"{100 * p['chance_false_closure_rate']:.0f} %)"
                if p["bilabial_segments"] and p["control_segments"] else "")
    print(f"{p['clips']} clips, {p['speakers']} speaker(s), {p['valid_frames']} valid frames "
          f"({p['excluded_frames']} without a face excluded): inner-lip opening r "
          f"{p['r_speech']:.3f} over {part} (chance {p['chance_r_speech']:.3f}; median per "
          f"clip {p['r_clip_median']:.3f}; interval {p['interval_r_speech']}){closures}{lve}\n"
          f"results: {out}/ (per_clip.csv, scores.json, {figure})")
    if side is not None:
        print(f"side by side: {side}/ ({len(videos)} videos: real + tracked | predicted from "
              "audio | animated face)")
    return 0


def _positive(value: str) -> int:
    """A count of 1 or more, for argparse (which shows the message of an ArgumentTypeError
    only: ``error: argument --workers: 0; allowed: ...``)."""
    try:
        n = int(value)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"{value}; allowed: a whole number, 1 or more")
    return n


def add_parser(sub) -> None:
    c = sub.add_parser("corpus", help="make a corpus from something other than the generator")
    csub = c.add_subparsers(dest="corpus_command", required=True)
    s = csub.add_parser("from-video", help="a corpus from talking-face videos with audio "
                        "(MediaPipe landmarks → the 79 markers, phones by forced alignment)")
    s.add_argument("src", type=Path, help="a video, or a folder of videos")
    s.add_argument("--out", required=True, type=Path, help="corpus folder to create (must not "
                   "exist)")
    s.add_argument("--speaker", help="speaker name (default: the videos' folder, or its "
                   "parent for a folder named video)")
    s.add_argument("--expression", default="neutral", choices=("neutral", "smile", "sad"),
                   help="the expression of every clip (default: neutral)")
    s.add_argument("--transcripts", type=Path, help="CSV with columns clip,text (default: each "
                   "clip's .align or .txt beside it or in an align/ folder beside its folder)")
    s.add_argument("--workers", type=_positive, default=2, help="processes (default: 2)")
    s.add_argument("--sample-rate", type=int, default=22050, help="corpus audio rate, Hz")
    s.add_argument("--max-missing", type=float, default=0.10, help="refuse a clip with more "
                   "of its frames than this without a face (default: 0.10)")
    s.add_argument("--max-gap", type=float, default=0.20, help="refuse a clip with a longer "
                   "run of frames without a face, seconds (default: 0.20)")
    s.add_argument("--audio-format", default="wav", choices=("wav", "flac"))
    s.add_argument("--licence", default="", help="the videos' licence and attribution, kept "
                   "in corpus.json")
    s.add_argument("--keep-landmarks", type=Path, help="keep the raw landmarks (one .npz per "
                   "clip) in this folder (refused if it holds one of those names already)")
    s.set_defaults(func=cmd_from_video)

    s = sub.add_parser("evaluate-face", help="score a model's lips against real talking-face "
                       "videos (inner-lip opening r, closures, LVE on its own speaker)")
    s.add_argument("videos", type=Path, help="a video, a folder of videos, or a corpus folder")
    s.add_argument("--model", help="a run name, run folder or .tfmap (default: the latest "
                   "run's voice-robust model)")
    s.add_argument("--runs-dir", type=Path, default=Path("runs"))
    s.add_argument("--speaker", help="the videos' speaker (default: their folder's name)")
    s.add_argument("--out", type=Path, help="results folder: per_clip.csv, scores.json, "
                   "opening_<clip>.png (default: face_eval/<source>-<hash of its path> beside "
                   "the model)")
    s.add_argument("--overwrite", action="store_true", help="replace an earlier evaluation in "
                   "that folder (and the clips' videos in --side-by-side's)")
    s.add_argument("--workers", type=_positive, default=2)
    s.add_argument("--side-by-side", type=Path, metavar="DIR", help="also write one MP4 per "
                   "clip into DIR: the video with its tracked markers | the markers predicted "
                   "from its audio | the animated face, with the clip's audio (videos only)")
    s.set_defaults(func=cmd_evaluate_face)
