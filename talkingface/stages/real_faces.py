"""Every candidate's lips against real faces, speaker by speaker (stage ``real_faces``).

The candidates are every child of the voices grid (``voices-<child>``, among them the default),
the paper's single-voice mapping (``paper``), the mapping trained on the real speaker alone
(``speaker-trained``: the ``real_speaker`` stage's nested run) and the peers users already use
(:data:`mapping.peers.PEERS`: the loudness envelope, openfacefx in transcript mode — given each
clip's own word times when its corpus keeps them — and in loudness mode, pylipsync). They are
scored by the rules of :mod:`analysis.face_eval` (speech frames, closures on /p b m/, chance,
frames without a detected face left out) on two parts of real faces, by speaker:

* ``dev``: ``real_faces.dev_corpus`` (``builtin``: GRID s26, ``face_model/real_faces/grid-s26``), a
  speaker no candidate was trained on — the development rule weighs these lips
  (:mod:`analysis.dev_rule`);
* ``test``: ``real_faces.test_corpus`` (``builtin``: GRID s31, ``face_model/real_faces/grid-s31``) and
  the real speaker's held-out sentences (``real_speaker.corpus``, the utterance split of the
  run seed). A candidate trained on the real speaker's training sentences has *seen* that
  speaker, and so has one trained on faces drawn with an articulation fitted on them
  (:func:`face_speakers`): its rows say so (``seen``), and the unseen speaker decides.

Every figure is made from each clip's audio at its own rate; the default, the speaker-trained
model and the peers are also scored with it resampled to each rate of :data:`RATES` (they hear
it at that rate). Rows: one per candidate, part, speaker (and
``all`` for the part pooled: a part with fewer than three speakers gives no interval and says
so), rate. Files: ``results.csv`` and ``summary.json`` (the parts' speakers and clips, the
default model).
"""
from __future__ import annotations

import csv
import functools
import json
import time
from pathlib import Path

import face_model
from tqdm import tqdm

from analysis.face_eval import score_clips
from analysis.speech_eval import training_speakers
from data_synth.articulation import TABLE, articulation_path, articulation_record
from face_model.corpus import corpus_hash, load_corpus, read_manifest
from face_model.motion_units import MotionUnits
from groundwork.errors import ParameterError
from mapping.animator import FaceAnimator
from mapping.checkpoint import AudioMapping
from mapping.peers import PEERS, peer_versions
from talkingface.paths import RunPaths
from talkingface.stages.base import read_done, write_csv
from talkingface.stages.face_scoring import clips_from_corpus, score_model, score_peer
from talkingface.stages.given_corpus import check_folder
from talkingface.stages.real_speaker import NESTED, real_corpus
from talkingface.stages.training import utterance_test_ids
from talkingface.stages.voices import voices_models

REAL_FACES = Path(face_model.__file__).resolve().parent / "real_faces"
BUILTIN = {"dev": REAL_FACES / "grid-s26", "test": REAL_FACES / "grid-s31"}
RATES = (None, 16000, 8000)  # None: each clip's own rate ("native")
PARTS = ("dev", "test")
COLUMNS = ("model", "part", "speaker", "rate", "seen", "clips", "speech_frames", "r_speech",
           "chance_r_speech", "interval_r_speech", "r_clip_median", "bilabial_segments",
           "real_closed_rate", "closure_rate", "chance_closure_rate", "false_closure_rate",
           "chance_false_closure_rate")


def part_folder(cfg, part: str) -> Path | None:
    """The corpus folder of ``real_faces.<part>_corpus`` (None: off)."""
    value = getattr(cfg.real_faces, f"{part}_corpus")
    if not value:
        return None
    return BUILTIN[part] if value == "builtin" else Path(value)


def real_faces_applies(cfg) -> bool:
    """On when the run trains voices children and names a development or test part."""
    return any(part_folder(cfg, p) is not None for p in PARTS)


def real_faces_inputs(paths, cfg) -> dict:
    """The parts' corpora (their manifest hashes, by the one reader) join the stage's key."""
    out = {}
    for part in PARTS:
        folder = part_folder(cfg, part)
        if folder is not None:
            out[part] = check_folder(folder, f"real_faces.{part}_corpus",
                                     also="builtin or a corpus made by `talkingface corpus "
                                          "from-video`")
    return out


def _clips(paths: RunPaths, cfg) -> dict:
    """``{part: [RealClip]}``: the dev part's clips; the test part's and the real speaker's
    held-out sentences."""
    parts = {p: [] for p in PARTS}
    for p in PARTS:
        folder = part_folder(cfg, p)
        if folder is not None:
            parts[p] = clips_from_corpus(folder)
    real = real_corpus(cfg)
    if real is not None:
        corpus = load_corpus(real)
        parts["test"] += clips_from_corpus(real, utterance_test_ids(corpus, cfg))
    return parts


def face_speakers(corpus_dir, real) -> frozenset:
    """The real speakers whose mouths moved the drawn faces of the synthetic corpus at
    ``corpus_dir``: with a fitted articulation (``corpus.json``'s ``settings.articulation``
    other than ``table``), the speakers of the fit's training sentences. A model trained on
    those faces has *seen* them on a real face, though never heard them. Read from the run's
    real speaker's corpus ``real`` when the fit's ``corpus_hash`` is that corpus's; the fit's
    ``corpus`` name otherwise. Empty for the hand table or a given corpus."""
    info_file = Path(corpus_dir) / "corpus.json"
    info = json.loads(info_file.read_text(encoding="utf-8")) if info_file.is_file() else {}
    value = (info.get("settings") or {}).get("articulation", TABLE)
    if info.get("source") or not value or value == TABLE:
        return frozenset()
    record = articulation_record(articulation_path(value))
    if real is not None and record.get("corpus_hash") == _hash(str(real)):
        ids = set(record.get("training_utterances") or ())
        rows = read_manifest(Path(real) / "manifest.csv", ("utt_id", "speaker"))
        return frozenset(r["speaker"] for r in rows if r["utt_id"] in ids)
    return frozenset({str(record.get("corpus", value))})


@functools.lru_cache(maxsize=4)
def _hash(root: str) -> str:
    return corpus_hash(root)


def _candidates(paths: RunPaths) -> dict:
    """``{name: (tfmap, units, training corpus)}`` of the run's models."""
    out = {f"voices-{name}": (tfmap, units, corpus)
           for name, (tfmap, corpus, units) in voices_models(paths).items()}
    done = read_done(paths.mapping) or {}
    if "utterance" in done.get("models", {}):
        out["paper"] = (paths.mapping / done["models"]["utterance"], paths.units_model,
                        paths.corpus)
    nested = RunPaths.at(paths.root / NESTED)
    nested_done = read_done(nested.mapping) or {}
    if "utterance" in nested_done.get("models", {}):
        out["speaker-trained"] = (nested.mapping / nested_done["models"]["utterance"],
                                  nested.units / "motion_units.npz", nested.corpus)
    return out


def _rows(name: str, part: str, scores, rate: str, seen: set) -> list[dict]:
    """One row for the part pooled (``speaker`` all) and one per speaker."""
    tracks = scores.tracks
    speakers = sorted({t.speaker for t in tracks})
    pooled = [("all", scores.pooled)] + [
        (s, score_clips([t for t in tracks if t.speaker == s]).pooled) for s in speakers]
    rows = []
    for speaker, p in pooled:
        is_seen = bool(seen & set(speakers)) if speaker == "all" else speaker in seen
        rows.append({"model": name, "part": part, "speaker": speaker, "rate": rate,
                     "seen": is_seen, "clips": p["clips"],
                     **{k: p.get(k) for k in COLUMNS[6:]}})
    return rows


def evaluate_real_faces(paths: RunPaths, cfg) -> dict:
    """The stage (module docstring)."""
    t0 = time.perf_counter()
    parts = _clips(paths, cfg)
    if not any(parts.values()):
        raise ParameterError("real_faces: no clips in the development or test part")
    candidates = _candidates(paths)
    voices = read_done(paths.stage("voices")) or {}
    default = f"voices-{voices['model']}" if voices.get("model") else None
    rows = []
    jobs = [(n, p, r) for n in [*candidates, *PEERS] for p in PARTS if parts[p]
            for r in (RATES if n in (default, "speaker-trained", *PEERS) else RATES[:1])]
    animators: dict = {}
    for name, part, rate in tqdm(jobs, desc="real faces", unit="score"):
        label = "native" if rate is None else str(rate)
        if name in PEERS:
            rows += _rows(name, part, score_peer(name, parts[part], input_rate=rate), label,
                          set())
            continue
        tfmap, units, corpus = candidates[name]
        if name not in animators:  # one model in memory at a time
            animators = {name: (FaceAnimator(AudioMapping.load(tfmap), MotionUnits.load(units)),
                                set(training_speakers(corpus))
                                | face_speakers(corpus, real_corpus(cfg)))}
        animator, seen = animators[name]
        s = score_model(animator, parts[part], training_corpus=corpus, input_rate=rate)
        rows += _rows(name, part, s, label, seen)
    out = paths.stage("real_faces")
    write_csv(out / "results.csv", rows)
    summary = {
        "parts": {p: {"speakers": sorted({c.speaker for c in clips}),
                      "clips": {s: sum(c.speaker == s for c in clips)
                                for s in sorted({c.speaker for c in clips})}}
                  for p, clips in parts.items()},
        "default": default,
        "candidates": sorted(candidates), "peers": list(PEERS), "peer_versions": peer_versions(),
        "rates": ["native" if r is None else r for r in RATES],
        "rates_for": "every rate: the default, the speaker-trained model and the peers; the "
                     "native rate: every other candidate",
        "seconds": round(time.perf_counter() - t0, 1)}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    return {"rows": len(rows), "candidates": len(candidates)}


def read_rows(stage_dir) -> list[dict]:
    """``results.csv`` of a ``real_faces`` stage folder (empty when there is none)."""
    f = Path(stage_dir) / "results.csv"
    if not f.is_file():
        return []
    with open(f, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))
