"""``talkingface study …``: stimuli, allocation, sessions with people, simulated participants.

    talkingface study stimuli  --name RUN            runs/RUN/stimuli from the run's mapping
    talkingface study allocate --study-dir D         the pre-generated SR/RS list (seeded)
    talkingface study run --participant P01          one PsychoPy session (--resume, --fullscreen)
    talkingface study web --out web                  the same study as a jsPsych web page
    talkingface study serve --web web                serve it; its data into the study folder
    talkingface study release --participant P01      give an aborted session's slot back
    talkingface study simulate --n 20                simulated participants (FLMP observers;
                                                     again, with the same settings, to resume)
    talkingface analyze DIR [--allow-incomplete]     Tables III-VII, statistics and model fits

The study seed is the run seed (``--seed``/``--set seed=``); the study folder defaults to
``study_data`` and the stimuli to ``runs/<name>/stimuli`` of the latest run.
"""
from __future__ import annotations

import hashlib
import json
import shutil
from contextlib import contextmanager
from pathlib import Path

from analysis.perception_report import analyze_study, perception_section
from analysis.report import Report
from groundwork.atomic import fresh_partial_folder, swap_in
from groundwork.errors import ParameterError
from study.classifier import observer_classifier, visual_evidence
from study.data import Allocation, data_path, read_rows
from study.design import N_TRIALS, participant_seed, session_trials
from study.runner import run_session, scripted_responder
from study.simulate import RESPONDER_MODEL, make_observers, responder, simulate_study
from study.stimuli import load_manifest
from talkingface.cli import runs
from talkingface.cli.args import config_args, resolve_config, run_args
from talkingface.cli.study_web import add_parsers as add_web_parsers
from talkingface.cli.study_web import stimuli_folder
from talkingface.config import MAX_SEED
from talkingface.paths import check_run_name
from talkingface.provenance import git_commit

DEFAULT_STUDY_DIR = Path("study_data")


def monte_carlo_seed(seed) -> int:
    """``--seed`` of ``analyze`` and ``report --study-data`` (default 0), checked as the run
    seed is."""
    if seed is None:
        return 0
    if not 0 <= seed <= MAX_SEED:
        raise ParameterError(f"--seed is {seed}; allowed: an integer in [0, {MAX_SEED}]")
    return seed


def study_report(study_dir, name: str | None = None, *, seed: int = 0, reports_dir="reports",
                 allow_incomplete: bool = False, overwrite: bool = False) -> Path:
    """``reports/study/<name>.pdf`` from a study's data alone: the analysis and how it was made
    (``allow_incomplete``: analyse the complete sessions of a folder that has incomplete ones;
    the report says so). Study reports have a folder of their own, so one never replaces a
    replication's ``reports/<name>.pdf``; the default name (:func:`study_report_name`) is never
    another study's, and an existing report is replaced only with ``overwrite``."""
    folder = Path(reports_dir) / "study"
    name = study_report_name(study_dir, folder) if name is None else check_run_name(name)
    pdf, out = folder / f"{name}.pdf", folder / f"{name}_analysis"
    for made in (pdf, out):
        if made.exists() and not overwrite:
            raise ParameterError(f"{made} already exists (from {_source_of(out) or 'a study'});"
                                 " pass --overwrite to replace it, or --name for another name")
    with _analysis_folder(out) as partial:
        summary = analyze_study(study_dir, partial, seed=seed, allow_incomplete=allow_incomplete)
        rep = Report(f"talkingface perception study: {name}",
                     "Emotion judgments of a synthetic and a real talking face (Hong, Wen &amp; "
                     "Huang 2002, §VII-C)")
        perception_section(rep, summary, partial)
        rep.heading("Methods")
        rep.paragraph(f"Analysed by talkingface (source commit {git_commit()}) from {study_dir}; "
                      f"Monte Carlo and bootstrap seed {seed}. Participants: "
                      f"{summary['participants']} "
                      f"({'simulated' if summary['simulated'] else 'real'}).")
        rep.build(pdf)
    return pdf


def study_report_name(study_dir, folder) -> str:
    """The default name of a study's report in ``folder``: the study folder's name, unless a
    report of that name is another study's; then that name and 8 hex digits of the study
    folder's full path (the same for every report of one study)."""
    path = Path(study_dir).resolve()
    name = check_run_name(path.name)
    source = _source_of(Path(folder) / f"{name}_analysis")
    if source is None or source == str(path):
        return name
    return f"{name}-{hashlib.sha256(str(path).encode()).hexdigest()[:8]}"


def _source_of(analysis_dir: Path) -> str | None:
    """The full path of the study folder an analysis folder was made from (None: none there)."""
    try:
        summary = json.loads((analysis_dir / "analysis.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    source = summary.get("study_path") if isinstance(summary, dict) else None
    return str(source) if source else "a study of unknown folder"


@contextmanager
def _analysis_folder(out: Path):
    """Build an analysis folder beside ``out`` and swap it in when the block ends without an
    error (removed otherwise): no half analysis under the name, the old one kept until then."""
    partial = fresh_partial_folder(out)
    try:
        yield partial
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    swap_in(partial, out)


def cmd_analyze(args) -> int:
    out = args.out or Path(args.study_data) / "analysis"
    if out.exists() and not out.is_dir():
        raise ParameterError(f"--out {out} is a file; give a folder")
    if out.is_dir() and any(out.iterdir()) and not args.overwrite:
        raise ParameterError(f"--out {out} already holds files (an analysis of "
                             f"{_source_of(out) or 'something else'}); pass --overwrite to "
                             "replace them, or another --out")
    with _analysis_folder(out) as partial:
        summary = analyze_study(args.study_data, partial, seed=monte_carlo_seed(args.seed),
                                allow_incomplete=args.allow_incomplete)
    for k, t in summary["tallies"].items():
        print(f"Table {k}: {t['counts']}")
    sites = summary["sites"]
    where = ", ".join(f"{k} {v}" for k, v in sites.items() if k in ("lab", "web", "none",
                                                                    "unknown"))
    print(f"{summary['participants']} participants ({where}); tables, statistics and fits in "
          f"{out}")
    if sites.get("web"):
        print(f"online: {sites['web_left_fullscreen']} left fullscreen and "
              f"{sites['web_lost_focus']} lost focus during a trial (columns fullscreen, focused)")
    for i in summary["incomplete"]:
        print(f"incomplete: {i['participant_id']} ({i['judgments']} of {N_TRIALS} judgments; "
              f"{i['reason']}): {'analysed' if i['analysed'] else 'left out'}")
    return 0


def cmd_stimuli(args) -> int:
    info = runs.stimuli(args.name, resolve_config(args), overwrite=args.overwrite)
    print(f"{info['n_stimuli']} stimuli in {Path('runs') / args.name / 'stimuli'} (manifest.csv, "
          "contact_sheet.png)")
    return 0


def cmd_allocate(args) -> int:
    cfg = resolve_config(args)
    n = cfg.study.n_participants if args.n is None else args.n
    rows = Allocation(args.study_dir).create(n, cfg.seed)
    counts = {s: sum(r["sequence"] == s for r in rows) for s in ("SR", "RS")}
    print(f"{args.study_dir / 'allocation.csv'}: {len(rows)} slots (SR {counts['SR']}, RS "
          f"{counts['RS']}), seed {cfg.seed}")
    return 0


def _injected(args, stimuli_dir: Path, cfg, pid: str):
    """``(responder, model name)`` for ``--inject``: ``flmp`` or a CSV of responses."""
    if not args.inject:
        return None, "human"
    if args.inject != "flmp":
        return scripted_responder(args.inject), f"script:{Path(args.inject).name}"
    clf = observer_classifier(stimuli_dir, cfg.seed)
    observer = make_observers(1, participant_seed(cfg.seed, pid))[0]
    answer = responder(observer, visual_evidence(clf, load_manifest(stimuli_dir)))
    if args.resume:
        _replay_answers(answer, args.study_dir, pid, cfg.seed)
    return answer, RESPONDER_MODEL


def _replay_answers(answer, study_dir: Path, pid: str, seed: int) -> None:
    """On --resume, let a simulated observer answer the judgments already on file again (and
    discard them), so its random stream continues where the interrupted session left it."""
    path = data_path(study_dir, pid)
    if not path.is_file():
        return
    held = [r for r in Allocation(study_dir).rows() if r["participant_id"] == pid]
    if held:
        for trial in session_trials(pid, held[0]["sequence"], seed)[:len(read_rows(path)[0])]:
            answer(trial)


def cmd_run(args) -> int:
    cfg = resolve_config(args)
    stim = stimuli_folder(args)
    resp, model = _injected(args, stim, cfg, args.participant)
    s = cfg.study
    res = run_session(args.study_dir, stim, args.participant, study_seed=cfg.seed,
                      n_slots=s.n_participants, resume=args.resume,
                      fullscreen=args.fullscreen or s.fullscreen, keys=tuple(s.keys),
                      practice=s.practice, fixation_s=s.fixation_s, iti_s=s.iti_s,
                      audio_backend=s.audio_backend, responder=resp, responder_model=model,
                      screenshot=args.screenshot)
    state = "complete" if res["complete"] else ("aborted" if res["aborted"] else "stopped")
    print(f"participant {res['participant_id']} ({res['sequence']}): {res['rows']} of 27 "
          f"judgments, {state}; data: {res['data']}")
    if not res["complete"]:
        print(f"continue with: talkingface study run --participant {res['participant_id']} "
              "--resume")
    return 0 if res["complete"] else 3


def cmd_release(args) -> int:
    slot = Allocation(args.study_dir).release(args.participant, note=args.note or "")
    print(f"slot {slot['slot']} ({slot['sequence']}) is free again; {args.participant}'s data "
          "stay where they are")
    return 0


def cmd_simulate(args) -> int:
    cfg = resolve_config(args)
    stim = stimuli_folder(args)
    stimuli = load_manifest(stim)  # a missing or damaged stimulus set is named first
    clf = observer_classifier(stim, cfg.seed)
    res = simulate_study(args.study_dir, stimuli, clf, n=args.n, seed=cfg.seed,
                         study_seed=cfg.seed, progress=True)
    print(json.dumps(res, indent=1, default=str))
    return 0


def add_parser(sub) -> None:
    a = sub.add_parser("analyze", help="Tables III–VII, statistics and FLMP/WTAV fits of study "
                       "data (real or simulated)")
    a.add_argument("study_data", type=Path, help="a study data folder")
    a.add_argument("--out", type=Path, help="where to write (default: <study_data>/analysis)")
    a.add_argument("--seed", type=int, help="seed of the Monte Carlo parts (default 0)")
    a.add_argument("--allow-incomplete", action="store_true",
                   help="analyse the complete sessions of a folder that also holds incomplete "
                   "ones (refused otherwise); the summary lists them")
    a.add_argument("--overwrite", action="store_true", help="replace an analysis that is "
                   "there")
    a.set_defaults(func=cmd_analyze)

    p = sub.add_parser("study", help="the perception study: stimuli, allocation, PsychoPy "
                       "sessions, simulated participants")
    ss = p.add_subparsers(dest="study_command", required=True)

    s = ss.add_parser("stimuli", help="make runs/<name>/stimuli from the run's trained mapping")
    run_args(s, "run (trained first if needed)")
    s.set_defaults(func=cmd_stimuli)

    def study_dir(q):
        q.add_argument("--study-dir", type=Path, default=DEFAULT_STUDY_DIR,
                       help="the study data folder (default: study_data)")

    s = ss.add_parser("allocate", help="write the seeded SR/RS allocation list")
    study_dir(s)
    s.add_argument("--n", type=int, help="slots (default: study.n_participants)")
    config_args(s)
    s.set_defaults(func=cmd_allocate)

    s = ss.add_parser("run", help="one PsychoPy session for a participant")
    s.add_argument("--participant", required=True, help="id: letters and digits only, no "
                   "personal data (e.g. P01)")
    study_dir(s)
    s.add_argument("--stimuli", type=Path, help="stimulus folder (default: the latest run's)")
    s.add_argument("--resume", action="store_true", help="continue an interrupted session")
    s.add_argument("--fullscreen", action="store_true")
    s.add_argument("--inject", help="answer automatically: 'flmp' (a simulated observer) or a "
                   "CSV of stimulus_id,response[,rt_s] (tests and demonstrations)")
    s.add_argument("--screenshot", type=Path, help="save a PNG of the first bimodal trial")
    config_args(s)
    s.set_defaults(func=cmd_run)

    add_web_parsers(ss, study_dir)

    s = ss.add_parser("release", help="free an aborted participant's allocation slot")
    s.add_argument("--participant", required=True)
    s.add_argument("--note", help="why (kept in allocation_log.csv)")
    study_dir(s)
    s.set_defaults(func=cmd_release)

    s = ss.add_parser("simulate", help="simulated participants (FLMP observers); run it again "
                       "with the same settings to resume an interrupted simulation")
    s.add_argument("--n", type=int, default=20)
    study_dir(s)
    s.add_argument("--stimuli", type=Path, help="stimulus folder (default: the latest run's)")
    config_args(s)
    s.set_defaults(func=cmd_simulate)

