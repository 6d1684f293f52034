"""The voices grid's default model (``configs/voices.yaml`` ``model:``) re-chosen from a run: the
development rule's pick on the run's real-speech results.

    python tools/choose_voice_model.py RUN_DIR [--voices configs/voices.yaml] [--json] [--check]

Reads ``RUN_DIR/speech_eval/results.csv`` (the ``speech_eval`` stage's table) and prints, for
every voices child (models named ``voices-<child>``), its figures on the unseen development
recordings (``split`` = ``unseen-dev``) named by :data:`analysis.speech_report.DEV_RULE` and the
rule's score, their mean; the pick is :func:`analysis.speech_report.dev_choice`'s (the highest
score; an exact tie goes to the name later in alphabetical order, as ``dev_choice`` breaks it). A
child without finite development figures has no score. ``--check`` compares the pick with the
voices file's ``model`` and exits 1 with one line when they differ.
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from analysis.speech_report import DEV_RULE, dev_choice, dev_rule_figures  # noqa: E402
from groundwork.errors import CorpusError, ParameterError  # noqa: E402

PREFIX = "voices-"
SPLIT = "unseen-dev"
VOICES = REPO / "configs" / "voices.yaml"


def read_results(run_dir) -> list[dict]:
    """The rows of ``RUN_DIR/speech_eval/results.csv``."""
    path = Path(run_dir) / "speech_eval" / "results.csv"
    if not path.is_file():
        raise CorpusError(f"{path}: not found; RUN_DIR must be a run whose speech_eval stage "
                          f"has run")
    with open(path, newline="", encoding="utf-8-sig") as f:
        return list(csv.DictReader(f))


def voices_model(voices=VOICES) -> str:
    """The ``model`` of a voices grid file."""
    data = yaml.safe_load(Path(voices).read_text(encoding="utf-8")) or {}
    model = data.get("model") if isinstance(data, dict) else None
    if not isinstance(model, str) or not model:
        raise ParameterError(f"{voices}: no 'model' naming the default child")
    return model


def choose(results: list[dict]) -> dict:
    """``{"rows": per-child development figures and score, "pick": child or None}``."""
    best, scores = dev_choice(results, prefix=PREFIX)
    rows = []
    for r in results:
        if r.get("split") != SPLIT or not r.get("model", "").startswith(PREFIX):
            continue
        row = {"child": r["model"][len(PREFIX):]}
        for k in DEV_RULE:
            try:
                row[k] = float(r.get(k, "nan"))
            except (TypeError, ValueError):
                row[k] = float("nan")
        for k in ("files", "seconds"):
            if r.get(k) not in (None, ""):
                row[k] = r[k]
        row["score"] = scores.get(r["model"])
        rows.append(row)
    rows.sort(key=lambda row: (row["score"] is None, -(row["score"] or 0.0), row["child"]))
    return {"rows": rows, "pick": best[len(PREFIX):] if best else None,
            "figures": list(dev_rule_figures(results, prefix=PREFIX))}


def table(result: dict, current: str | None) -> str:
    cols = ("child", *DEV_RULE, "score")
    width = max([len(r["child"]) for r in result["rows"]] + [5])
    used = result.get("figures") or list(DEV_RULE)
    left = [k for k in DEV_RULE if k not in used]
    lines = [f"voices children on the unseen development recordings ({SPLIT}); score = mean of "
             + ", ".join(used) + (f" ({', '.join(left)}: not measured on the development part, "
                                  "left out for every child)" if left else ""),
             f"{cols[0]:<{width}}" + "".join(f"{c:>26}" for c in cols[1:])]
    for r in result["rows"]:
        score = "no score" if r["score"] is None else f"{r['score']:.3f}"
        lines.append(f"{r['child']:<{width}}" + "".join(f"{r[k]:>26.3f}" for k in DEV_RULE)
                     + f"{score:>26}")
    lines.append("rule: the highest score (analysis/speech_report.py dev_choice); an exact tie "
                 "to the later name")
    lines.append(f"pick: {result['pick']}"
                 + (f" (configs/voices.yaml model: {current})" if current else ""))
    return "\n".join(lines)


def check_line(result: dict, current: str, voices=VOICES) -> str | None:
    if result["pick"] != current:
        return (f"{voices}: model is {current!r} but the development rule picks "
                f"{result['pick']!r}")
    return None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path, help="a run folder (runs/<name>)")
    ap.add_argument("--voices", type=Path, default=VOICES, help="the voices grid file")
    ap.add_argument("--json", action="store_true", help="print the result as JSON")
    ap.add_argument("--check", action="store_true",
                    help="exit 1 with one line if the voices file's model is not the pick")
    args = ap.parse_args(argv)
    try:
        result = choose(read_results(args.run_dir))
        current = voices_model(args.voices)
    except (CorpusError, ParameterError) as e:
        print(e, file=sys.stderr)
        return 2
    if result["pick"] is None:
        print(f"{args.run_dir / 'speech_eval' / 'results.csv'}: no voices child has development "
              f"figures ({SPLIT} rows of {', '.join(DEV_RULE)})", file=sys.stderr)
        return 2
    if args.check:
        line = check_line(result, current, args.voices)
        print(line or f"{args.voices}: model {current!r} is the development rule's pick",
              file=sys.stderr if line else sys.stdout)
        return 1 if line else 0
    print(json.dumps({**result, "voices_model": current}, indent=1) if args.json
          else table(result, current))
    return 0


if __name__ == "__main__":
    sys.exit(main())
