"""The perception study of the replication (paper §VII-C): three stages.

``stimuli/``: the study's stimuli from the run's trained mapping. ``study_data/``: the simulated
participants (FLMP observers) in the study data format. ``analysis/``: Tables III–VII,
statistics and model fits of ``study_data``. Sessions with real people run outside the run
folder (``talkingface study run``), into a study folder of their own.
"""
from __future__ import annotations

import csv
import json
from pathlib import Path

from analysis.perception_report import analyze_study
from groundwork.errors import ParameterError
from study.classifier import observer_classifier
from study.simulate import simulate_study
from study.stimuli import build_stimuli, load_manifest
from talkingface.paths import RunPaths
from talkingface.stages.models import load_animator


def make_stimuli(paths: RunPaths, cfg) -> dict:
    """The stimulus set, animated by the run's model: its voice-robust model (stage ``voices``)
    when it has one, else the paper's single-voice mapping."""
    animator, _ = load_animator(str(paths.root))
    build_stimuli(paths.stimuli, animator=animator, synth_cfg=cfg.synth, seed=cfg.seed,
                  progress=True)
    return json.loads((paths.stimuli / "stimuli.json").read_text())


def simulate_participants(paths: RunPaths, cfg) -> dict:
    """``study.n_participants`` simulated participants judging the run's stimuli."""
    clf = observer_classifier(paths.stimuli, cfg.seed)
    res = simulate_study(paths.study_data, load_manifest(paths.stimuli), clf,
                         n=cfg.study.n_participants, seed=cfg.seed, study_seed=cfg.seed,
                         progress=True)
    # marks the folder as simulated for anyone who reads it without the run (the report too)
    (paths.study_data / "simulated.json").write_text(json.dumps(res, indent=1, default=str))
    return json.loads((paths.study_data / "simulated.json").read_text())


def analyze(paths: RunPaths, cfg) -> dict:
    """Tables III–VII, statistics and FLMP/WTAV fits of the run's study data."""
    return analyze_study(paths.study_data, paths.analysis, seed=cfg.seed)


def real_participants(study_dir: Path) -> list[str]:
    """The participants of a study folder whose judgments are not simulated (sorted)."""
    found = set()
    for path in sorted(Path(study_dir).glob("sub-*/sub-*_task-emotion_beh.csv")):
        with open(path, newline="", encoding="utf-8-sig") as f:
            for row in csv.DictReader(f):
                if row.get("simulated", "").strip().lower() != "true":
                    found.add(row.get("participant_id") or path.parent.name[4:])
    return sorted(found)


def keep_real_participants(study_dir: Path) -> None:
    """Refuse to replace a study folder that holds real participants' judgments."""
    people = real_participants(study_dir)
    if people:
        raise ParameterError(
            f"{study_dir} holds the judgments of real participants ({', '.join(people)}); it is "
            f"never replaced. Move it out of the run first (mv {study_dir} "
            f"study_archive_{Path(study_dir).parent.name}), then run again")
