"""Shared helpers for the bench scripts: a fresh paper-size corpus and figure printing."""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def parse_args(description: str) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.add_argument("--repeat", type=int, default=3, help="timed repetitions (the best is kept)")
    return p.parse_args()


def report(figures: dict, as_json: bool) -> None:
    figures = {"cores": os.cpu_count(), **figures}
    if as_json:
        print(json.dumps(figures))
    else:
        for k, v in figures.items():
            print(f"{k:>28s}: {v:.3f}" if isinstance(v, float) else f"{k:>28s}: {v}")
