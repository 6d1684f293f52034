"""The rule that picks the default voice-robust model (``configs/voices.yaml`` ``model:``) on
development data only, never on the test speakers, among the models whose measured live
latency (speech_eval's ``latency.json``, :mod:`talkingface.stages.latency`) is within
``targets.stream_latency_p99_ms`` (issue 40: a model over it cannot be the default, whatever
its accuracy).

The score weighs what is heard and what is seen equally (issue 50; fixed before any candidate
was scored on real lips):

* **audio**: the development part of the real-speech set holds two kinds of recording
  (:attr:`analysis.speech_set.SpeechItem.kind`), weighed equally (issue 51; fixed before any
  candidate was scored on a development sentence): **sentences** (continuous speech, what users
  say: GRID s26) and **digits** (isolated words: two FSDD speakers). Per kind, the mean of
  :data:`DEV_RULE`'s figures that kind measures for some candidate, over its unseen recordings
  (speech_eval's ``results.csv``, ``split`` :data:`AUDIO_KINDS`, native rate); audio is the mean
  of the kinds. A run whose results have no per-kind rows (a development part of one kind, or
  a run made before the kinds) scores the pooled ``unseen-dev`` rows as its one kind;
* **lips**: the mean of :data:`LIP_RULE`'s figures on the development part of the real faces
  (the ``real_faces`` stage's ``results.csv``: ``part`` = ``dev``, every speaker pooled, native
  rate; a speaker no candidate was trained on): speech-frame lip r and the share of /p b m/
  segments the lips close;
* score = ``AUDIO_WEIGHT`` · audio + ``LIP_WEIGHT`` · lips. A run without real faces scored
  (no ``real_faces`` rows) scores the audio alone, as before; a figure the development data
  measure for no candidate is left out for all of them alike.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

DEV_RULE = ("viseme_acc", "bilabial_closed_frac", "labiodental_contact_frac", "r_reference")
LIP_RULE = ("r_speech", "closure_rate")  # real_faces rows: lip r on speech frames, /p b m/ closed
AUDIO_WEIGHT = 0.5
LIP_WEIGHT = 0.5
# the development part's kinds of recording: results.csv split → the kind's name, equal weights
AUDIO_KINDS = {"unseen-dev-sentences": "sentences", "unseen-dev-digits": "digits"}
POOLED = "unseen-dev"  # the whole development part, when its rows have no kinds
LATENCY_FILE = "latency.json"  # speech_eval: each model's live latency (talkingface.stages.latency)


def _figures(row: dict, keys: tuple) -> dict:
    """``{figure: value}`` of ``keys`` in a CSV row (NaN where one is missing or not a number)."""
    vals = {}
    for k in keys:
        try:
            vals[k] = float(row[k])
        except (KeyError, TypeError, ValueError):
            vals[k] = float("nan")
    return vals


def dev_rows(results: list[dict], prefix: str, split: str = POOLED) -> dict:
    """``{model: {figure: value}}`` of :data:`DEV_RULE` on the native-rate ``split`` rows of
    the models named ``prefix``* (NaN where a figure is missing)."""
    return {r["model"]: _figures(r, DEV_RULE) for r in results
            if r["split"] == split and r["model"].startswith(prefix)
            and str(r.get("input_rate") or "native") == "native"}


def dev_rule_figures(results: list[dict], prefix: str = "voices-",
                     split: str = POOLED) -> tuple[str, ...]:
    """The figures of :data:`DEV_RULE` the development rows of ``split`` measure: a figure they
    measure for no candidate (digits hold no /p b m/, so no closure can be scored on them) is
    left out of the rule for all of them alike."""
    rows = dev_rows(results, prefix, split)
    return tuple(k for k in DEV_RULE if any(math.isfinite(v[k]) for v in rows.values()))


def audio_splits(results: list[dict], prefix: str = "voices-") -> tuple[str, ...]:
    """The results.csv splits the audio half is the mean of: the :data:`AUDIO_KINDS` with
    development rows measuring some figure, else the pooled :data:`POOLED` (module docstring)."""
    kinds = tuple(k for k in AUDIO_KINDS if dev_rule_figures(results, prefix, k))
    return kinds or (POOLED,)


def lip_rows(real_faces: list[dict] | None, prefix: str = "voices-") -> dict:
    """``{model: {figure: value}}`` of :data:`LIP_RULE` on the ``real_faces`` rows of the
    development part (``part`` dev, ``speaker`` all, ``rate`` native) of the models named
    ``prefix``* (NaN where a figure is missing)."""
    return {r["model"]: _figures(r, LIP_RULE) for r in real_faces or []
            if r.get("part") == "dev" and r.get("speaker") == "all" and r.get("rate") == "native"
            and str(r.get("model", "")).startswith(prefix)}


def lip_rule_figures(real_faces: list[dict] | None, prefix: str = "voices-") -> tuple:
    """The figures of :data:`LIP_RULE` the development faces measure for some candidate."""
    rows = lip_rows(real_faces, prefix)
    return tuple(k for k in LIP_RULE if any(math.isfinite(v[k]) for v in rows.values()))


def dev_parts(results: list[dict], prefix: str = "voices-",
              real_faces: list[dict] | None = None) -> dict:
    """``{model: {"audio": mean, "kinds": {split: mean}, "lips": mean or None}}``: the two
    halves of the score of each model with every used figure finite (module docstring), and the
    audio half's kinds; ``lips`` None for every model when no development faces were scored."""
    splits = audio_splits(results, prefix)
    per = [(dev_rows(results, prefix, k), dev_rule_figures(results, prefix, k)) for k in splits]
    lips, lip_used = lip_rows(real_faces, prefix), lip_rule_figures(real_faces, prefix)
    out = {}
    for m in per[0][0]:
        kinds = {}
        for split, (rows, used) in zip(splits, per):
            v = rows.get(m)
            if v is None or not used or not all(math.isfinite(v[k]) for k in used):
                break
            kinds[split] = sum(v[k] for k in used) / len(used)
        if len(kinds) != len(splits):
            continue
        part = {"audio": sum(kinds.values()) / len(kinds), "kinds": kinds, "lips": None}
        if lip_used:
            lv = lips.get(m)
            if lv is None or not all(math.isfinite(lv[k]) for k in lip_used):
                continue
            part["lips"] = sum(lv[k] for k in lip_used) / len(lip_used)
        out[m] = part
    return out


def dev_score(part: dict) -> float:
    """The rule's score of one model's :func:`dev_parts` entry."""
    if part["lips"] is None:
        return part["audio"]
    return AUDIO_WEIGHT * part["audio"] + LIP_WEIGHT * part["lips"]


def dev_choice(results: list[dict], prefix: str = "voices-", latency: dict | None = None,
               bound_ms: float | None = None, real_faces: list[dict] | None = None
               ) -> tuple[str | None, dict]:
    """``(model, {model: score})``: among the models named ``prefix``*, the one with the highest
    score (module docstring: the audio figures of :func:`dev_rule_figures` on the
    ``unseen-dev`` rows of ``results``, speech_eval's results.csv rows, and with
    ``real_faces``, the ``real_faces`` stage's rows, the lip figures of :func:`lip_rule_figures`
    on the development faces); a model missing one of the used figures gets no score; an exact
    tie goes to the later name; None when no such model has development figures.

    With ``latency`` (``{model: measured stream latency p99, ms, or None}``, e.g.
    :func:`latency_p99`) and ``bound_ms`` (``targets.stream_latency_p99_ms``), a model the bound
    excludes (:func:`excluded_by_latency`: over the bound, or not measured) cannot be the pick,
    whatever its score; the scores still list it. None when the bound excludes every scored
    model."""
    scores = {m: dev_score(p) for m, p in dev_parts(results, prefix, real_faces).items()}
    if not scores:
        return None, {}
    out = excluded_by_latency(results, latency, bound_ms, prefix)
    eligible = [m for m in scores if m not in out]
    best = max(eligible, key=lambda m: (scores[m], m)) if eligible else None
    return best, scores


def deciding_half(parts: dict, best: str | None, scores: dict, excluded=()) -> str:
    """What decided the pick over the runner-up among the eligible models, in words: which half
    of the score (audio or lips) gave the pick its lead."""
    others = [m for m in scores if m != best and m not in excluded]
    if best is None or not others:
        return "no other eligible candidate"
    second = max(others, key=lambda m: (scores[m], m))
    a, b = parts[best], parts[second]
    if a["lips"] is None:
        return f"audio alone (no development faces): {a['audio']:.3f} against {second}'s " \
               f"{b['audio']:.3f}"
    d_audio = AUDIO_WEIGHT * (a["audio"] - b["audio"])
    d_lips = LIP_WEIGHT * (a["lips"] - b["lips"])
    half = "the lips" if d_lips >= d_audio else "the audio"
    return (f"{half}: against the runner-up {second}, lips {a['lips']:.3f} vs "
            f"{b['lips']:.3f}, audio {a['audio']:.3f} vs {b['audio']:.3f}")


def excluded_by_latency(results: list[dict], latency: dict | None, bound_ms: float | None,
                        prefix: str = "voices-") -> dict:
    """``{model: p99 ms or None}``: the candidates of :func:`dev_choice` (models named
    ``prefix``* with development rows) that the latency bound excludes: a measured stream
    latency p99 above ``bound_ms``, or none measured (None: absent from ``latency``, or its
    stream was not paced in real time). Empty when ``latency`` or ``bound_ms`` is None (the
    latency was not measured, or no bound is set)."""
    if latency is None or bound_ms is None:
        return {}
    out = {}
    for m in dev_rows(results, prefix):
        p99 = latency.get(m)
        if p99 is None or not math.isfinite(float(p99)) or float(p99) > bound_ms:
            out[m] = None if p99 is None or not math.isfinite(float(p99)) else float(p99)
    return out


def read_latency(path) -> dict | None:
    """The contents of speech_eval's ``latency.json`` (:mod:`talkingface.stages.latency`:
    ``recording``, ``seconds``, ``paced``, ``models``: ``{model: {latency_p50_ms,
    latency_p99_ms, compute_p99_ms, algorithmic_latency_ms, paced, ...}}``), a folder holding
    it or the file itself; None when there is no such file (the latency was not measured)."""
    path = Path(path)
    path = path / LATENCY_FILE if path.is_dir() else path
    return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None


def latency_p99(latency: dict | None) -> dict | None:
    """``{model: stream latency p99, ms, or None when not paced}`` of :func:`read_latency`'s
    contents; None when the latency was not measured."""
    if latency is None:
        return None
    return {m: v.get("latency_p99_ms") for m, v in (latency.get("models") or {}).items()}
