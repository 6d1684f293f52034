"""The bad-input table's part: Settings that name data (validated before any stage), long error lines, interrupts.

``CASES`` are ``(argv, names)`` as in :mod:`tests.talkingface.bad_input_cases`;
:func:`add_inputs` makes the files they name in the suite's working folder.

Every config setting that names data outside the run (``real_speaker.corpus``,
``real_speaker.videos``, ``corpus.source``, ``synth.text_file``, ``ablations.grid``,
``ceiling.grid``, ``real_steps.grid``, ``voices.grid``)
is read and checked before any stage runs, and refused in a line that names the setting: a
bad real speaker's corpus used to be found only when its stage was reached, minutes into a
replication, and named as ``corpus.source``. The Ctrl-C tests and the cut simulation's bounded
line are in test_interrupts.py.
"""
from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np

from tests.talkingface.bad_input_cases import QUICK, RUN, _copy_corpus

PLANNED = 1200  # participants the cut simulation sd_cut_many planned (its list has their slots)


def _replicate(*settings: str, name: str = "N") -> list:
    """``replicate`` of the suite's quick settings, then ``settings`` (``--set`` given later
    wins), on a new run ``name``."""
    return ["replicate", "--name", name, *QUICK, *settings]


CASES: list = [
    # -- real_speaker.corpus: checked by the one corpus reader before the first stage
    (_replicate("--set", "real_speaker.corpus=rs_nan_corpus"),
     ["real_speaker.corpus", "rs_nan_corpus", "NaN"]),
    # an existing run: refused before any of its stages is run again
    (_replicate("--overwrite", "--set", "real_speaker.corpus=rs_nan_corpus", name="R"),
     ["real_speaker.corpus", "rs_nan_corpus", "NaN"]),
    (_replicate("--set", "real_speaker.corpus=missing_corpus"),
     ["real_speaker.corpus", "missing_corpus", "not found", "builtin"]),
    (_replicate("--set", "real_speaker.corpus=speech.wav"),
     ["real_speaker.corpus", "speech.wav", "is a file"]),
    (_replicate("--set", "real_speaker.corpus=a_folder"),
     ["real_speaker.corpus", "a_folder", "manifest.csv"]),
    (_replicate("--set", "real_speaker.corpus=rs_phone_corpus"),
     ["real_speaker.corpus", "rs_phone_corpus", "zz"]),
    # -- the other settings that name data
    (_replicate("--set", "synth.text_file=missing_sentences.txt"),
     ["synth.text_file", "missing_sentences.txt"]),
    # -- synth.articulation: table, a shipped name or an articulation model file
    (_replicate("--set", "synth.articulation=missing_articulation.npz"),
     ["synth.articulation", "missing_articulation.npz", "file not found", "allowed: table"]),
    (_replicate("--set", "synth.articulation=not_a_model.npz"),
     ["synth.articulation", "not_a_model.npz", "allowed: table"]),
    (_replicate("--set", "synth.articulation=grid-s99"),
     ["synth.articulation", "grid-s99", "grid-s1"]),
    (["replicate", "--name", "N", *RUN, "--ablations", "grid_list.yaml"],
     ["ablations.grid", "grid_list.yaml"]),
    (_replicate("--set", "ceiling.grid=grid_unknown.yaml"), ["ceiling.grid", "grid_unknown.yaml"]),
    (_replicate("--set", "real_speaker.corpus=c", "--set", "real_steps.grid=grid_unknown.yaml"),
     ["real_steps.grid", "grid_unknown.yaml"]),
    (_replicate("--set", "real_speaker.corpus=c", "--set", "real_speaker.videos=no_videos"),
     ["real_speaker.videos", "no_videos", "not found"]),
    (_replicate("--set", "voices.grid=grid.yaml"), ["voices.grid", "grid.yaml", "'model'"]),
    # -- the causal front end: its model file, its settings
    (_replicate("--set", "mapping.gate_front_end=recogniser", "--set", "mapping.recogniser=causal",
                "--set", "mapping.front_model=no_front.npz"),
     ["mapping.front_model", "no_front.npz", "not found"]),
    (_replicate("--set", "mapping.gate_front_end=recogniser", "--set", "mapping.recogniser=causal",
                "--set", "mapping.front_model=speech.wav"),
     ["speech.wav", "not a phone front model file"]),
    (_replicate("--set", "mapping.front_model=x.npz"),
     ["mapping.front_model", "x.npz", "with mapping.recogniser 'causal'"]),
    (_replicate("--set", "mapping.recogniser=Causal"), ["mapping.recogniser", "'Causal'"]),
    (["front-end", "--name", "F", *RUN, "--set", "front_end.train.lookahead_ms=150"],
     ["front_end.train.lookahead_ms", "150", "a multiple of 10 from 0 to 100"]),
    (["front-end", "--name", "F", *RUN, "--set", "voices.grid=default", "--set",
      "front_end.corpora=[run, real]"], ["front_end.corpora", "real_speaker.corpus names no corpus"]),
    (["front-end", "--name", "F", *RUN], ["talkingface front-end", "voices.grid none"]),
    (["train", "--name", "G", *RUN, "--set", "corpus.source=rs_nan_corpus"],
     ["corpus.source", "rs_nan_corpus", "NaN"]),
    # -- speech_set.per_speaker: how many recordings of each speaker and part are scored
    (_replicate("--set", "speech_set.per_speaker=-1"),
     ["speech_set.per_speaker", "-1", "an integer >= 0"]),
    (["evaluate-speech", "--model", "R", "--out", "ev_subset/results.csv", "--set",
      "speech_set.per_speaker=x"], ["speech_set.per_speaker", "'x'", "an integer"]),
    # -- a message that would list a thousand participants: one line, its advice kept
    (["analyze", "sd_cut_many", "--out", "an_new"],
     ["sd_cut_many", "holds incomplete sessions", "--allow-incomplete"]),
]


def _cut_many(root: Path) -> None:
    """``sd_cut_many``: the run's simulated study data as a simulation of :data:`PLANNED`
    participants cut after its first ones (the slots it had not reached are free)."""
    out = root / "sd_cut_many"
    shutil.copytree(root / "runs" / "R" / "study_data", out)
    with open(out / "allocation.csv", newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    fields = list(rows[0])
    rows += [{**dict.fromkeys(fields, ""), "slot": str(slot), "sequence": ("SR", "RS")[slot % 2],
              "status": "free"} for slot in range(len(rows) + 1, PLANNED + 1)]
    with open(out / "allocation.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=fields, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)


def add_inputs(root: Path) -> None:
    """Make the inputs of :data:`CASES` in ``root``: two damaged one-utterance copies of the
    corpus ``c`` (a NaN marker; an unknown phone) and a cut simulation of many participants."""
    (root / "not_a_model.npz").write_text("these are not arrays\n")
    nan = _copy_corpus(root, "rs_nan_corpus")
    with open(nan / "manifest.csv", newline="", encoding="utf-8") as f:
        first = next(csv.DictReader(f))
    markers = np.load(nan / first["markers"])
    markers[3, 5, 0] = np.nan
    np.save(nan / first["markers"], markers)
    phones = _copy_corpus(root, "rs_phone_corpus") / first["phones"]
    lines = phones.read_text(encoding="utf-8").splitlines()
    start, end, _ = lines[2].split(",")
    lines[2] = f"{start},{end},zz"
    phones.write_text("\n".join(lines) + "\n", encoding="utf-8")
    _cut_many(root)
