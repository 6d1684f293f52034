"""The stage pipeline: each stage reads and writes folders under ``runs/<name>/``.

A stage writes ``done.json`` (its config and results) last; a re-run of ``replicate`` with the
same config reuses completed stages, and a different config for an existing run is refused unless
``overwrite`` is given, so nothing is silently mixed or lost.
"""
from __future__ import annotations

import json
from contextlib import nullcontext
import shutil
import time
from dataclasses import replace
from pathlib import Path

import yaml

from talkingface.config import dump_config, to_dict
from talkingface.paths import RunPaths
from talkingface.tracking import mlflow_run
from face_model.errors import ParameterError


def _done(stage_dir: Path, name: str = "done.json") -> dict | None:
    p = stage_dir / name
    return json.loads(p.read_text()) if p.is_file() else None


def _mark_done(stage_dir: Path, cfg, results: dict) -> None:
    dump_config(cfg, stage_dir / "config.yaml")
    (stage_dir / "done.json").write_text(json.dumps({"config": to_dict(cfg), **results},
                                                    indent=1))


def prepare_run(paths: RunPaths, cfg, *, overwrite: bool) -> None:
    """Create ``runs/<name>``; refuse a different config on an existing run unless overwrite."""
    if paths.config.is_file():
        old = yaml.safe_load(paths.config.read_text())
        if old != to_dict(cfg):
            if not overwrite:
                raise ParameterError(
                    f"{paths.root} was made with a different config; choose another --name, or "
                    f"pass --overwrite to replace it (compare {paths.config})")
            shutil.rmtree(paths.root)
    paths.root.mkdir(parents=True, exist_ok=True)
    dump_config(cfg, paths.config)


def stage_synth(paths: RunPaths, cfg, *, progress: bool = True) -> dict:
    """Generate the corpus (reused when already complete for this config)."""
    from data_synth.generate import synthesize_corpus
    from face_model.corpus import corpus_hash

    def made_by(c: dict) -> tuple:  # what determines the corpus (workers only sets the speed)
        return c["seed"], {k: v for k, v in c["synth"].items() if k != "workers"}

    done = _done(paths.corpus)
    if done and made_by(done["config"]) == made_by(to_dict(cfg)):
        return done
    t0 = time.perf_counter()
    synthesize_corpus(paths.corpus, cfg.synth, cfg.seed, overwrite=True, progress=progress)
    results = {"seconds": time.perf_counter() - t0, "corpus_hash": corpus_hash(paths.corpus)}
    _mark_done(paths.corpus, cfg, results)
    return _done(paths.corpus)


def stage_units(corpus_dir: Path, out_dir: Path, cfg) -> dict:
    """Fit the Motion Units on a corpus folder; writes the model and a variance table."""
    from analysis.foundation import summarize_units
    from face_model.corpus import corpus_hash, load_corpus
    from face_model.motion_units import fit_corpus_units

    corpus = load_corpus(corpus_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    units, _ = fit_corpus_units(corpus, n_utterance=cfg.units.n_utterance,
                                n_expression=cfg.units.n_expression,
                                alignment=cfg.units.alignment,
                                metadata={"corpus_hash": corpus_hash(corpus_dir)})
    seconds = time.perf_counter() - t0
    units.save(out_dir / "motion_units.npz")
    summary = summarize_units(units)
    with open(out_dir / "variance.csv", "w") as f:
        f.write("motion_units,number,explained,paper\n")
        for k, v in summary["explained"].items():
            n = units.n_utterance if k == "neutral" else units.n_expression
            f.write(f"{k},{n},{v:.6f},{summary['paper'][k]}\n")
    results = {"seconds": seconds, "summary": summary}
    _mark_done(out_dir, cfg, results)
    return results


def _trained_by(c: dict) -> tuple:  # what determines the mapping results
    from talkingface.motion_stage import tracked_by

    tracked = tracked_by(c) if c["mapping"].get("visual_source") == "tracked" else None
    return (c["seed"], {k: v for k, v in c["synth"].items() if k != "workers"}, c["units"],
            c["mapping"], tracked)


def training_corpus(paths: RunPaths, cfg, *, progress: bool = True) -> Path:
    """The corpus the mapping learns from: the run's corpus (``mapping.visual_source:
    markers``) or its tracked copy (``tracked``, made here when missing)."""
    if cfg.mapping.visual_source == "markers":
        return paths.corpus
    from talkingface.motion_stage import stage_track_corpus

    stage_track_corpus(paths.corpus, paths.units_model, paths.tracked, cfg, progress=progress)
    return paths.tracked


def stage_train(paths: RunPaths, cfg, *, progress: bool = True, mlf=None) -> dict:
    """Train and evaluate the mapping and the baselines (reused when done for this config)."""
    from talkingface.train_stage import log_train, train_and_evaluate

    done = _done(paths.mapping)
    if not (done and _trained_by(done["config"]) == _trained_by(to_dict(cfg))):
        corpus_dir = training_corpus(paths, cfg, progress=progress)
        t0 = time.perf_counter()
        train_and_evaluate(corpus_dir, paths.units_model, paths.mapping, cfg,
                           progress=progress)
        done = _done(paths.mapping)
        done["seconds"] = time.perf_counter() - t0
    if mlf is not None:
        log_train(mlf, done, paths.mapping, cfg)
    return done


def stage_ablate(paths: RunPaths, cfg, grid_path, *, workers: int = 0, progress: bool = True,
                 mlf=None, nested: bool = True) -> list[dict]:
    """Every setting of an ablation grid as a child run (see :mod:`talkingface.ablate`).

    The children hang under a parent run: a new nested run of the active run (``nested``), or
    the active run itself."""
    from talkingface.ablate import load_grid, run_ablations

    grid = load_grid(grid_path, cfg)
    with (mlf.start_run(run_name=f"ablations:{Path(grid_path).stem}", nested=True)
          if mlf is not None and nested else nullcontext()):
        if mlf is not None:
            mlf.set_tags({"stage": "ablate", "grid": str(grid_path)})
        rows = run_ablations(grid, training_corpus(paths, cfg, progress=progress),
                             paths.units_model, paths.ablations,
                             workers=workers, progress=progress, mlf=mlf)
        if mlf is not None:
            mlf.log_artifact(str(paths.ablations / "results.csv"), "ablations")
    return rows


def stage_report(paths: RunPaths, cfg) -> Path:
    """Summaries and figures from the run's stage folders, then ``reports/<name>.pdf``."""
    from analysis.foundation import corpus_section, make_figures, summarize_corpus, units_section
    from analysis.report import Report
    from face_model.corpus import load_corpus
    from face_model.motion_units import MotionUnits

    corpus = load_corpus(paths.corpus)
    units = MotionUnits.load(paths.units_model)
    summary = {"corpus": summarize_corpus(corpus), "units": _done(paths.units)["summary"]}
    paths.report_dir.mkdir(parents=True, exist_ok=True)
    dump_config(cfg, paths.report_dir / "config.yaml")
    (paths.report_dir / "summary.json").write_text(json.dumps(summary, indent=1))
    figs = make_figures(corpus, units, summary, paths.report_dir)
    rep = Report(f"talkingface replication: {paths.name}",
                 "Hong, Wen &amp; Huang (2002), Real-Time Speech-Driven Face Animation with "
                 "Expressions Using Neural Networks — rebuilt on a synthetic corpus")
    corpus_section(rep, summary["corpus"], figs)
    units_section(rep, summary["units"], figs)
    if _done(paths.mapping):
        from analysis.mapping_report import mapping_section

        ablations = paths.ablations / "results.csv"
        mapping_section(rep, _done(paths.mapping), paths.mapping,
                        ablations if ablations.is_file() else None)
    if _done(paths.root / "keyframes"):
        from analysis.motion_report import motion_section

        motion_section(rep, paths.root / "keyframes", paths.root / "render",
                       paths.root / "tracking")
    if (paths.root / "stimuli" / "stimuli.json").is_file():
        from analysis.study_report import study_section

        study_section(rep, paths.root / "stimuli", paths.root / "study_data")
    study = _done(paths.root / "analysis", "analysis.json")
    if study is not None:
        from analysis.perception_report import perception_section

        perception_section(rep, study, paths.root / "analysis")
    methods_section(rep, cfg, corpus.info, study=study)
    return rep.build(paths.pdf)


def methods_section(rep, cfg, corpus_info: dict, *, study: dict | None = None) -> None:
    from talkingface.tracking import git_commit

    rep.heading("Settings and versions")
    rep.paragraph(f"Source commit {git_commit()}; run seed {cfg.seed}. Every table and figure "
                  "above was computed by the pipeline from this run's folders.")
    if study is not None:
        who = "simulated (FLMP observers)" if study["simulated"] else (
            "real people" if not study["any_simulated"] else "partly simulated")
        rep.paragraph(f"Perception study: {study['participants']} participants, {who}; study "
                      f"seed {cfg.seed} (allocation list and trial orders), Monte Carlo, "
                      f"bootstrap and power simulations seeded with {cfg.seed}.")
    versions = corpus_info.get("versions", {})
    rep.table("Package versions", ["package", "version"], sorted(versions.items()))
    flat = [[f"{sec}.{k}", json.dumps(v)] for sec, vals in to_dict(cfg).items()
            if isinstance(vals, dict) for k, v in vals.items()]
    rep.table("Resolved configuration", ["key", "value"], flat, col_widths=[200, 250])


def replicate(name: str, cfg, *, overwrite: bool = False, progress: bool = True,
              runs_dir="runs", reports_dir="reports", ablation_grid=None,
              workers: int = 0) -> Path:
    """Run every stage into ``runs/<name>`` and write ``reports/<name>.pdf``; log to MLflow.

    ``ablation_grid``: a grid file whose settings are trained as child runs and tabulated in
    the report (None: no ablations)."""
    from face_model.corpus import corpus_hash

    paths = RunPaths.create(name, runs_dir=runs_dir, reports_dir=reports_dir)
    prepare_run(paths, cfg, overwrite=overwrite)
    with mlflow_run(cfg, run_name=name, tags={"stage": "replicate"}) as mlf:
        synth = stage_synth(paths, cfg, progress=progress)
        units = stage_units(paths.corpus, paths.units, cfg)
        from talkingface.motion_stage import stage_keyframes, stage_render, stage_tracking
        stage_keyframes(paths.corpus, paths.units_model, paths.root / "keyframes", cfg)
        stage_tracking(paths.corpus, paths.units_model, paths.root / "tracking", cfg)
        training_corpus(paths, cfg, progress=progress)  # tracked copy (visual_source tracked)
        stage_train(paths, cfg, progress=progress, mlf=mlf)
        stage_render(paths.root, paths.root / "render", cfg)
        from talkingface.study_cli import stage_analyze, stage_simulate, stage_stimuli
        stage_stimuli(paths.root, cfg, progress=progress)
        stage_simulate(paths.root, cfg)
        stage_analyze(paths.root, cfg)
        if ablation_grid:
            stage_ablate(paths, cfg, ablation_grid, workers=workers, progress=progress, mlf=mlf)
        pdf = stage_report(paths, cfg)
        if mlf is not None:
            mlf.set_tag("corpus_hash", synth.get("corpus_hash") or corpus_hash(paths.corpus))
            info = json.loads((paths.corpus / "corpus.json").read_text())
            mlf.log_metrics({"corpus.n_frames": info["n_frames"],
                             "corpus.n_utterances": info["n_utterances"],
                             "corpus.seconds": synth["seconds"],
                             "units.fit_seconds": units["seconds"],
                             **{f"units.explained.{k}": v
                                for k, v in units["summary"]["explained"].items()}})
            mlf.log_artifact(str(paths.config))
            mlf.log_artifact(str(paths.units / "variance.csv"), "units")
            mlf.log_artifact(str(paths.units_model), "units")
            mlf.log_artifacts(str(paths.report_dir), "report")
            mlf.log_artifact(str(pdf))
    return pdf


def with_synth(cfg, **changes):
    """``cfg`` with some synth settings replaced (used by the CLI's shortcut flags)."""
    return replace(cfg, synth=replace(cfg.synth, **changes))
