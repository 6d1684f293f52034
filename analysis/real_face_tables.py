"""The tables of the report's real-speaker section (:mod:`analysis.real_face_report`): their rows.

Every cell is read from the ``real_speaker`` stage's ``summary.json`` (a dict here) and formatted
by :func:`fmt` or :func:`pct`; the target verdicts come from :func:`target_checks`. A findings
page (:mod:`analysis.findings`) that uses these functions prints the section's numbers
character for character. A missing value is a ``–`` cell, never an error.

Tables: the face scores of every model and peer (:func:`face_rows`, one per
:data:`SCORE_ROWS`), the speech-frame r by input rate (:func:`rate_rows`), Tables I–II and the
lip metrics of :data:`METHOD` beside the synthetic corpus and the paper (:func:`tables_rows`,
:func:`lip_rows`), and the peers' channel tables (:func:`mapping_rows`).
"""
from __future__ import annotations

import math
from pathlib import Path

from analysis.config import TargetsConfig
from analysis.report import escape

METHOD = "gated_mlp"  # the paper's mapping, shown in the Tables I-II comparison
SCORE_ROWS = (("speaker_model", "speaker-trained model"),
              ("synthetic_model", "synthetic-trained default model"),
              ("loudness", "loudness envelope (peer)"),
              ("openfacefx-text", "openfacefx, transcript (peer)"),
              ("openfacefx-energy", "openfacefx, loudness (peer)"),
              ("pylipsync", "pylipsync (peer)"))
PEER_ROWS = SCORE_ROWS[2:]


def num(v) -> float:
    """``v`` as a float; NaN for None, ``""`` or anything that is not a number."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def fmt(v, digits: int = 3) -> str:
    """``v`` with ``digits`` decimals, or ``–`` when absent."""
    x = num(v)
    return "–" if math.isnan(x) else f"{x:.{digits}f}"


def pct(v, digits: int = 2) -> str:
    """A fraction as a percentage (``97.56 %``), or ``–`` when absent."""
    x = num(v)
    return "–" if math.isnan(x) else f"{100 * x:.{digits}f} %"


def pooled_of(summary: dict, key: str) -> dict:
    """The pooled face scores of model or peer ``key`` (a key of :data:`SCORE_ROWS`): the dict
    under ``face_scores/<key>/pooled`` of the summary, or ``{}`` when absent."""
    return ((summary.get("face_scores") or {}).get(key) or {}).get("pooled") or {}


def target_checks(summary: dict, targets: TargetsConfig = TargetsConfig()) -> list[dict]:
    """The real-face targets of ``targets`` each checked against the stage's scores.

    Returns
    -------
    list of dict
        ``model`` (a key of :data:`SCORE_ROWS`), ``what`` (``r``, ``closures`` or ``rate``),
        ``key`` (the field of :class:`analysis.config.TargetsConfig`), ``target``, ``value``
        (speech-frame r; the share of /p b m/ segments closed; for ``rate`` the drop of the
        speech-frame r from the corpus's rate to 16 kHz; NaN when absent) and ``verdict``:
        ``met``, ``not met`` or ``not measured``.
    """
    rates = summary.get("rates") or {}
    native = str(summary.get("input_rate", ""))
    out = []
    for key, model, what, value in (
            ("face_speaker_r", "speaker_model", "r",
             pooled_of(summary, "speaker_model").get("r_speech")),
            ("face_synthetic_r", "synthetic_model", "r",
             pooled_of(summary, "synthetic_model").get("r_speech")),
            ("face_closures", "synthetic_model", "closures",
             pooled_of(summary, "synthetic_model").get("closure_rate"))):
        out.append({"model": model, "what": what, "key": key, "target": getattr(targets, key),
                    "value": num(value)})
    for model in ("speaker_model", "synthetic_model"):
        a = num(((rates.get(native) or {}).get(model) or {}).get("r_speech"))
        b = num(((rates.get("16000") or {}).get(model) or {}).get("r_speech"))
        out.append({"model": model, "what": "rate", "key": "rate_tolerance",
                    "target": targets.rate_tolerance, "value": a - b})
    for c in out:
        v = c["value"]
        ok = v <= c["target"] if c["what"] == "rate" else v >= c["target"]
        c["verdict"] = "not measured" if math.isnan(v) else "met" if ok else "not met"
    return out


def models_text(models: dict) -> str:
    """The model files (their last three path parts) in a sentence."""
    named = [f"{label} {escape('/'.join(Path(str(models[key])).parts[-3:]))}"
             for key, label in SCORE_ROWS if models.get(key)]
    return f"Models: {'; '.join(named)}." if named else "The summary names no model files."


def _check_text(c: dict) -> str:
    if c["what"] == "r":
        return f"r ≥ {c['target']:.2f}: {c['verdict']}"
    if c["what"] == "closures":
        return f"closures ≥ {100 * c['target']:.0f} %: {c['verdict']}"
    return f"drop ≤ {c['target']:.2f}: {c['verdict']}"


def _with_chance(v, chance, digits: int = 3, percent: bool = False) -> str:
    f = (lambda x: pct(x, 0)) if percent else (lambda x: fmt(x, digits))
    return "–" if math.isnan(num(v)) else f"{f(v)} ({f(chance)})"


def face_rows(summary: dict, targets: TargetsConfig) -> list[list]:
    """The rows of the face-score table, one per :data:`SCORE_ROWS` entry in its order.

    Returns
    -------
    list of list of str
        Per row: label; r speech, r silence (each with its chance in brackets); median r per
        clip; /p b m/ closed ``k/n rate (chance)``; false closures (chance); LVE in px (the
        speaker-trained model only); the verdicts of its r and closure targets, or ``–``.
    """
    checks = target_checks(summary, targets)
    rows = []
    for key, label in SCORE_ROWS:
        p = pooled_of(summary, key)
        k, n = num(p.get("closures_hit")), num(p.get("bilabial_segments"))
        rate = _with_chance(p.get("closure_rate"), p.get("chance_closure_rate"), percent=True)
        closed = "–" if math.isnan(k) or math.isnan(n) else f"{int(k)}/{int(n)} {rate}"
        lve = fmt(p.get("lve_px"), 2) if key == "speaker_model" else "–"
        target = "; ".join(_check_text(c) for c in checks if c["model"] == key
                           and c["what"] != "rate")
        rows.append([label, _with_chance(p.get("r_speech"), p.get("chance_r_speech")),
                     _with_chance(p.get("r_silence"), p.get("chance_r_silence")),
                     fmt(p.get("r_clip_median")), closed,
                     _with_chance(p.get("false_closure_rate"),
                                  p.get("chance_false_closure_rate"), percent=True),
                     lve, target or "–"])
    return rows


def rate_rows(summary: dict, targets: TargetsConfig) -> tuple[list, list]:
    """The speech-frame r of the two models at each input rate, highest rate first.

    Returns
    -------
    rows : list of list of str
        Per model: label, r at each rate of ``order``, the drop to 16 kHz, its verdict.
    order : list of str
        The rates (Hz, as the summary's keys), highest first.
    """
    rates = summary.get("rates") or {}
    order = sorted(rates, key=lambda r: -num(r))
    checks = {c["model"]: c for c in target_checks(summary, targets) if c["what"] == "rate"}
    rows = []
    for key, label in SCORE_ROWS[:2]:
        cells = [fmt(((rates.get(r) or {}).get(key) or {}).get("r_speech")) for r in order]
        c = checks.get(key)
        rows.append([label, *cells, fmt(c["value"]) if c else "–",
                     _check_text(c) if c else "–"])
    return rows, order


def peer_sentences(summary: dict) -> list[str]:
    """Plain sentences where the default does not beat a peer (r, closures, false closures)."""
    d = pooled_of(summary, "synthetic_model")
    out = []
    for key, label in PEER_ROWS:
        p = pooled_of(summary, key)
        name = label.replace(" (peer)", "")
        for field, what, better in (("r_speech", "speech-frame r", 1),
                                    ("closure_rate", "share of /p b m/ closed", 1),
                                    ("false_closure_rate", "false-closure rate", -1)):
            a, b = num(d.get(field)), num(p.get(field))
            if math.isnan(a) or math.isnan(b) or better * (a - b) > 0:
                continue
            fig = (lambda x: fmt(x)) if field == "r_speech" else (lambda x: pct(x, 0))
            if field == "false_closure_rate":
                text = (f"its {what} ({fig(a)}) is above that of the {name} ({fig(b)})"
                        if a > b else f"its {what} equals that of the {name} ({fig(a)})")
            else:
                gap = fmt(b - a) if field == "r_speech" else pct(b - a, 0)
                text = (f"its {what} ({fig(a)}) is below the {name}'s ({fig(b)}) by {gap}"
                        if b > a else f"its {what} equals the {name}'s ({fig(a)})")
            out.append(text)
    return out


def mapping_rows(table: dict) -> list[list]:
    """``[channel, opening (2 decimals), viseme]`` per channel of a peer's table
    ``{channel: (opening, viseme)}`` (:data:`mapping.peers.OCULUS_TABLE`, ...), escaped."""
    return [[escape(ch), f"{o:.2f}", escape(v)] for ch, (o, v) in table.items()]


def _rows_by(rows: list, method: str = METHOD) -> dict:
    """``{(split, part): row}`` of the neutral rows of ``method``."""
    return {(r.get("split"), r.get("part")): r for r in rows or []
            if r.get("method") == method and r.get("expression", "neutral") == "neutral"}


def tables_rows(summary: dict) -> list[list]:
    """Tables I–II of :data:`METHOD` (neutral speech): per split and part, R, ν_d, ν_d of the
    estimate and MSE each on the real corpus, the synthetic corpus and in the paper."""
    real, syn = (_rows_by((summary.get("tables") or {}).get(k)) for k in ("real", "synthetic"))
    out = []
    for split in ("random_frames", "utterance"):
        for part in ("train", "test"):
            r, s = real.get((split, part), {}), syn.get((split, part), {})
            if not (r or s):
                continue
            row = [split, part]
            for m, d in (("R", 3), ("nu_d", 3), ("nu_d_est", 3), ("MSE", 4)):
                paper = r.get(f"paper_{m}", "") or s.get(f"paper_{m}", "")
                row += [fmt(r.get(m), d), fmt(s.get(m), d), fmt(paper, d)]
            out.append(row)
    return out


def lip_rows(summary: dict) -> list[list]:
    """The lip metrics of :data:`METHOD` on the testing set, per split: LVE (px), R lips and the
    share of /p b m/ segments closed (``share of n``), each real then synthetic."""
    real, syn = (_rows_by((summary.get("tables") or {}).get(k)) for k in ("real", "synthetic"))

    def closed(r):
        n = num(r.get("bilabial_segments"))
        return (f"{fmt(r.get('closure'), 2)} of {int(n)}" if not math.isnan(n) and n > 0
                else "–")
    out = []
    for split in ("random_frames", "utterance"):
        r, s = real.get((split, "test"), {}), syn.get((split, "test"), {})
        cells = [fmt(r.get("LVE"), 2), fmt(s.get("LVE"), 2), fmt(r.get("R_lips")),
                 fmt(s.get("R_lips")), closed(r), closed(s)]
        if any(c != "–" for c in cells):
            out.append([split, *cells])
    return out
