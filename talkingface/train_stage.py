"""The train stage: the audio-to-MUP mapping and its baselines on both splits (paper §VI, §VII-A).

Reads ``runs/<name>/corpus`` and ``runs/<name>/units``; writes ``runs/<name>/mapping/``:

    tables.csv        every method × split × expression × train/test: R, ν, ν', MSE, paper values
    ranking_<split>.csv   methods ranked by mean test R
    gate.json         gate accuracy per split, the small-class merges
    confusion_<split>.csv/.png  the gate's confusion on neutral test frames (true class per row)
    <method>_<split>.tfmap the primary method trained on each split (AudioMapping file)
    trajectories.png  predicted vs true MUPs of test sentences
    done.json         the config and a summary
"""
from __future__ import annotations

import csv
import json
import time
from pathlib import Path

from talkingface.config import dump_config, to_dict


def _write_csv(path: Path, rows: list[dict]) -> Path:
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return path


def train_and_evaluate(corpus_dir: Path, units_path: Path, out_dir: Path, cfg, *,
                       methods=None, splits=None, progress: bool = True) -> dict:
    """Train and evaluate ``methods`` (default: the primary method and every baseline) on
    ``splits``; write the stage folder and return its summary."""
    from analysis.evaluation import ranking, run_experiment, table_rows
    from analysis.figures import confusion_matrix, mup_trajectories
    from face_model.corpus import corpus_hash, load_corpus
    from face_model.motion_units import MotionUnits
    from mapping.dataset import build_dataset
    from mapping.model import AudioMapping

    m = cfg.mapping
    corpus = load_corpus(corpus_dir)
    units = MotionUnits.load(units_path)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    data = build_dataset(corpus, units, n_mfcc=m.n_mfcc, deltas=m.deltas)
    feature_seconds = time.perf_counter() - t0
    results = run_experiment(data, units, m, seed=cfg.seed, methods=methods, splits=splits,
                             progress=progress)
    rows = table_rows(results)
    _write_csv(out_dir / "tables.csv", rows)
    splits_run = list(dict.fromkeys(r.split for r in results))
    ranks = {s: ranking(results, s) for s in splits_run}
    for s, rk in ranks.items():
        _write_csv(out_dir / f"ranking_{s}.csv", rk)
    gate, models = {}, {}
    meta = {"corpus_hash": corpus_hash(corpus_dir), "seed": cfg.seed, "config": to_dict(cfg)}
    for r in results:
        if r.gate is not None:
            conf = r.gate.pop("confusion")
            gate[f"{r.method}/{r.split}"] = r.gate
            with open(out_dir / f"confusion_{r.split}.csv", "w", newline="") as f:
                w = csv.writer(f)
                w.writerow(["true\\gated", *r.gate["class_names"]])
                for name, row in zip(r.gate["class_names"], conf):
                    w.writerow([name, *row.tolist()])
            confusion_matrix(conf, r.gate["class_names"], out_dir / f"confusion_{r.split}.png",
                             title=f"Gate confusion, neutral test frames ({r.split} split)")
        if r.method == m.method:
            path = out_dir / f"{r.method}_{r.split}.tfmap"
            AudioMapping(r.mapper, sample_rate=corpus.utterances[0].sample_rate,
                         fps=corpus.utterances[0].fps, n_mfcc=m.n_mfcc, deltas=m.deltas,
                         n_utterance=units.n_utterance,
                         metadata={**meta, "split": r.split}).save(path)
            models[r.split] = str(path.name)
    (out_dir / "gate.json").write_text(json.dumps(gate, indent=1))
    traj = mup_trajectories(_trajectory_items(data, results, m, units.n_utterance),
                            out_dir / "trajectories.png")
    held = next((r for r in results if r.split == "utterance"), None)
    test_utts = ([d.utt_id for d, mk in zip(data, held.masks) if not mk.any()]
                 if held is not None else [])
    summary = {"rows": rows, "ranking": ranks, "gate": gate, "models": models,
               "test_utterances": test_utts,
               "feature_seconds": feature_seconds, "trajectories": traj.name,
               "fit_seconds": {f"{r.method}/{r.split}": r.fit_seconds for r in results},
               "config": to_dict(cfg)}
    dump_config(cfg, out_dir / "config.yaml")
    (out_dir / "done.json").write_text(json.dumps(summary, indent=1, default=float))
    return summary


def _trajectory_items(data, results, mcfg, n_utterance: int) -> list[dict]:
    """For one test sentence per expression (utterance split if run): the true MUPs and the
    estimates of the primary method and of the best-ranked baseline."""
    from analysis.evaluation import ranking

    split = "utterance" if any(r.split == "utterance" for r in results) else results[0].split
    by = {r.method: r for r in results if r.split == split}
    others = [x["method"] for x in ranking(results, split) if x["method"] != mcfg.method]
    shown = [mcfg.method] + others[:1]
    masks = by[mcfg.method].masks if mcfg.method in by else next(iter(by.values())).masks
    items = []
    for expr in dict.fromkeys(d.expression for d in data):
        idx = [i for i, d in enumerate(data) if d.expression == expr and not masks[i].any()]
        if not idx:  # random_frames: every sentence has training frames; take the first
            idx = [i for i, d in enumerate(data) if d.expression == expr]
        i = idx[0]
        items.append({"title": f"{data[i].utt_id} ({expr}, {split} split)",
                      "truth": data[i].mups, "n_utterance": n_utterance,
                      "estimates": {meth: by[meth].predictions[i] for meth in shown if meth in by}})
    return items


def train_metrics(summary: dict, primary: str) -> dict:
    """MLflow metrics: the primary method as ``<split>.<expression>.<part>.<metric>``, every
    other method under ``baseline.<method>.``, gate accuracy and training times."""
    out = {}
    for r in summary["rows"]:
        prefix = "" if r["method"] == primary else f"baseline.{r['method']}."
        for k in ("R", "nu_d", "nu_d_est", "MSE"):
            out[f"{prefix}{r['split']}.{r['expression']}.{r['part']}.{k}"] = r[k]
    for key, g in summary["gate"].items():
        split = key.split("/")[1]
        out.update({f"gate.{split}.{k}": v for k, v in g.items() if isinstance(v, float)})
    for key, sec in summary["fit_seconds"].items():
        method, split = key.split("/")
        out[f"fit_seconds.{method}.{split}"] = sec
    for split, rk in summary["ranking"].items():
        for x in rk:
            out[f"rank.{split}.{x['method']}"] = x["rank"]
    out["feature_seconds"] = summary["feature_seconds"]
    return out


def log_train(mlf, summary: dict, out_dir: Path, cfg) -> None:
    """Log the train stage to the active MLflow run: metrics, tables, plots, models, pyfunc."""
    from talkingface.pyfunc import log_mapping_model

    mlf.log_metrics(train_metrics(summary, cfg.mapping.method))
    for p in sorted(out_dir.iterdir()):
        if p.suffix in (".csv", ".json", ".png", ".yaml", ".tfmap"):
            mlf.log_artifact(str(p), "mapping")
    models = summary["models"]
    if models:
        split = "utterance" if "utterance" in models else next(iter(models))
        log_mapping_model(mlf, out_dir / models[split], name="mapping")
