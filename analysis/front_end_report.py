"""The report's "The causal front end" subsection (issue 40): what the run's own phone front end
(the ``front_end`` stage, :mod:`talkingface.stages.front_end`) learned from and what it cost to
teach, beside what it gives on real speech against hama, its teacher, and pocketsphinx — each
read from the stage's and speech_eval's files, never typed.

The figures on real speech come from speech_eval's ``results.csv`` (the recogniser rows, whose
model names start with the recogniser's: ``causal-front …``, ``hama-…``, ``pocketsphinx-…``);
the live cost of the models that read it is in the real-speech section's latency table. A recording of one
of the front end's training speakers is *seen* for it and is left out of its unseen rows, so its
rows may hold fewer recordings than hama's: the table states both.
"""
from __future__ import annotations

import csv
from pathlib import Path

KINDS = (("causal", "the causal front end (ours)"), ("hama", "hama (its teacher)"),
         ("pocketsphinx", "pocketsphinx"))
SPLITS = (("unseen-test-independent", "test, independent labels"),
          ("unseen-dev", "development"))


def _rows(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8-sig") as f:
        return list(csv.DictReader(f))


def _num(v, digits: int = 3) -> str:
    try:
        return f"{float(v):.{digits}f}"
    except (TypeError, ValueError):
        return "–"


def training_rows(done: dict) -> list[list[str]]:
    """The front end's training record (the stage's done.json) as table rows."""
    t = done.get("training") or {}
    hist = t.get("history") or []
    teacher = done.get("teacher") or {}
    return [
        ["corpora", ", ".join(f"{k} ({v} utterances, {done['minutes_of_audio'][k]:.1f} min)"
                              for k, v in (done.get("utterances") or {}).items())],
        ["training speakers (seen)", ", ".join(done.get("training_speakers") or [])],
        ["examples (with augmented copies)", str(done.get("examples", "–"))],
        ["teacher pass (hama, whole utterances)",
         f"{done.get('teacher_seconds', 0):.0f} s: {teacher.get('heard', 0)} heard, "
         f"{teacher.get('reused', 0)} from the cache"],
        ["training", f"{done.get('train_seconds', 0):.0f} s, {len(hist)} epochs, the weights "
                     f"of epoch {t.get('best_epoch', '–')} kept"],
        ["held-out loss (training utterances held out)",
         _num(hist[-1]["heldout_loss"]) if hist and hist[-1].get("heldout_loss") is not None
         else "–"],
        ["stage, all told", f"{done.get('seconds', 0):.0f} s"]]


def accuracy_rows(results: list[dict], key: str) -> list[list[str]]:
    """Per recogniser and split: recordings, speakers, viseme accuracy whole and streaming."""
    body = []
    for split, title in SPLITS:
        for kind, name in KINDS:
            r = next((r for r in results if r["model"].startswith(kind)
                      and r["split"] == split and str(r.get("input_rate") or "native")
                      == "native"), None)
            if r is None or r.get("files") in ("", "0", None):
                continue
            body.append([name, title, f"{r.get('speakers', '–')} / {r['files']}",
                         _num(r.get("viseme_acc")), _num(r.get(key))])
    return body


def front_end_section(rep, done: dict | None, speech_dir: Path) -> None:
    """Add the subsection when the run trained its front end (``done``: the stage's
    done.json; None: it did not)."""
    if not done:
        return
    rep.heading("The causal front end", level=2, key="front_end")
    rep.paragraph("The run teaches its own phone front end (mapping/causal_front.py): a small "
                  "causal network over log-mel frames that names the phone of every 10-ms step "
                  "with 0–100 ms of look-ahead, taught by hama's whole-utterance phones and the "
                  "corpus's labels. {label:front_end_training} gives what it learned from and "
                  "what teaching it cost.")
    rep.table("The causal front end's training (front_end/done.json)", ["", ""],
              training_rows(done), key="front_end_training", stage="front_end",
              note="A recording of a training speaker is seen, and scored apart, for the front "
                   "end and for every model that reads it.")
    results = _rows(Path(speech_dir) / "results.csv")
    key = next((k for k in (results[0] if results else {}) if k.startswith(
        "viseme_acc_stream_")), "viseme_acc_stream_100ms")
    body = accuracy_rows(results, key)
    if body:
        rep.table("The causal front end beside hama and pocketsphinx on real speech, native "
                  "rate (speech_eval/results.csv)",
                  ["recogniser", "recordings", "speakers / recordings", "viseme acc, whole",
                   "viseme acc, " + key.rsplit("_", 1)[-1]], body, key="front_end_accuracy",
                  note="The causal front end has no whole-utterance reading: its 'whole' is its "
                       "stream at its longest look-ahead.")
