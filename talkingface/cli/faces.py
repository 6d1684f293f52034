"""Real faces from video: ``talkingface corpus from-video`` and ``talkingface evaluate-face``.

    talkingface corpus from-video SRC --out DIR [--speaker S] [--transcripts CSV] [--workers N]
    talkingface evaluate-face [--model M] VIDEOS [--out DIR] [--speaker S] [--workers N]

Both read video through MediaPipe Face Mesh in the face environment (``bash tools/setup.sh
face``; :mod:`face_model.landmarks`). ``evaluate-face`` also takes a corpus folder (one made
by ``corpus from-video``, whose markers need no decoding).
"""
from __future__ import annotations

import json
from pathlib import Path

from analysis.face_eval import opening_strip_figure, write_scores_csv
from face_model.video_corpus import FromVideoSettings, default_speaker
from face_model.video_import import corpus_from_video
from groundwork.atomic import atomic_file
from groundwork.errors import ParameterError
from talkingface.stages.face_scoring import clips_from_corpus, clips_from_videos, score_model
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


def cmd_evaluate_face(args) -> int:
    """Score a model on real clips by the rules of :mod:`analysis.face_eval`: speech frames from
    the corpus's phones, or, for videos, from each clip's transcript forced-aligned (a clip
    without one is scored on all its valid frames, and the command says so)."""
    animator, tfmap = load_animator(args.model, args.runs_dir)
    src = Path(args.videos)
    if (src / "manifest.csv").is_file():
        clips, refused, unaligned = clips_from_corpus(src), [], []
    else:
        clips, refused, unaligned = clips_from_videos(
            src, speaker=args.speaker or default_speaker(src), workers=args.workers)
    training = _model_corpus(Path(tfmap))
    scores = score_model(animator, clips, training_corpus=training, progress=True)
    out = Path(args.out) if args.out else Path(tfmap).parent / "face_eval" / src.name
    out.mkdir(parents=True, exist_ok=True)
    write_scores_csv(scores, out / "per_clip.csv")
    record = {"model": str(tfmap), "source": str(src), "refused": refused,
              "no_speech_frames": unaligned, **scores.to_dict()}
    with atomic_file(out / "scores.json") as tmp:
        tmp.write_text(json.dumps(record, indent=1) + "\n")
    first = scores.tracks[0]
    opening_strip_figure(first, out / f"opening_{first.clip}.png",
                         f"{first.clip}: real vs predicted inner-lip opening")
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
          f"results: {out / 'per_clip.csv'}, {out / 'scores.json'}")
    return 0


def _positive(value: str) -> int:
    n = int(value)
    if n < 1:
        raise ParameterError(f"--workers {value}; allowed: 1 or more")
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
                   "clip) in this folder")
    s.set_defaults(func=cmd_from_video)

    s = sub.add_parser("evaluate-face", help="score a model's lips against real talking-face "
                       "videos (inner-lip opening r, closures, LVE on its own speaker)")
    s.add_argument("videos", type=Path, help="a video, a folder of videos, or a corpus folder")
    s.add_argument("--model", help="a run name, run folder or .tfmap (default: the latest "
                   "run's voice-robust model)")
    s.add_argument("--runs-dir", type=Path, default=Path("runs"))
    s.add_argument("--speaker", help="the videos' speaker (default: their folder's name)")
    s.add_argument("--out", type=Path, help="results folder (default: face_eval/<videos> "
                   "beside the model)")
    s.add_argument("--workers", type=_positive, default=2)
    s.set_defaults(func=cmd_evaluate_face)
