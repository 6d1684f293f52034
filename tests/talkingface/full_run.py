"""The small full replication the suite shares (``full_run_dir`` in tests/conftest.py, made once
per test session): every stage of ``talkingface replicate`` on a tiny corpus, with a real
speaker (every 4th of the built-in GRID s1's 196 sentences, given as a corpus folder) with two
trained steps, three voice-robust models (one trained on the real speaker), four ceiling
steps and MLflow in the folder's own
store."""
from __future__ import annotations

import csv
import shutil
from pathlib import Path

from talkingface.stages.real_speaker import BUILTIN

# 3 sentences; the real-speaker stage (GRID s1, 196 sentences) only where a test asks for it
TINY = ["--set", "synth.n_sentences=3", "--set", "synth.workers=2",
        "--set", "real_speaker.corpus=''"]
# the tracker's evaluation on 3 utterances (one per expression; 6 by default), two training
# seeds per ceiling step (3 by default), the real-speech set's first 2 recordings of each
# speaker and part (21 of 354, every speaker) and at most 40 epochs per network (600 by
# default; the real speaker's 196 sentences train every method on both splits): every stage
# and its bookkeeping, with less work
SMALLER = ["--set", "tracker.n_utterances=3", "--set", "ceiling.seeds=2",
           "--set", "real_steps.seeds=2", "--set", "front_end.voices=[espeak:en-us+f3]",
           "--set", "front_end.train.epochs=2", "--set", "front_end.train.hidden=16",
           "--set", "speech_set.per_speaker=2", "--set", "mapping.train.max_epochs=40"]
# four ceiling steps, small: the run's, one nuisance off (its own corpus), the tracked MUPs
# (a tracked copy of the run's corpus), the oracle
CEILING_GRID = """base:
  mapping.splits: [random_frames, utterance]
  mapping.baselines: []
  mapping.train.max_epochs: 40
children:
  ours: {}
  no-brow-motion: {synth.brow_px: 0}
  tracked: {mapping.visual_source: tracked}
  oracle: {mapping.gate_front_end: labels, mapping.mlp_input: phones}
"""
# two trained steps on the real speaker's training sentences: the run's mapping, the oracle
REAL_STEPS_GRID = """base:
  mapping.splits: [random_frames, utterance]
  mapping.baselines: []
  mapping.train.max_epochs: 40
children:
  ours: {}
  oracle: {mapping.gate_front_end: labels, mapping.mlp_input: phones}
"""
# four voice-robust configurations, small: the run's voice, three engines with CMVN, the real
# speaker's training sentences alone, and the run's causal front end (the front_end stage)
VOICES_GRID = """model: many
base:
  mapping.splits: [utterance]
  mapping.baselines: []
children:
  one: {}
  many:
    synth.voices: [espeak:en-us+f3, flite:awb, festival:kal_diphone]
    mapping.cmvn: meanvar
  real: {voices.real_face: alone}
  causal: {mapping.gate_front_end: recogniser, mapping.recogniser: causal,
           mapping.mlp_input: phones, mapping.phone_training: labels}
"""


# every 4th sentence of the built-in real speaker (49 of 196): the stage trains all seven
# methods on both splits and scores every peer at three rates, a quarter of the work; the
# built-in folder itself is read by tests/talkingface/test_real_speaker_scoring.py
REAL_EVERY = 4


def real_speaker_part(dst: Path, every: int = REAL_EVERY) -> Path:
    """Copy every ``every``-th sentence of the built-in real speaker (manifest order) with its
    audio, markers, phones and quality files, ``corpus.json`` and ``NOTICE.md`` to ``dst``: a
    corpus folder in the layout ``real_speaker.corpus`` takes."""
    with open(BUILTIN / "manifest.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    keep = rows[::every]
    for row in keep:
        for column in ("audio", "markers", "phones", "quality"):
            (dst / row[column]).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(BUILTIN / row[column], dst / row[column])
    with open(dst / "manifest.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(keep)
    for name in ("corpus.json", "NOTICE.md"):
        shutil.copy2(BUILTIN / name, dst / name)
    return dst


def build_full_run(root: Path, main) -> Path:
    """Make the run ``tiny`` (and ``reports/tiny.pdf``, ``mlflow.db``, ``mlartifacts/``) with
    ``main`` (the CLI entry point) in ``root``, the current folder."""
    (root / "voices.yaml").write_text(VOICES_GRID)
    (root / "ceiling.yaml").write_text(CEILING_GRID)
    (root / "real_steps.yaml").write_text(REAL_STEPS_GRID)
    real_speaker_part(root / "grid-s1-part")
    assert main(["replicate", "--name", "tiny", *TINY, *SMALLER, "--ablations", "none",
                 "--voices", "voices.yaml", "--set", "ceiling.grid=ceiling.yaml",
                 "--set", "real_steps.grid=real_steps.yaml",
                 "--set", "real_speaker.corpus=grid-s1-part"]) == 0
    return root
