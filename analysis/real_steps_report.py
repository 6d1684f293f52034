"""The report's subsection "Where the real speaker's R goes": the ``real_steps`` stage's rows
(:mod:`talkingface.stages.real_steps`: the probe's ``steps.json`` and the trained steps'
``results.csv``), each with the question it answers, and the Motion Units the audio can and
cannot predict. Every figure is the stage's; the sentences under the tables are computed from
them. A missing file becomes a sentence, not an error.
"""
from __future__ import annotations

import csv
import json
from pathlib import Path

from analysis.mapping_report import ci_cell, r_cell, seeds_note
from analysis.report import escape

STAGE = "real_steps"
CHEEK_DOMINATED = 0.5  # a unit whose squared loading is over half on the cheek markers
REGION_NAMES = {"lips": "lips", "cheeks": "cheeks", "forehead": "brows and forehead",
                "glasses": "glasses"}  # the stage's regions in words (plural nouns)


def _f(x) -> str:
    return f"{float(x):.3f}"


def step_rows(steps: dict) -> list[list[str]]:
    """``[step, question, R]`` rows of the steps table (keys of ``steps.json`` as strings or
    numbers: JSON makes the dictionaries' numeric keys strings)."""
    get = {str(k): v for k, v in steps.get("context", {}).items()}
    oracle = {str(k): v for k, v in steps.get("oracle", {}).items()}
    smooth = {str(k): v for k, v in steps.get("smoothing_floor", {}).items()}
    lags = {int(k): v for k, v in steps.get("offset", {}).get("r", {}).items()}
    best = steps.get("offset", {}).get("best")
    rows = [
        ["Motion Units", "How much of the markers' motion do the utterance MUs keep? (markers "
         "against their reconstruction)", _f(steps["reconstruction_r"])],
        ["Landmark jitter", "How much of the truth is frame-to-frame noise? (the truth against "
         "its 3-frame moving average)", _f(smooth["3"])],
        ["Probe at the pipeline's context", "What does a linear model of ±3 frames of MFCC "
         "reach?", _f(get["3"])],
    ]
    definition = steps.get("definition", {})
    if "markers" in definition:
        rows.append(["Truth: the markers", "Scored against the aligned markers instead of "
                     "their MU reconstruction?", _f(definition["markers"])])
    if "pixels" in definition:
        rows.append(["Eq. 6 undivided", "Scored in pixels, without dividing each coordinate "
                     "by its largest displacement?", _f(definition["pixels"])])
    if best is not None and lags:
        rows.append(["Audio–video offset", f"Does shifting the face against the sound help? "
                     f"(best of −6…+6 frames: {int(best):+d}; at 0: {_f(lags[0])})",
                     _f(lags[int(best)])])
    widest = max(get, key=int)
    rows.append(["Wider audio context", f"Does more audio help? (±{widest} frames)",
                 _f(get[widest])])
    if oracle:
        rows.append(["Oracle phones", "If the true phones (forced alignment) replaced the "
                     "audio? (one-hot, ±6 frames)", _f(oracle["6"])])
    curve = {int(k): v for k, v in steps.get("learning_curve", {}).items()}
    if len(curve) > 1:
        sizes = sorted(curve)
        proj = steps.get("learning_projection")
        more = (f"; {proj['per_doubling']:+.3f} per doubling, so {proj['sentences']} sentences "
                f"would give about {_f(proj['r'])}" if proj else "")
        rows.append(["More data", "What do more training sentences buy? (the probe fitted on "
                     + ", ".join(f"{n}: {_f(curve[n])}" for n in sizes) + " sentences"
                     + more + ")", _f(curve[sizes[-1]])])
    if "oracle_and_audio" in steps:
        rows.append(["Oracle phones and audio", "Both together (±6 frames)",
                     _f(steps["oracle_and_audio"])])
    for name, r in steps.get("regions", {}).items():
        rows.append([f"{REGION_NAMES.get(name, name).capitalize()} only",
                     f"What does the probe reach on the {REGION_NAMES.get(name, name)}' "
                     f"coordinates alone? ({100 * r['weight']:.0f} % of what Eq. 6 weighs)",
                     _f(r["r"])])
    return rows


def unit_rows(steps: dict) -> list[list[str]]:
    """Per Motion Unit: variance share, loadings on lips, cheeks, forehead and sideways, R."""
    return [[str(u["unit"]), f"{100 * u['variance_share']:.1f} %", f"{u['lips']:.2f}",
             f"{u['cheeks']:.2f}", f"{u['forehead']:.2f}", f"{u['x']:.2f}", _f(u["r_audio"])]
            for u in steps.get("units", [])]


def units_sentence(steps: dict) -> str:
    """What the per-unit rows show, from the rows: the best-predicted unit, and the share and
    best R of the units whose loading is mostly on the cheeks."""
    units = steps.get("units", [])
    if not units:
        return ""
    top = max(units, key=lambda u: u["r_audio"])
    cheek = [u for u in units if u["cheeks"] > CHEEK_DOMINATED]
    text = (f"The audio predicts unit {top['unit']} best (R {_f(top['r_audio'])}; "
            f"{100 * top['variance_share']:.0f} % of the variance, "
            f"{100 * top['lips']:.0f} % of its loading on the lips).")
    if cheek:
        share = sum(u["variance_share"] for u in cheek)
        best = max(u["r_audio"] for u in cheek)
        names = ", ".join(str(u["unit"]) for u in cheek)
        text += (f" Units {names}, mostly on the cheeks, hold {100 * share:.0f} % of the "
                 f"variance and reach at most R {_f(best)}: motion the audio does not carry.")
    return text


# the trained steps of configs/real_steps.yaml: child → the question its row answers
TRAINED_QUESTIONS = {
    "ours": "The run's mapping: the paper's gate (44 phone-class mixtures on the MFCC)",
    "pocketsphinx": "If pocketsphinx's phones (trained on real speech) drive the gate?",
    "hama": "If hama's phones drive the gate?",
    "hama-phones": "If the MLPs also read hama's phones instead of the MFCC (the default "
                   "model's front end)?",
    "oracle": "If the true phones and their timing replaced the audio (gate and MLPs)?",
}


def read_trained(stage_dir) -> list[dict]:
    """The trained steps' rows (``results.csv``), or [] when the stage has none."""
    path = Path(stage_dir) / "results.csv"
    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def trained_rows(rows: list[dict]) -> list[list[str]]:
    """``[step, question, R utterance, R frame split, frame − utterance, /p b m/ closed]``."""
    out = []
    for r in rows:
        try:
            gap = f"{float(r['random_frames_R']) - float(r['utterance_R']):+.3f}"
        except (KeyError, ValueError):
            gap = "–"
        out.append([escape(r["step"]), escape(TRAINED_QUESTIONS.get(r["step"], "")),
                    r_cell(r, "utterance"), r_cell(r, "random_frames"), gap,
                    ci_cell(r, "utterance_closure", 2)])
    return out


def trained_sentence(rows: list[dict]) -> str:
    """What the trained rows show, from the rows: the best step against ``ours`` on the
    utterance split, and the frame split's gain over it."""
    by = {r["step"]: r for r in rows}
    if "ours" not in by:
        return ""
    ours = float(by["ours"]["utterance_R"])
    top = max(rows, key=lambda r: float(r["utterance_R"]))
    text = (f"On the training sentences' own held-out sentences, the run's mapping reaches R "
            f"{ours:.3f}; the best step is {escape(top['step'])} (R "
            f"{float(top['utterance_R']):.3f}).")
    if "oracle" in by:
        oracle = by["oracle"]
        r = float(oracle["utterance_R"])
        if oracle.get("utterance_R_differs") == "True" and r > ours:
            text += (f" The true phones raise R to {r:.3f} in a paired test over seeds: part "
                     "of the gap is the phones the audio gives.")
        elif oracle.get("utterance_R_differs") in ("True", "False"):
            text += (f" The true phones reach R {r:.3f}, not higher than the run's mapping in "
                     "a paired test over seeds: knowing the phones exactly does not close the "
                     "gap.")
        else:
            text += f" The true phones reach R {r:.3f}."
    gap = float(by["ours"]["random_frames_R"]) - ours
    text += (f" The paper's random-frame split adds {gap:+.3f} to the run's mapping (test "
             "frames between training frames of the same sentence).")
    return text


def real_steps_section(rep, stage_dir) -> None:
    """Add the subsection from ``stage_dir/steps.json`` (keys for a findings page: tables
    ``real_steps`` and ``real_steps_units``)."""
    rep.heading("Where the real speaker's R goes", level=2, stage=STAGE, key="real_steps_section")
    try:
        steps = json.loads((Path(stage_dir) / "steps.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        rep.paragraph(f"No steps: the stage's steps.json could not be read "
                      f"({escape(type(e).__name__)}).")
        return
    rep.paragraph(
        f"Measured on the real speaker's {steps['training_sentences']} training sentences "
        f"({steps['frames']:,} frames) only; the held-out sentences are not read. One probe "
        "for every row: a ridge regression from the audio to the MUPs fitted on every other "
        "training sentence and scored by Eq. 6 as Table II is (the paper's truth: the MUs' "
        "reconstruction, each coordinate divided by its largest displacement) on the rest, "
        "then the other way round, so that the rows differ only in what they change. Eq. 6 "
        "weighs every coordinate by its variance after that division, so a marker that "
        "hardly moves counts as much as the lips. {label:real_steps} gives the steps, "
        "{label:real_steps_units} the Motion Units.")
    rep.table("Where the real speaker's R goes: one step at a time, training sentences",
              ["step", "question", "R"], step_rows(steps),
              note="Deterministic probe: no seed, so no interval; "
                   "tools/real_speaker_steps.py prints the same rows.", key="real_steps")
    rep.table("The real speaker's utterance Motion Units: where they move and what the audio "
              "predicts of each (ridge, ±6 frames of MFCC)",
              ["unit", "variance", "lips", "cheeks", "forehead", "sideways", "R audio"],
              unit_rows(steps),
              note="lips, cheeks, forehead: the share of the unit's squared loading on that "
                   "region's markers; sideways: on the x coordinates.", key="real_steps_units")
    sentence = units_sentence(steps)
    if sentence:
        rep.paragraph(sentence)
    trained = read_trained(stage_dir)
    if not trained:
        return
    rep.paragraph(
        "The pipeline itself, one change at a time: each row trains the mapping on the "
        "training sentences only (each seed its own split of them) and scores it by Eq. 6 on "
        "both of the paper's splits. {label:real_steps_trained} gives the rows.")
    rep.table("Where the real speaker's R goes: the trained pipeline, training sentences",
              ["step", "question", "R (utterance)", "R (frame split)", "frame − utt.",
               "/p b m/ closed"], trained_rows(trained),
              note=seeds_note(trained, "utterance",
                              "every row trains on the real speaker's training sentences")
                   + " Each row is an MLflow child run of "
                   "the real_steps parent run (configs/real_steps.yaml).",
              key="real_steps_trained")
    sentence = trained_sentence(trained)
    if sentence:
        rep.paragraph(sentence)
