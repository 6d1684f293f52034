"""The report's section on real faces of people no model was trained on (the ``real_faces``
stage, :mod:`talkingface.stages.real_faces`): the test table (every candidate and peer, speaker
by speaker), the rates, what the development rule saw on the development face, and the first
page's finding. Every figure of the finding is a cell of the test table, printed by
:func:`cell`, so it reads on both pages character for character."""
from __future__ import annotations

import math

from analysis.report import escape

PEERS = ("loudness", "openfacefx-text", "openfacefx-energy", "pylipsync")
PEER_LABELS = {"loudness": "loudness envelope", "openfacefx-text": "openfacefx (transcript, "
               "word times)", "openfacefx-energy": "openfacefx (loudness)",
               "pylipsync": "pylipsync"}


def num(x) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


def cell(row: dict | None, key: str, chance: str) -> str:
    """``0.43 (0.01)``: a figure with its chance in brackets ("–" when absent)."""
    if row is None or math.isnan(num(row.get(key))):
        return "–"
    c = num(row.get(chance))
    return f"{num(row[key]):.2f}" + ("" if math.isnan(c) else f" ({c:.2f})")


def _index(rows: list[dict]) -> dict:
    return {(r["model"], r["part"], r["speaker"], r["rate"]): r for r in rows}


def speakers_tested(rows: list[dict]) -> list[str]:
    """The test part's speakers, those no candidate has seen first."""
    spk = sorted({r["speaker"] for r in rows if r["part"] == "test" and r["speaker"] != "all"})
    seen = {r["speaker"] for r in rows if r["part"] == "test" and r.get("seen") == "True"}
    return sorted(spk, key=lambda s: (s in seen, s))


def _label(model: str, default: str | None) -> str:
    name = PEER_LABELS.get(model, model)
    if model in PEERS:
        return f"{escape(name)} (peer)"
    # a table cell is drawn as it is, not parsed: no markup in it (analysis.report.table)
    return f"{escape(name)} (default)" if model == default else escape(name)


def ordered_models(rows: list[dict], default: str | None) -> list[str]:
    """The default, then the other candidates by r on the first test speaker, then the peers."""
    idx = _index(rows)
    first = (speakers_tested(rows) or [""])[0]
    models = sorted({r["model"] for r in rows} - set(PEERS) - {default})
    models.sort(key=lambda m: -num((idx.get((m, "test", first, "native")) or {}).get(
        "r_speech")) if not math.isnan(num((idx.get((m, "test", first, "native")) or {}).get(
            "r_speech"))) else math.inf)
    return ([default] if default in {r["model"] for r in rows} else []) + models + \
        [p for p in PEERS if p in {r["model"] for r in rows}]


def best_peer(rows: list[dict], speaker: str) -> str | None:
    """The peer with the highest native-rate r on ``speaker``'s test clips."""
    idx = _index(rows)
    rs = {p: num((idx.get((p, "test", speaker, "native")) or {}).get("r_speech"))
          for p in PEERS}
    rs = {p: v for p, v in rs.items() if not math.isnan(v)}
    return max(rs, key=rs.get) if rs else None


def real_faces_section(rep, rows: list[dict], summary: dict) -> None:
    """Add the section (key ``real_faces``; tables ``real_faces_test``, ``real_faces_rates``,
    ``real_faces_dev``) from the stage's ``results.csv`` rows and ``summary.json``."""
    rep.heading("Real faces of people no model was trained on", stage="real_faces",
                key="real_faces")
    if not rows:
        rep.paragraph("No results: the real_faces stage wrote no rows.")
        return
    default = summary.get("default")
    idx = _index(rows)
    speakers = speakers_tested(rows)
    parts = summary.get("parts") or {}
    counts = "; ".join(f"{escape(s)} {n} clips" for p in ("dev", "test")
                       for s, n in ((parts.get(p) or {}).get("clips") or {}).items())
    rep.paragraph(
        "Every candidate model and the lip-sync tools users already use, on real faces, "
        "speaker by speaker (" + counts + "): the development face (GRID s26, on which the "
        "development rule weighs lips) and the test faces, read once after the choice: GRID "
        "s31, whom no model was trained on, and the real speaker's held-out sentences, whom "
        "the models trained on the real speaker's training sentences have <i>seen</i> (marked "
        "*): the unseen speaker decides. Lip r over speech frames (clips z-scored before "
        "pooling) and the share of /p b m/ segments the lips close, each with its chance in "
        "brackets (circular shifts); one speaker per column, so no interval. The transcript "
        "peer is given each clip's own word times. {label:real_faces_test}; "
        "{label:real_faces_rates} gives the same at 16 and 8 kHz; {label:real_faces_dev} what "
        "the development rule saw.")
    header = ["model"]
    for s in speakers:
        header += [f"r {escape(s)}", f"/p b m/ closed {escape(s)}"]
    body = []
    for m in ordered_models(rows, default):
        line = [_label(m, default)]
        for s in speakers:
            r = idx.get((m, "test", s, "native"))
            mark = "*" if r is not None and r.get("seen") == "True" else ""
            line += [cell(r, "r_speech", "chance_r_speech") + mark,
                     cell(r, "closure_rate", "chance_closure_rate")]
        body.append(line)
    real = [idx.get(("loudness", "test", s, "native")) for s in speakers]
    note = ("Real lips close " + ", ".join(
        f"{num(r.get('real_closed_rate')):.2f} of {escape(s)}'s /p b m/ segments"
        for s, r in zip(speakers, real) if r) + " by the same rule. * seen in training.")
    rep.table("Lips of the test speakers: every candidate and peer (native rate)", header, body,
              key="real_faces_test", note=note)
    rates_header = ["model"] + [f"r {escape(s)} {rate}" for s in speakers
                                for rate in ("16 kHz", "8 kHz")]
    rates_body = []
    for m in [default, "speaker-trained", *PEERS]:
        if m is None or not any(k[0] == m for k in idx):
            continue
        rates_body.append([_label(m, default)] + [
            cell(idx.get((m, "test", s, rate)), "r_speech", "chance_r_speech")
            for s in speakers for rate in ("16000", "8000")])
    rep.table("The test speakers' lips with the audio at 16 and 8 kHz", rates_header,
              rates_body, key="real_faces_rates")
    dev = sorted({r["speaker"] for r in rows if r["part"] == "dev" and r["speaker"] != "all"})
    dev_body = [[_label(m, default)] + [
        x for s in dev for x in (cell(idx.get((m, "dev", s, "native")), "r_speech",
                                      "chance_r_speech"),
                                 cell(idx.get((m, "dev", s, "native")), "closure_rate",
                                      "chance_closure_rate"))]
        for m in ordered_models(rows, default)]
    rep.table("Lips of the development speaker (what the development rule weighs)",
              ["model"] + [h for s in dev for h in (f"r {escape(s)}",
                                                    f"/p b m/ closed {escape(s)}")],
              dev_body, key="real_faces_dev")


def real_faces_finding(rows: list[dict], summary: dict) -> str | None:
    """The first page's line: the default's lip r on each test speaker against the best peer's
    there, its /p b m/ closures, and whether the speaker was seen."""
    default = summary.get("default")
    idx = _index(rows)
    speakers = speakers_tested(rows)
    parts = []
    for s in speakers:
        mine = idx.get((default, "test", s, "native"))
        peer = best_peer(rows, s)
        if mine is None or peer is None:
            continue
        theirs = idx.get((peer, "test", s, "native"))
        ahead = num(mine["r_speech"]) > num(theirs["r_speech"])
        seen = " (seen in training)" if mine.get("seen") == "True" else " (never seen)"
        parts.append(f"on {escape(s)}{seen} r {cell(mine, 'r_speech', 'chance_r_speech')} "
                     f"{'ahead of' if ahead else '<b>behind</b>'} the best peer, "
                     f"{escape(PEER_LABELS[peer])}, at "
                     f"{cell(theirs, 'r_speech', 'chance_r_speech')}, /p b m/ closed "
                     f"{cell(mine, 'closure_rate', 'chance_closure_rate')}")
    if not parts:
        return None
    return (f"<b>Real faces never trained on.</b> The default model "
            f"({escape(default)}) moves the lips " + "; ".join(parts)
            + " ({label:real_faces_test}, p. {page:real_faces_test}).")
