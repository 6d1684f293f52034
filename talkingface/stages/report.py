"""The report stage: ``runs/<name>/report/`` (figures and the summary) and ``reports/<name>.pdf``
from whatever stages of the run are finished."""
from __future__ import annotations

import csv
import json
from pathlib import Path

from analysis.findings import findings
from analysis.grid_summary import forest_figure, grid_summary, read_replicates
from analysis.articulation_eval import articulation_section
from analysis.corpus_report import corpus_section, make_figures, summarize_corpus, units_section
from analysis.mapping_report import ceiling_section, mapping_section
from analysis.motion_report import motion_section
from analysis.perception_report import perception_section
from analysis.real_faces_report import real_faces_finding, real_faces_section
from analysis.real_face_report import real_speaker_section
from analysis.real_steps_report import real_steps_section
from analysis.report import Report, escape
from analysis.front_end_report import front_end_section
from analysis.speech_report import speech_section
from analysis.study_report import study_section
from face_model.corpus import load_corpus
from face_model.motion_units import MotionUnits
from talkingface.config import dump_config, flatten
from talkingface.provenance import git_commit, versions
from talkingface.paths import STAGE_FOLDERS, RunPaths
from talkingface.stages.applies import expression_note, given, switched_off
from talkingface.stages.base import read_done
from talkingface.stages.real_faces import read_rows
from talkingface.stages.voices import read_results


def build_report(paths: RunPaths, cfg) -> dict:
    """Summaries and figures from the run's stage folders, then ``reports/<name>.pdf``.

    Also writes ``report/versions.json`` (:func:`talkingface.provenance.versions`, taken as the
    stage runs) and ``report/uncited.txt`` (the tables and figures no text cites,
    :meth:`analysis.report.Report.uncited`); the returned record holds both."""
    made_with = versions()  # what made the numbers, as the stage runs
    corpus = load_corpus(paths.corpus)
    units = MotionUnits.load(paths.units_model)
    summary = {"corpus": summarize_corpus(corpus), "units": read_done(paths.units)["summary"]}
    dump_config(cfg, paths.report_dir / "config.yaml")
    (paths.report_dir / "summary.json").write_text(json.dumps(summary, indent=1))
    (paths.report_dir / "versions.json").write_text(json.dumps(made_with, indent=1))
    figs = make_figures(corpus, units, summary, paths.report_dir)
    scope = corpus_scope(paths, cfg, corpus)
    rep = Report(f"talkingface replication: {paths.name}",
                 "Hong, Wen &amp; Huang (2002), Real-Time Speech-Driven Face Animation with "
                 "Expressions Using Neural Networks — rebuilt on "
                 + ("a given corpus" if scope["given"] else "a synthetic corpus"))
    corpus_section(rep, summary["corpus"], figs, given=scope["given"], scope=scope["note"],
                   switched_off=scope["switched_off"])
    units_section(rep, summary["units"], figs, note=scope["note"])
    mapping = read_done(paths.mapping)
    if mapping:
        ablations = paths.ablations / "results.csv"
        mapping_section(rep, mapping, paths.mapping, ablations if ablations.is_file() else None,
                        forest=_forest(paths))
        ceiling_section(rep, paths.stage("ceiling"))
    voices = read_done(paths.stage("voices"))
    default_model = (voices or {}).get("model")
    targets_section(rep, cfg.targets)
    speech_section(rep, paths.stage("speech_eval"), read_results(paths),
                   table_ii_R=_table_ii_R(mapping, cfg.mapping.method),
                   default_model=default_model, given_corpus=scope["given"] is not None,
                   targets=cfg.targets, real_faces=read_rows(paths.stage("real_faces")))
    front_end_section(rep, read_done(paths.stage("front_end")), paths.stage("speech_eval"))
    if read_done(paths.keyframes):
        motion_section(rep, paths.keyframes, paths.render, paths.tracking)
    if (paths.stimuli / "stimuli.json").is_file():
        study_section(rep, paths.stimuli, paths.study_data)
    study = read_done(paths.analysis)
    if study is not None:
        perception_section(rep, study, paths.analysis)
    faces = read_rows(paths.stage("real_faces"))
    faces_summary = _json(paths.stage("real_faces") / "summary.json")
    if faces:
        real_faces_section(rep, faces, faces_summary)
        if (paths.stage("articulation") / "summary.json").is_file():
            articulation_section(rep, paths.stage("articulation"))
    if (paths.stage("real_speaker") / "summary.json").is_file():
        real_speaker_section(rep, paths.stage("real_speaker"), paths.report_dir,
                             targets=cfg.targets)
        if not faces and (paths.stage("articulation") / "summary.json").is_file():
            articulation_section(rep, paths.stage("articulation"))
        if (paths.stage("real_steps") / "steps.json").is_file():
            real_steps_section(rep, paths.stage("real_steps"))
    methods_section(rep, cfg, corpus.info, study=study, made_with=made_with)
    items = findings(mapping=mapping, method=cfg.mapping.method, ab_dir=paths.ablations,
                     ceiling_dir=paths.stage("ceiling"), speech_dir=paths.stage("speech_eval"),
                     default_model=default_model, study=study, has=set(rep.refs.labels),
                     targets=cfg.targets, real_dir=paths.stage("real_speaker"),
                     steps_dir=paths.stage("real_steps"))
    line = real_faces_finding(faces, faces_summary) if faces else None
    if line:  # the real faces open the real-face findings, as their section opens the part
        at = next((i for i, t in enumerate(items) if t.startswith("<b>A real face.")),
                  len(items))
        items.insert(at, line)
    if scope["finding"]:
        items.append(scope["finding"])
    rep.findings(items)
    pdf = rep.build(paths.pdf)
    uncited = rep.uncited()
    (paths.report_dir / "uncited.txt").write_text("".join(f"{u}\n" for u in uncited))
    record = {"pdf": str(pdf), "versions": made_with, "uncited": uncited}
    if scope["note"]:
        record["note"] = scope["note"]
    if scope["switched_off"]:
        record["switched_off"] = scope["switched_off"]
    return record


def _json(path) -> dict:
    """A stage's JSON file, or {} when it is missing or unreadable."""
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def corpus_scope(paths: RunPaths, cfg, corpus) -> dict:
    """What the run's corpus allows: ``given`` (``source`` and ``info`` of a given corpus, else
    None), ``note`` (what the stages skip without smile or sad, else None), ``switched_off``
    (``{stage: why}`` of the stages the corpus rules out) and the first page's ``finding``
    saying so (None when nothing is skipped)."""
    done = read_done(paths.corpus) or {}
    given_info = ({"source": done.get("source", cfg.corpus.source), "info": corpus.info}
                  if given(cfg) else None)
    note = expression_note(u.expression for u in corpus.utterances)
    off = switched_off(cfg, STAGE_FOLDERS)
    finding = None
    if note or off:
        cite = "switched_off" if off else "corpus"
        finding = ("<b>The corpus.</b> "
                   + (f"A given corpus ({escape(given_info['source'])}). " if given_info else "")
                   + (escape(note) + " " if note else "")
                   + (f"Stages it switches off: {', '.join(off)} " if off else "See ")
                   + f"({{label:{cite}}}, p. {{page:{cite}}}).")
    return {"given": given_info, "note": note, "switched_off": off, "finding": finding}


def _forest(paths: RunPaths):
    """The ablations' forest plot (:func:`analysis.grid_summary.forest_figure`) in the report's
    folder, from the stage's replicates; None when the run has no ablations."""
    reps = paths.ablations / "replicates.csv"
    results = paths.ablations / "results.csv"
    if not reps.is_file() or not results.is_file():
        return None
    with open(results, newline="", encoding="utf-8-sig") as f:
        rows = list(csv.DictReader(f))
    reference = next((r["setting"] for r in rows if "reference" in (
        r.get("utterance_R_differs"), r.get("random_frames_R_differs"))), rows[0]["setting"])
    summary = grid_summary(read_replicates(reps), reference=reference)
    return forest_figure(summary, paths.report_dir / "ablations_forest.png",
                         reference=reference, title=f"Ablations: each setting against "
                                                    f"{reference}")


def targets_section(rep, targets) -> None:
    """The project's targets on real data, as the run's config states them (``targets``:
    :class:`analysis.config.TargetsConfig`): the one table every section that compares a
    figure with a target quotes."""
    rep.heading("Targets on real data", stage="report", key="targets_section")
    rep.paragraph("The targets the real-data sections below measure the models against are "
                  "stated once, in the run's config (section <i>targets</i>), and listed in "
                  "{label:targets}. They were set before the test data were read; they are "
                  "measured and reported, never tuned toward.")
    rep.table("Targets on real data (the run's config, section targets)",
              ["key", "target", "what it bounds"],
              [[escape(k), f"{v:g}", escape(text)] for k, v, text in targets.rows()],
              key="targets")


def _table_ii_R(mapping: dict | None, method: str) -> float | None:
    """The run's mapping's mean test R on the utterance split (Table II), if trained."""
    for x in ((mapping or {}).get("ranking") or {}).get("utterance", []):
        if x.get("method") == method:
            return float(x["R"])
    return None


def methods_section(rep, cfg, corpus_info: dict, *, study: dict | None = None,
                    made_with: list | None = None) -> None:
    """Settings and versions: the commit and seed, the versions of every package and program
    that made a number (``made_with``: :func:`talkingface.provenance.versions` as the report
    stage ran; taken now when None) and the resolved configuration."""
    rep.heading("Settings and versions", stage="report")
    rep.paragraph(f"Source commit {git_commit()}; run seed {cfg.seed}. Every table and figure "
                  "above was computed by the pipeline from this run's folders; "
                  "{label:versions} lists the packages and programs that made them and "
                  "{label:config} the settings they ran under.")
    if study is not None:
        who = "simulated (FLMP observers)" if study["simulated"] else (
            "real people" if not study["any_simulated"] else "partly simulated")
        rep.paragraph(f"Perception study: {study['participants']} participants, {who}; study "
                      f"seed {cfg.seed} (allocation list and trial orders), Monte Carlo, "
                      f"bootstrap and power simulations seeded with {cfg.seed}.")
    made_with = versions() if made_with is None else made_with
    now = {name: v for name, v, _ in made_with}
    synth = corpus_info.get("versions", {})
    differ = [f"{escape(k)} {escape(v)}" for k, v in sorted(synth.items())
              if now.get(k if k != "python" else "Python", v) != v]
    rep.table("Packages and programs that made the numbers (versions as the report stage ran)",
              ["package or program", "version", "what it made"],
              [[escape(n), escape(v), escape(what)] for n, v, what in made_with], key="versions",
              note="Also in report/versions.json. "
                   + ("The corpus was synthesised with " + ", ".join(differ) + " (corpus.json)."
                      if differ else "The corpus's own record (corpus.json) agrees."
                      if synth else ""))
    unused = ("synth.",) if given(cfg) else ()  # a given corpus is not synthesised
    flat = [[k, json.dumps(v)] for k, v in flatten(cfg).items()
            if "." in k and not k.startswith(unused)]
    rep.table("Resolved configuration", ["key", "value"], flat, col_widths=[200, 250],
              key="config",
              note="The synth settings are left out: the corpus is given (corpus.source), not "
                   "synthesised." if unused else "")

