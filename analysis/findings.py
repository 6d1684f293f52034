"""The report's first page: what the run found, each headline figure with its interval and the
table or figure (and page) that shows it.

Every figure here is read from the same stage files as the section that shows it and printed by
the same formatting function as that section's table cell, so a number on the first page is,
character for character, a number on the page it cites (``tests/analysis/test_findings.py``
checks it on a built report). A finding whose stage did not run is left out; nothing here is
computed that the cited tables do not show.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from analysis import real_face_tables as face
from analysis import real_steps_report as real_steps
from analysis import speech_report as speech
from analysis.config import TargetsConfig
from analysis.grid_summary import (best, delta_cell, fmt, fmt_level, fmt_p, grid_summary,
                                   read_replicates)
from analysis.mapping_report import _f, ci_cell, lookahead_rows_for_report, r_cell
from analysis.metrics import PAPER_TABLES
from analysis.report import escape
from groundwork.errors import TalkingFaceError
from groundwork.modelfile import read_model
from mapping import checkpoint

KEEP = 0.95  # the share of R the look-ahead finding asks the mapping to keep


def _read(path: Path) -> list[dict]:
    if not Path(path).is_file():
        return []
    with open(path, newline="", encoding="utf-8-sig") as f:
        return list(csv.DictReader(f))


def _cite(key: str) -> str:
    return f"({{label:{key}}}, p. {{page:{key}}})"


def table_ii_finding(mapping: dict, method: str) -> str | None:
    """Our Table II against the paper's: the range of test R over expressions per split."""
    rows = [r for r in mapping.get("rows", []) if r["method"] == method and r["part"] == "test"]
    if not rows:
        return None
    paper = [v[0] for v in PAPER_TABLES["test"].values()]
    parts = []
    for split, name in (("random_frames", "the paper's frame split"),
                        ("utterance", "the utterance split")):
        rs = [r["R"] for r in rows if r["split"] == split]
        if rs:
            parts.append(f"{_f(min(rs))}–{_f(max(rs))} on {name}")
    return (f"<b>Table II.</b> Our test R per expression ({escape(method)}, one seed) is "
            + " and ".join(parts) + f", against the paper's {_f(min(paper))}–{_f(max(paper))} "
            + _cite("table_ii") + ".")


def ablation_finding(ab_dir: Path) -> str | None:
    """The best setting of the ablations and whether it differs from the reference."""
    ab = _read(ab_dir / "results.csv")
    if not ab or not (ab_dir / "replicates.csv").is_file():
        return None
    reference = next((r["setting"] for r in ab if "reference" in
                      (r.get("utterance_R_differs"), r.get("random_frames_R_differs"))),
                     ab[0]["setting"])
    summary = grid_summary(read_replicates(ab_dir / "replicates.csv"), reference=reference)
    split = summary[0]["split"]
    ref = summary[0]
    top = best(summary, split)
    n = summary[0]["seeds"]
    text = (f"<b>Best method.</b> Over {n} training seeds the paper's setting "
            f"(<i>{escape(reference)}</i>) reaches test R {fmt(ref['R'])} ± "
            f"{fmt(ref['R_ci95'])} on the {split} split. ")
    if top["verdict"] == "reference":
        text += "No other setting of the grid does better. "
    else:
        verdict = {"better": "significantly better (Holm-corrected paired test)",
                   "worse": "significantly worse",
                   "no difference": "not significantly different after Holm's correction",
                   "not tested": "not tested (one seed)"}[top["verdict"]]
        text += (f"The best is <i>{escape(top['setting'])}</i>: {fmt(top['R'])} ± "
                 f"{fmt(top['R_ci95'])}, Δ {delta_cell(top)} (Holm-adjusted interval, "
                 f"{fmt_level(top['ci_level'])}), p (Holm) {fmt_p(top['p_holm'])} — {verdict}. ")
    worse = sum(r["verdict"] == "worse" for r in summary if r["split"] == split)
    better = sum(r["verdict"] == "better" for r in summary if r["split"] == split)
    return (text + f"{better} setting{'s' * (better != 1)} differ{'s' * (better == 1)} for "
            f"the better and {worse} for the worse " + _cite("ablations")
            + "; the forest plot " + _cite("forest") + ".")


def lookahead_finding(ab_dir: Path, method: str, split: str = "utterance") -> str | None:
    """The least algorithmic latency at which ``method`` keeps :data:`KEEP` of the R of the
    paper's window (the look-ahead table's rows)."""
    rows = lookahead_rows_for_report(_read(ab_dir / "results.csv"), split)
    mine = [r for r in rows if r["method"] == method]
    ref = next((r for r in mine if not str(r["setting"]).startswith("lookahead-")), None)
    curve = sorted((r for r in mine if str(r["setting"]).startswith("lookahead-")),
                   key=lambda r: float(r["latency_ms"]))
    if ref is None or not curve:
        return None
    target = KEEP * float(ref[f"{split}_R"])
    keep = next((r for r in curve if float(r[f"{split}_R"]) >= target), None)
    head = (f"<b>Look-ahead.</b> With the paper's window ({_f(float(ref['latency_ms']), 1)} ms) "
            f"{escape(method)} reaches R {ci_cell(ref, f'{split}_R')}; ")
    if keep is None:
        return head + (f"no shorter look-ahead of the grid keeps {100 * KEEP:.0f} % of it "
                       + _cite("lookahead") + ".")
    return head + (f"it keeps {100 * KEEP:.0f} % of that from {_f(float(keep['latency_ms']), 1)}"
                   f" ms on (<i>{escape(keep['setting'])}</i>: {ci_cell(keep, f'{split}_R')}) "
                   + _cite("lookahead") + ".")


def ceiling_finding(ceiling_dir: Path) -> str | None:
    """Where the gap to the paper goes: our R, without the corpus's nuisances, the oracle."""
    rows = {r["step"]: r for r in _read(ceiling_dir / "results.csv")}
    if not rows:
        return None
    paper = sum(v[0] for v in PAPER_TABLES["test"].values()) / len(PAPER_TABLES["test"])
    first = next(iter(rows))
    names = [(first, "ours"), ("all-off", "every nuisance of the corpus off"),
             ("oracle", "the oracle reading the true phones"),
             ("all-off-oracle", "both"), ("tracked", "learning from tracked MUPs")]
    parts = [f"{label} {ci_cell(rows[s], 'random_frames_R')}" for s, label in names if s in rows]
    return ("<b>The gap to the paper.</b> On the paper's frame split, mean test R: "
            + "; ".join(parts) + f"; the paper {_f(paper)} " + _cite("ceiling") + ".")


def _stream_key(rows: list[dict], targets: TargetsConfig) -> str | None:
    """The streaming viseme column at the targets' look-ahead, else the first one the rows
    have (the one the speech section shows)."""
    keys = [k for k in (rows[0] if rows else {}) if k.startswith("viseme_acc_stream_")]
    want = f"viseme_acc_stream_{targets.lookahead_ms:g}ms"
    return want if want in keys else (keys[0] if keys else None)


def speech_finding(speech_dir: Path, default_model: str | None,
                   targets: TargetsConfig | None = None) -> str | None:
    """The default model on the unseen test speakers, streaming, against the recognisers
    streaming at the same look-ahead and against the target: each figure as the section's
    table prints it (:func:`analysis.speech_report._cell`: the value, its speaker-level
    interval, the chance baseline), with the speakers and recordings behind it."""
    targets = targets or TargetsConfig()
    rows = [r for r in speech._rows(speech_dir / "results.csv")
            if r["split"] == "unseen-test" and r.get("files") not in ("", "0", None)
            and str(r.get("input_rate") or "native") == "native"]
    if not rows:
        return None
    model = f"voices-{default_model}" if default_model else "gated_mlp_utterance"
    mine = next((r for r in rows if r["model"] == model), None)
    key = _stream_key(rows, targets)
    if mine is None or key is None:
        return None
    ms = key.rsplit("_", 1)[-1].replace("ms", " ms")
    bars = [r for r in rows if r["model"].startswith(speech.RECOGNISERS)]
    value = speech._num(mine.get(key))
    text = (f"<b>Real speech.</b> On the unseen test speakers ({mine.get('speakers') or 0} "
            f"speakers, {mine.get('files') or 0} recordings) the default model "
            f"(<i>{escape(model)}</i>) streaming at {ms} labels visemes at "
            f"{speech._cell(mine, key, chance=False)}")
    if value != "–":
        met = float(mine[key]) >= targets.viseme_accuracy
        text += (f": {'at or above' if met else 'below'} the target of "
                 f"{targets.viseme_accuracy:g} {_cite('targets')}")
    if bars:
        text += "; the recognisers streaming at the same look-ahead reach " + " and ".join(
            f"{escape(b['model'].split()[0].split('-')[0])} "
            f"{speech._cell(b, key, chance=False)}"
            for b in bars)
    tally = speech.speaker_tally(speech_dir, model, key)
    if tally:
        text += (f"; per speaker, streaming it is "
                 + speech.tally_text(tally, "unseen sentence speakers") + " "
                 + _cite("speech_per_speaker"))
    return text + (f"; it closes the lips on {speech._cell(mine, 'bilabial_closed_frac')} of "
                   "/p b m/ segments (in brackets: chance) " + _cite("speech_unseen-test")
                   + ".")


def drawn_with(tfmap) -> str:
    """The ``synth.articulation`` the model at ``tfmap`` was trained under (its recorded
    config): ``table`` for the hand table, or when the file cannot be read."""
    try:
        meta = read_model(Path(tfmap), kind=checkpoint.KIND, versions=(checkpoint.VERSION,),
                          what="mapping").metadata
    except (TypeError, OSError, TalkingFaceError):
        return "table"
    config = (meta.get("metadata") or {}).get("config") or {}  # AudioMapping.metadata
    return str((config.get("synth") or {}).get("articulation") or "table")


def real_speaker_finding(real_dir: Path, targets: TargetsConfig | None = None) -> str | None:
    """The synthetic-trained default on the real speaker's held-out sentences: speech-frame lip
    r and /p b m/ closures, each with its chance in brackets, against the targets, the
    loudness envelope and the peers — saying plainly whether the default beats each, and where
    it does not, by how much (its cell beside theirs). Every figure is a cell of the section's
    table (:func:`analysis.real_face_tables.face_rows`), character for character."""
    targets = targets or TargetsConfig()
    try:
        summary = json.loads((Path(real_dir) / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    cells = {key: row for (key, _), row in zip(face.SCORE_ROWS, face.face_rows(summary, targets))}
    r = {key: face.num(face.pooled_of(summary, key).get("r_speech")) for key, _ in face.SCORE_ROWS}
    mine = cells.get("synthetic_model")
    if mine is None or math.isnan(r["synthetic_model"]):
        return None
    p = face.pooled_of(summary, "synthetic_model")
    checks = {c["key"]: c["verdict"] for c in face.target_checks(summary, targets)}
    spk = (summary.get("corpus") or {}).get("speaker", "the speaker")
    speakers = p.get("speakers", "?")
    no_interval = "no interval" in str(p.get("interval_r_speech") or "no interval")
    drawn = drawn_with((summary.get("models") or {}).get("synthetic_model"))
    faces = ("faces only" if drawn == "table" else
             f"faces drawn with the articulation {escape(drawn)}, fitted on a real mouth")
    text = (f"<b>A real face.</b> On {escape(p.get('clips', '?'))} held-out sentences of "
            f"{escape(spk)} ({escape(speakers)} speaker{'s' * (speakers != 1)}"
            f"{': no interval' if no_interval else ''}) the default model, trained on synthetic "
            f"speech and {faces}, moves the lips with r {mine[1]} on speech frames (in "
            f"brackets: chance; target {targets.face_synthetic_r:g}: "
            f"{checks.get('face_synthetic_r', 'not measured')}) and closes {mine[4]} of the "
            f"/p b m/ segments (target {100 * targets.face_closures:.0f} %: "
            f"{checks.get('face_closures', 'not measured')}) {_cite('targets')}")
    peers = [(key, label.replace(" (peer)", "")) for key, label in face.PEER_ROWS
             if not math.isnan(r.get(key, math.nan))]
    beaten = [label for key, label in peers if r["synthetic_model"] > r[key]]
    behind = [(key, label) for key, label in peers if r["synthetic_model"] <= r[key]]
    if peers and not behind:
        text += "; in r it beats the loudness envelope and every peer: " + ", ".join(
            f"{escape(label)} {cells[key][1]}" for key, label in peers)
    elif behind:
        text += ("; in r it does <b>not</b> beat " + ", ".join(
            f"the {escape(label)} ({cells[key][1]} against its {mine[1]})"
            for key, label in behind)
            + (f"; it beats: {'; '.join(escape(x) for x in beaten)}" if beaten else ""))
    if not math.isnan(r.get("speaker_model", math.nan)):
        text += (f"; the model trained on this speaker reaches r "
                 f"{cells['speaker_model'][1]} (target {targets.face_speaker_r:g}: "
                 f"{checks.get('face_speaker_r', 'not measured')})")
    return text + " " + _cite("real_face_scores") + "."


def real_steps_finding(stage_dir: Path) -> str | None:
    """Where the real speaker's R goes: the trained steps (the run's mapping on both splits,
    the recogniser and the oracle), the measurement floor and the cheek units, each figure as
    its table prints it (:mod:`analysis.real_steps_report`)."""
    try:
        steps = json.loads((Path(stage_dir) / "steps.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    trained = {r["step"]: r for r in real_steps.read_trained(stage_dir)}
    parts = []
    if "ours" in trained:
        ours = trained["ours"]
        text = (f"the run's mapping reaches R {r_cell(ours, 'utterance')} on held-out "
                f"sentences and {r_cell(ours, 'random_frames')} on the paper's frame split")
        others = [(k, label) for k, label in (("hama-phones", "hama's phones"),
                                              ("oracle", "the true phones"))
                  if k in trained]
        if others:
            text += "; with " + ", with ".join(
                f"{label} {r_cell(trained[k], 'utterance')}" for k, label in others)
        parts.append(text + " " + _cite("real_steps_trained"))
    floor = {str(k): v for k, v in steps.get("smoothing_floor", {}).items()}
    text = (f"the Motion Units keep R {_f(steps['reconstruction_r'])} of the markers' motion and "
            f"the truth against its smoothed self is R {_f(floor['3'])}")
    regions, definition = steps.get("regions", {}), steps.get("definition", {})
    if {"paper", "pixels"} <= set(definition):
        text += (f"; a linear audio probe reaches R {_f(definition['paper'])}, and "
                 f"{_f(definition['pixels'])} in pixels without Eq. 6's division by each "
                 "coordinate's largest displacement")
    if {"lips", "forehead"} <= set(regions):
        lips, brow = regions["lips"], regions["forehead"]
        text += (f"; the probe reaches R {_f(lips['r'])} on the lips' coordinates and "
                 f"{_f(brow['r'])} on the brows and forehead's, which Eq. 6 weighs about alike "
                 f"({100 * lips['weight']:.0f} % and {100 * brow['weight']:.0f} %)")
    text += " " + _cite("real_steps")
    units = steps.get("units", [])
    cheek = [u for u in units if u["cheeks"] > real_steps.CHEEK_DOMINATED]
    if cheek:
        text += (f"; units mostly on the cheeks hold "
                 f"{100 * sum(u['variance_share'] for u in cheek):.0f} % of the variance, which "
                 f"the audio predicts at R {_f(max(u['r_audio'] for u in cheek))} at most "
                 + _cite("real_steps_units"))
    parts.append(text)
    return ("<b>Where the real speaker's R goes.</b> On its training sentences alone, "
            + "; ".join(parts) + ".")


def study_finding(study: dict | None) -> str | None:
    """FLMP or WTAV per face, by BIC, and who the participants were."""
    models = (study or {}).get("models") or {}
    faces = models.get("faces") or {}
    if not all(f in faces for f in ("synthetic", "real")):
        return None
    parts = []
    for face in ("synthetic", "real"):
        f = faces[face]
        pref = f["comparison"]["preferred"]
        parts.append(f"{pref.upper()} for the {face} face (BIC FLMP {f['flmp']['bic']:.1f}, "
                     f"WTAV {f['wtav']['bic']:.1f})")
    who = ("simulated participants (FLMP observers), so this checks the analysis, not "
           "people" if study["simulated"] else "real participants")
    return (f"<b>Perception study.</b> {study['participants']} {who}: the data prefer "
            + " and ".join(parts) + " " + _cite("models") + ".")


def findings(*, mapping: dict | None, method: str, ab_dir: Path, ceiling_dir: Path,
             speech_dir: Path, default_model: str | None, study: dict | None,
             has: set, targets: TargetsConfig | None = None,
             real_dir: Path | None = None, steps_dir: Path | None = None) -> list[str]:
    """The findings of a run whose report has the parts ``has`` (the keys its sections
    registered), in the order of the paper's questions; ``targets``: the run's
    :class:`~analysis.config.TargetsConfig`; ``real_dir``: the real_speaker stage's folder;
    ``steps_dir``: the real_steps stage's."""
    items = [
        table_ii_finding(mapping or {}, method) if "table_ii" in has else None,
        ablation_finding(ab_dir) if {"ablations", "forest"} <= has else None,
        lookahead_finding(ab_dir, method) if "lookahead" in has else None,
        ceiling_finding(ceiling_dir) if "ceiling" in has else None,
        speech_finding(speech_dir, default_model, targets)
        if {"speech_unseen-test", "targets"} <= has else None,
        real_speaker_finding(real_dir, targets)
        if real_dir is not None and {"real_face_scores", "targets"} <= has else None,
        real_steps_finding(steps_dir)
        if steps_dir is not None and {"real_steps", "real_steps_units"} <= has else None,
        study_finding(study) if "models" in has else None,
    ]
    return [i for i in items if i and not (isinstance(i, float) and math.isnan(i))]
