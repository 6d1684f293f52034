"""Compare the result tables of two runs: identical, or how far apart per column.

    python tools/compare_runs.py runs/A runs/B [--tolerance 0.01] [--json]

For each table a replication writes (Tables I–II, the ablation and look-ahead results, the
ceiling, the voices, real speech) it prints whether the two files are byte-identical and, when
not, the largest absolute difference of each numeric column that differs (columns of times —
``seconds``, ``fit_seconds`` — are skipped: they are measurements of the machine, not results)
and the rows that do not match. Exit status 1 when a figure differs by more than
``--tolerance`` or a table is missing in one run but not the other.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path

TABLES = ("mapping/tables.csv", "mapping/ranking_utterance.csv",
          "mapping/ranking_random_frames.csv", "ablations/results.csv",
          "ablations/replicates.csv", "ceiling/results.csv", "ceiling/replicates.csv",
          "voices/results.csv", "speech_eval/results.csv", "speech_eval/per_file.csv",
          *(f"analysis/table_{t}.csv" for t in ("III", "IV", "V", "VI", "VII")))
TIMES = ("seconds", "fit_seconds", "feature_seconds")


def _rows(path: Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8-sig") as f:
        return list(csv.DictReader(f))


def _number(text: str):
    try:
        return float(text)
    except (TypeError, ValueError):
        return None


def compare_table(a: Path, b: Path) -> dict:
    """``{"identical": bool, "columns": {col: max |diff|}, "text": [cells that differ as
    text]}`` of two CSV tables with the same rows."""
    if a.read_bytes() == b.read_bytes():
        return {"identical": True, "columns": {}, "text": []}
    ra, rb = _rows(a), _rows(b)
    out = {"identical": False, "columns": {}, "text": []}
    if len(ra) != len(rb):
        out["text"].append(f"{len(ra)} rows against {len(rb)}")
        return out
    for i, (x, y) in enumerate(zip(ra, rb)):
        for col in dict.fromkeys([*x, *y]):
            if col in TIMES or x.get(col) == y.get(col):
                continue
            u, v = _number(x.get(col)), _number(y.get(col))
            if u is None or v is None or math.isnan(u) != math.isnan(v):
                out["text"].append(f"row {i + 1} {col}: {x.get(col)!r} against {y.get(col)!r}")
            elif not math.isnan(u):
                out["columns"][col] = max(out["columns"].get(col, 0.0), abs(u - v))
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("a", type=Path)
    p.add_argument("b", type=Path)
    p.add_argument("--tolerance", type=float, default=0.01)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    report, worst, bad = {}, 0.0, False
    for name in TABLES:
        fa, fb = args.a / name, args.b / name
        if not fa.is_file() and not fb.is_file():
            continue
        if fa.is_file() != fb.is_file():
            report[name] = {"missing in": str(args.b if fa.is_file() else args.a)}
            bad = True
            continue
        r = report[name] = compare_table(fa, fb)
        worst = max([worst, *r["columns"].values()])
        bad |= bool(r["text"])
    bad |= worst > args.tolerance
    if args.json:
        print(json.dumps({"tables": report, "largest_difference": worst,
                          "tolerance": args.tolerance, "within": not bad}))
        return int(bad)
    for name, r in report.items():
        if "missing in" in r:
            print(f"{name}: missing in {r['missing in']}")
        elif r["identical"]:
            print(f"{name}: identical")
        else:
            cols = ", ".join(f"{c} {d:.2g}" for c, d in sorted(r["columns"].items(),
                                                              key=lambda kv: -kv[1])[:8])
            print(f"{name}: differs (largest per column: {cols or 'none'})")
            for t in r["text"][:5]:
                print(f"    {t}")
    print(f"largest difference of a figure: {worst:.3g} (tolerance {args.tolerance:g}): "
          f"{'within' if not bad else 'NOT within'}")
    return int(bad)


if __name__ == "__main__":
    sys.exit(main())
