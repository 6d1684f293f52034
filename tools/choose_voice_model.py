"""The voices grid's default model (``configs/voices.yaml`` ``model:``) re-chosen from a run: the
development rule's pick on the run's real-speech results.

    python tools/choose_voice_model.py RUN_DIR [--voices configs/voices.yaml] [--json] [--check]

Reads ``RUN_DIR/speech_eval/results.csv`` (the ``speech_eval`` stage's table) and prints, for
every voices child (models named ``voices-<child>``), its figures on the unseen development
recordings named by :data:`analysis.dev_rule.DEV_RULE`, per kind (sentences, digits:
``split`` ``unseen-dev-sentences``, ``unseen-dev-digits``; the pooled ``unseen-dev`` for a run
without kinds), the audio half (the mean over the kinds of each kind's mean) and the rule's
score; the pick is :func:`analysis.dev_rule.dev_choice`'s (the highest
score; an exact tie goes to the name later in alphabetical order, as ``dev_choice`` breaks it). A
child without finite development figures has no score.

Time is weighed too: when ``RUN_DIR/speech_eval/latency.json`` is there
(:mod:`talkingface.stages.latency`: each model streamed as ``talkingface stream`` streams it,
paced in real time), each child's measured latency p50/p99 is printed beside its figures, and a
child whose p99 exceeds the bound, or whose latency was not measured, cannot be the pick,
whatever its score (:func:`analysis.dev_rule.excluded_by_latency`). The bound is the run's
``targets.stream_latency_p99_ms`` (``RUN_DIR/speech_eval/config.yaml``; default the paper's
window plus one frame, :data:`analysis.config.PAPER_STREAM_LATENCY_MS`), or ``--bound-ms``.
Without the file the latency was not measured: the table says so and no bound is applied.

Lips are weighed too (issue 50): when ``RUN_DIR/real_faces/results.csv`` is there (the
``real_faces`` stage: every child's lips on the development faces, GRID s26), each child's lip
r on speech frames and /p b m/ closure are printed beside its audio figures, the score is half
audio, half lips (:mod:`analysis.dev_rule`), and the last line says which half decided.
``--check`` compares the pick (the same rule) with the voices file's ``model`` and exits 1 with
one line when they differ.
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

from analysis.config import TargetsConfig  # noqa: E402
from analysis.dev_rule import (AUDIO_KINDS, AUDIO_WEIGHT, DEV_RULE,  # noqa: E402
                               LATENCY_FILE, LIP_RULE, LIP_WEIGHT, dev_rows, audio_splits,
                               deciding_half, dev_choice, dev_parts, dev_rule_figures,
                               excluded_by_latency, latency_p99, lip_rows, lip_rule_figures,
                               read_latency)
from groundwork.errors import CorpusError, ParameterError  # noqa: E402
from groundwork.settings import SettingError  # noqa: E402

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


def read_faces(run_dir) -> list[dict]:
    """The rows of ``RUN_DIR/real_faces/results.csv`` (empty when the run scored no real
    faces: the rule then weighs the audio alone)."""
    path = Path(run_dir) / "real_faces" / "results.csv"
    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8-sig") as f:
        return list(csv.DictReader(f))


def voices_model(voices=VOICES) -> str:
    """The ``model`` of a voices grid file."""
    data = yaml.safe_load(Path(voices).read_text(encoding="utf-8")) or {}
    model = data.get("model") if isinstance(data, dict) else None
    if not isinstance(model, str) or not model:
        raise ParameterError(f"{voices}: no 'model' naming the default child")
    return model


def run_bound(run_dir) -> float:
    """The run's ``targets.stream_latency_p99_ms`` (``RUN_DIR/speech_eval/config.yaml``), else
    the default (:class:`analysis.config.TargetsConfig`)."""
    path = Path(run_dir) / "speech_eval" / "config.yaml"
    data = yaml.safe_load(path.read_text(encoding="utf-8")) if path.is_file() else None
    value = ((data or {}).get("targets") or {}).get("stream_latency_p99_ms")
    if value is None:
        return TargetsConfig().stream_latency_p99_ms
    try:
        return TargetsConfig(stream_latency_p99_ms=value).stream_latency_p99_ms
    except SettingError as e:
        raise ParameterError(f"{path}: targets.{e}") from None


def choose(results: list[dict], latency: dict | None = None,
           bound_ms: float | None = None, faces: list[dict] | None = None) -> dict:
    """``{"rows": per-child development figures (each kind's audio figures, lips), score and
    latency, "pick": child or None, "kinds": the audio half's splits, "figures": {split: the
    figures it measures}, "lip_figures", "decided", "bound_ms", "latency_measured", "excluded":
    children the bound excluded}``; ``latency``: :func:`analysis.dev_rule.read_latency`'s
    contents (None: not measured, no bound applied); ``faces``: the ``real_faces`` stage's rows
    (:func:`read_faces`)."""
    p99 = latency_p99(latency)
    best, scores = dev_choice(results, prefix=PREFIX, latency=p99, bound_ms=bound_ms,
                              real_faces=faces)
    out = excluded_by_latency(results, p99, bound_ms, prefix=PREFIX)
    lips = lip_rows(faces, prefix=PREFIX)
    parts = dev_parts(results, PREFIX, faces)
    kinds = audio_splits(results, PREFIX)
    by_kind = {k: dev_rows(results, PREFIX, k) for k in kinds}
    measured = (latency or {}).get("models") or {}
    rows = []
    for model in sorted(dev_rows(results, PREFIX, SPLIT)):
        row = {"child": model[len(PREFIX):]}
        for k in kinds:
            for fig in DEV_RULE:
                row[f"{AUDIO_KINDS.get(k, 'all')}:{fig}"] = by_kind[k].get(model, {}).get(
                    fig, float("nan"))
        pooled = next(r for r in results if r.get("split") == SPLIT and r["model"] == model
                      and str(r.get("input_rate") or "native") == "native")
        for k in ("files", "seconds"):
            if pooled.get(k) not in (None, ""):
                row[k] = pooled[k]
        row["audio"] = parts[model]["audio"] if model in parts else None
        for k in LIP_RULE:
            row[f"lip_{k}"] = lips.get(model, {}).get(k, float("nan"))
        row["score"] = scores.get(model)
        for k in ("latency_p50_ms", "latency_p99_ms"):
            row[k] = measured.get(model, {}).get(k)
        row["excluded"] = model in out
        rows.append(row)
    rows.sort(key=lambda row: (row["score"] is None, -(row["score"] or 0.0), row["child"]))
    return {"rows": rows, "pick": best[len(PREFIX):] if best else None,
            "kinds": list(kinds),
            "figures": {k: list(dev_rule_figures(results, PREFIX, k)) for k in kinds},
            "lip_figures": list(lip_rule_figures(faces, prefix=PREFIX)),
            "decided": deciding_half(parts, best, scores, out) if best else None,
            "bound_ms": bound_ms if latency is not None else None,
            "latency_measured": latency is not None,
            "excluded": sorted(m[len(PREFIX):] for m in out)}


def _ms(v) -> str:
    return "–" if v is None else f"{v:.0f}"


def _f(v) -> str:
    return "–" if v is None or v != v else f"{v:.3f}"


def table(result: dict, current: str | None) -> str:
    kinds = result.get("kinds") or [SPLIT]
    figures = result.get("figures") or {k: list(DEV_RULE) for k in kinds}
    audio_cols = [f"{AUDIO_KINDS.get(k, 'all')}:{fig}" for k in kinds for fig in figures[k]]
    lip_cols = [f"lip_{k}" for k in LIP_RULE]
    lip_used = result.get("lip_figures") or []
    halves = []
    for k in kinds:
        left = [f for f in DEV_RULE if f not in figures[k]]
        halves.append(f"{AUDIO_KINDS.get(k, 'all')} ({k}): mean of " + ", ".join(figures[k])
                      + (f"; {', '.join(left)}: not measured on the development part, left "
                         "out for every child" if left else ""))
    audio = ("mean of the kinds, equally weighed: " if len(kinds) > 1 else "") + "; ".join(halves)
    lines = [f"voices children on the unseen development recordings ({', '.join(kinds)}) and the "
             "development faces (real_faces, part dev, native rate); score = "
             + (f"{AUDIO_WEIGHT:g} x audio [{audio}] + {LIP_WEIGHT:g} x lips (mean of "
                + ", ".join(lip_used) + ")" if lip_used else
                f"audio alone [{audio}]: the run scored no development faces")]
    cols = audio_cols + ["audio"] + lip_cols + ["score"]
    width = max([len(r["child"]) for r in result["rows"]] + [5])
    cw = max([len(c) for c in cols] + [8]) + 2
    lines.append(f"{'child':<{width}}" + "".join(f"{c:>{cw}}" for c in cols)
                 + f"{'latency p50 ms':>16}{'p99 ms':>16}")
    for r in result["rows"]:
        score = "no score" if r["score"] is None else f"{r['score']:.3f}"
        lines.append(f"{r['child']:<{width}}"
                     + "".join(f"{_f(r.get(c)):>{cw}}" for c in audio_cols + ["audio"] + lip_cols)
                     + f"{score:>{cw}}" + f"{_ms(r.get('latency_p50_ms')):>16}"
                     + f"{_ms(r.get('latency_p99_ms')):>16}"
                     + ("   over the bound" if r.get("excluded") else ""))
    lines.append("rule: the highest score (analysis/dev_rule.py dev_choice); an exact tie "
                 "to the later name")
    if result.get("latency_measured"):
        lines.append(f"latency bound: p99 at most {result['bound_ms']:.1f} ms "
                     "(targets.stream_latency_p99_ms); excluded: "
                     + (", ".join(result["excluded"]) or "none"))
    else:
        lines.append(f"latency: not measured (no speech_eval/{LATENCY_FILE}); no bound applied")
    lines.append(f"pick: {result['pick']}"
                 + (f" (configs/voices.yaml model: {current})" if current else ""))
    if result.get("decided"):
        lines.append(f"decided by {result['decided']}")
    return "\n".join(lines)


def check_line(result: dict, current: str, voices=VOICES) -> str | None:
    if result["pick"] != current:
        over = current in result.get("excluded", [])
        return (f"{voices}: model is {current!r}"
                + (f" (over the latency bound of {result['bound_ms']:.1f} ms)" if over else "")
                + f" but the development rule picks {result['pick']!r}")
    return None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path, help="a run folder (runs/<name>)")
    ap.add_argument("--voices", type=Path, default=VOICES, help="the voices grid file")
    ap.add_argument("--json", action="store_true", help="print the result as JSON")
    ap.add_argument("--check", action="store_true",
                    help="exit 1 with one line if the voices file's model is not the pick")
    ap.add_argument("--bound-ms", type=float, default=None,
                    help="the bound on the latency p99, ms (default: the run's "
                         "targets.stream_latency_p99_ms)")
    args = ap.parse_args(argv)
    try:
        bound = (run_bound(args.run_dir) if args.bound_ms is None else
                 TargetsConfig(stream_latency_p99_ms=args.bound_ms).stream_latency_p99_ms)
        result = choose(read_results(args.run_dir),
                        read_latency(args.run_dir / "speech_eval" / LATENCY_FILE), bound,
                        read_faces(args.run_dir))
        current = voices_model(args.voices)
    except SettingError as e:
        print(f"--bound-ms: {e}", file=sys.stderr)
        return 2
    except (CorpusError, ParameterError) as e:
        print(e, file=sys.stderr)
        return 2
    if result["pick"] is None:
        scored = any(r["score"] is not None for r in result["rows"])
        print(f"{args.run_dir / 'speech_eval'}: the latency bound "
              f"({result['bound_ms']:.1f} ms) excluded every voices child with a score: "
              + ", ".join(result["excluded"]) if scored else
              f"{args.run_dir / 'speech_eval' / 'results.csv'}: no voices child has development "
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
