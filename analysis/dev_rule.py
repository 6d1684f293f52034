"""The rule that picks the default voice-robust model (``configs/voices.yaml`` ``model:``) on
the development speakers of the real-speech set, never on the test speakers: the highest mean
of :data:`DEV_RULE`'s figures over the unseen development recordings, among the models whose
measured live latency (speech_eval's ``latency.json``, :mod:`talkingface.stages.latency`) is
within ``targets.stream_latency_p99_ms`` (issue 40: a model over it cannot be the default,
whatever its accuracy)."""
from __future__ import annotations

import json
import math
from pathlib import Path

DEV_RULE = ("viseme_acc", "bilabial_closed_frac", "labiodental_contact_frac", "r_reference")
LATENCY_FILE = "latency.json"  # speech_eval: each model's live latency (talkingface.stages.latency)


def _dev_rows(results: list[dict], prefix: str) -> dict:
    """``{model: {figure: value}}`` of :data:`DEV_RULE` on the native-rate ``unseen-dev`` rows of
    the models named ``prefix``* (NaN where a figure is missing)."""
    out = {}
    for r in results:
        if r["split"] != "unseen-dev" or not r["model"].startswith(prefix) or \
                str(r.get("input_rate") or "native") != "native":
            continue
        vals = {}
        for k in DEV_RULE:
            try:
                vals[k] = float(r[k])
            except (KeyError, TypeError, ValueError):
                vals[k] = float("nan")
        out[r["model"]] = vals
    return out


def dev_rule_figures(results: list[dict], prefix: str = "voices-") -> tuple[str, ...]:
    """The figures of :data:`DEV_RULE` the development part measures: a figure it measures for
    no candidate (the digits of the development speakers hold no /p b m/, so no closure can be
    scored) is left out of the rule for all of them alike."""
    rows = _dev_rows(results, prefix)
    return tuple(k for k in DEV_RULE if any(math.isfinite(v[k]) for v in rows.values()))


def dev_choice(results: list[dict], prefix: str = "voices-", latency: dict | None = None,
               bound_ms: float | None = None) -> tuple[str | None, dict]:
    """``(model, {model: score})``: among the models named ``prefix``*, the one with the highest
    mean of :func:`dev_rule_figures` (the figures of :data:`DEV_RULE` the development part
    measures) on the ``unseen-dev`` rows of ``results`` (speech_eval's results.csv rows); a
    model missing one of those figures gets no score; an exact tie goes to the later name; None
    when no such model has development figures.

    With ``latency`` (``{model: measured stream latency p99, ms, or None}``, e.g.
    :func:`latency_p99`) and ``bound_ms`` (``targets.stream_latency_p99_ms``), a model the bound
    excludes (:func:`excluded_by_latency`: over the bound, or not measured) cannot be the pick,
    whatever its score; the scores still list it. None when the bound excludes every scored
    model."""
    rows = _dev_rows(results, prefix)
    used = dev_rule_figures(results, prefix)
    if not used:
        return None, {}
    scores = {m: sum(v[k] for k in used) / len(used) for m, v in rows.items()
              if all(math.isfinite(v[k]) for k in used)}
    out = excluded_by_latency(results, latency, bound_ms, prefix)
    eligible = [m for m in scores if m not in out]
    best = max(eligible, key=lambda m: (scores[m], m)) if eligible else None
    return best, scores


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
    for m in _dev_rows(results, prefix):
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
