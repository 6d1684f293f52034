"""``talkingface study web`` and ``study serve``: the perception study online.

    talkingface study web --out web                    the experiment as a static jsPsych page
    talkingface study serve --web web                  serve it; data into study_data/
        [--study-dir D] [--host 127.0.0.1] [--port 8000] [--inject flmp]

The page is built from the same stimuli and study settings as ``study run`` (``--stimuli``,
default the latest run's; ``study.*`` of the config: keys, practice, fixation, ITI, consent);
the server takes the same study folder, allocation list and seed, so lab and web participants
share one list of slots and one data format. See README "The perception study online".
"""
from __future__ import annotations

import json
import socket
from pathlib import Path

from groundwork.errors import ParameterError
from study.classifier import observer_classifier, visual_evidence
from study.design import participant_seed
from study.simulate import RESPONDER_MODEL, make_observers, responder
from study.stimuli import load_manifest
from study.web.app import make_app
from study.web.build import build_web
from study.web.server_session import WebStudy
from talkingface.cli.args import config_args, resolve_config

DEFAULT_HOST, DEFAULT_PORT = "127.0.0.1", 8000
SITE_FILE = "study.json"


def stimuli_folder(args) -> Path:
    """``--stimuli``, else the stimuli of the latest run (``runs/*/stimuli``)."""
    if args.stimuli:
        return Path(args.stimuli)
    found = sorted(Path("runs").glob("*/stimuli/manifest.csv"), key=lambda p: p.stat().st_mtime)
    if not found:
        raise ParameterError("no stimuli found under runs/: make them with `talkingface study "
                             "stimuli --name RUN` (or `make replicate`), or pass --stimuli DIR")
    return found[-1].parent


def read_site(web_dir) -> dict:
    """The built experiment's ``study.json``, or one line saying how to build it."""
    path = Path(web_dir) / SITE_FILE
    if not path.is_file():
        raise ParameterError(f"--web {web_dir}: no {SITE_FILE} there; build the experiment "
                             "with `talkingface study web --out DIR` and serve that folder")
    try:
        site = json.loads(path.read_text(encoding="utf-8"))
    except ValueError as exc:
        raise ParameterError(f"{path} is not JSON ({exc}); build the experiment again") \
            from None
    if not isinstance(site, dict) or site.get("format") != 1 or not isinstance(
            site.get("keys"), dict):
        raise ParameterError(f"{path}: not a study page of this version (format "
                             f"{site.get('format') if isinstance(site, dict) else None!r}; "
                             "allowed: 1); build the experiment again")
    return site


def flmp_observers(stimuli_dir, seed: int):
    """``observer(pid) -> answer``: the simulated observer ``study run --inject flmp`` uses
    for that participant."""
    evidence = visual_evidence(observer_classifier(stimuli_dir, seed), load_manifest(stimuli_dir))

    def observer(pid: str):
        return responder(make_observers(1, participant_seed(seed, pid))[0], evidence)
    return observer


def check_port(host: str, port: int) -> None:
    """Refuse a port outside 1-65535 or already in use, in one line."""
    if not 0 < port < 65536:
        raise ParameterError(f"--port {port}; allowed: 1-65535")
    with socket.socket() as s:
        try:
            s.bind((host, port))
        except OSError as exc:
            raise ParameterError(f"--host {host} --port {port}: cannot listen there "
                                 f"({exc.strerror}); pick another --port") from None


def cmd_web(args) -> int:
    cfg = resolve_config(args)
    info = build_web(stimuli_folder(args), args.out, study_cfg=cfg.study,
                     overwrite=args.overwrite)
    print(f"study web: the experiment in {args.out} ({info['n_files']} files, "
          f"{info['bytes'] / 2**20:.1f} MB); serve it with: talkingface study serve --web "
          f"{args.out}")
    return 0


def cmd_serve(args) -> int:
    import uvicorn  # (the server: only here)

    cfg = resolve_config(args)
    site = read_site(args.web)
    observer, model = None, "human"
    if args.inject is not None:
        if args.inject != "flmp":
            raise ParameterError(f"--inject {args.inject!r}; allowed: flmp")
        observer, model = flmp_observers(stimuli_folder(args), cfg.seed), RESPONDER_MODEL
    s = cfg.study
    check_port(args.host, args.port)
    study = WebStudy(args.study_dir, site, study_seed=cfg.seed, n_slots=s.n_participants,
                     completion_code=s.completion_code, completion_url=s.completion_url,
                     observer=observer, responder_model=model)
    base = f"http://{args.host}:{args.port}/"
    print(f"study serve: the experiment in {args.web} at {base}; data into {args.study_dir} "
          f"(allocation {args.study_dir / 'allocation.csv'}, seed {cfg.seed})")
    print(f"study serve: a participant's link: {base}?participant=P01 ; from Prolific: {base}"
          "?PROLIFIC_PID={{%PROLIFIC_PID%}}&STUDY_ID={{%STUDY_ID%}}&SESSION_ID={{%SESSION_ID%}}"
          " ; Ctrl-C stops the server")
    uvicorn.Server(uvicorn.Config(make_app(args.web, study), host=args.host, port=args.port,
                                  log_level="warning", access_log=False)).run()
    return 0


def add_parsers(ss, study_dir) -> None:
    """``study web`` and ``study serve`` under the ``study`` command's sub-parsers ``ss``
    (``study_dir(parser)`` adds ``--study-dir``)."""
    s = ss.add_parser("web", help="build the study as a static jsPsych web page")
    s.add_argument("--out", type=Path, required=True, help="the folder to write (refused if it "
                   "exists, unless --overwrite)")
    s.add_argument("--stimuli", type=Path, help="stimulus folder (default: the latest run's)")
    s.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    config_args(s)
    s.set_defaults(func=cmd_web)

    s = ss.add_parser("serve", help="serve a built web study and keep its participants' data")
    s.add_argument("--web", type=Path, required=True, help="the folder `study web` built")
    study_dir(s)
    s.add_argument("--host", default=DEFAULT_HOST, help="address to listen on (default "
                   "127.0.0.1: put a reverse proxy with HTTPS in front, see README)")
    s.add_argument("--port", type=int, default=DEFAULT_PORT)
    s.add_argument("--inject", help="'flmp': simulated observers answer every participant "
                   "(the page plays their answers through jsPsych's simulation)")
    s.add_argument("--stimuli", type=Path, help="with --inject: the stimulus folder the "
                   "observers judge (default: the latest run's)")
    config_args(s)
    s.set_defaults(func=cmd_serve)
