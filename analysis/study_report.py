"""The perception-study part of the PDF (paper §VII-C): the stimulus set and who took part.
The tallies, statistics and models of Tables III–VII come from the study analysis. Reads the
stage folders only."""
from __future__ import annotations

import csv
import json
from pathlib import Path


def study_section(report, stimuli_dir: Path, study_dir: Path | None) -> None:
    report.heading("Perception study (§VII-C): stimuli and participants", stage="stimuli",
                   key="study")
    info = json.loads((stimuli_dir / "stimuli.json").read_text())
    sentences = ", ".join(f"\"{t}\"" for t in info["sentences"].values())
    report.paragraph(
        f"Stimuli: the sentences {sentences}, read calmly (the expressions' own prosody is off, "
        "so every face of a sentence shares its audio track) by the run's speaker. Synthetic "
        "face: the trained mapping's MUPs from that audio with each expression. Real face: the "
        "generator's ground-truth markers of the same sentence spoken with that expression, "
        "head motion removed. Both drawn by the same renderer; "
        f"{info['n_stimuli']} stimuli with SHA-256 checksums in the manifest.")
    sheet = stimuli_dir / "contact_sheet.png"
    if sheet.is_file():
        report.paragraph("{label:contact_sheet} shows the middle frame of each visual-only "
                         "stimulus.")
        report.figure(sheet, "The middle frame of each visual-only stimulus (\"It is normal.\"), "
                      "synthetic and real face, neutral, smile and sad.", width=0.75,
                      key="contact_sheet")
    if study_dir is None or not (study_dir / "allocation.csv").is_file():
        return
    with open(study_dir / "allocation.csv", newline="", encoding="utf-8-sig") as f:
        slots = list(csv.DictReader(f))
    done = [s for s in slots if s["status"] == "complete"]
    rows = [[seq, sum(s["sequence"] == seq for s in slots),
             sum(s["sequence"] == seq for s in done)] for seq in ("SR", "RS")]
    simulated = (study_dir / "simulated.json").is_file()
    report.paragraph("{label:allocation} gives the bimodal order of each slot and how many "
                     "sessions were completed.")
    report.table("Allocation: bimodal order per slot (SR: synthetic face first)",
                 ["sequence", "slots", "complete sessions"], rows,
                 note="Permuted blocks of four from the run seed, written before any session. "
                      + ("Participants are simulated FLMP observers (study/simulate.py)."
                         if simulated else "Participants are people."), key="allocation")
