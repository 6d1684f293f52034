"""The mapping part of the PDF: Tables I and II beside the paper's, the ranking of every method,
the gate, the ablations and the trajectory plots. Reads only the train stage's summary and the
ablation results; computes nothing new."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from analysis.grid_summary import (HOLM_NOTE, TABLE_HEADER, best, grid_summary, read_replicates,
                                   table_rows)
from analysis.metrics import PAPER_TABLES
from analysis.report import escape

_TABLE_NAME = {"train": "TABLE I", "test": "TABLE II"}
_PART_NAME = {"train": "training set", "test": "testing set"}


def _f(x, nd=3) -> str:
    return "–" if x is None or (isinstance(x, float) and np.isnan(x)) else f"{x:.{nd}f}"


def ci_cell(row: dict, key: str, digits: int = 3) -> str:
    """A mean over seeds (column ``key``) with ``± half-width`` of its 95 % interval (column
    ``<key>_ci95``) when the row has one; ``–`` when there is no value."""
    x = _num(row.get(key))
    if np.isnan(x):
        return "–"
    half = _num(row.get(f"{key}_ci95"))
    return _f(x, digits) + ("" if np.isnan(half) else f" ± {half:.{digits}f}")


def r_cell(row: dict, split: str) -> str:
    """Mean test R of an ablation row with its 95 % interval over seeds (``± half-width``) and
    ``↑`` (higher) or ``↓`` (lower) when the paired test against the reference setting finds a
    difference."""
    text = ci_cell(row, f"{split}_R")
    if row.get(f"{split}_R_differs") != "True":
        return text
    return text + (" ↑" if _num(row.get(f"{split}_R_diff")) > 0 else " ↓")


def seeds_note(rows: list[dict], split: str, corpus: str = "the corpus is the run's") -> str:
    """What a table of seed replicates shows, in words (its reference setting is the row whose
    ``<split>_R_differs`` is ``reference``); ``corpus``: what the rows trained on, in words."""
    n = sorted({int(float(r["n_seeds"])) for r in rows if r.get("n_seeds")})
    if not n or n == [1]:
        return ("One training seed per row: differences of a few thousandths in R are within "
                "run-to-run noise.")
    ref = [r.get("setting", r.get("step")) for r in rows
           if r.get(f"{split}_R_differs") == "reference"]
    tested = [r for r in rows if r.get(f"{split}_R_differs") in ("True", "False")]
    marked = sum(r[f"{split}_R_differs"] == "True" for r in tested)
    ref = repr(ref[0]) if ref else "the grid's reference setting"
    return (f"Figures: mean over {'/'.join(map(str, n))} training seeds ± the half-width of its "
            "95 % t-interval. " + (
                f"↑ (↓) marks a row whose R is higher (lower) than {ref}'s in a paired t-test "
                "over the same seeds, Holm-corrected over all the grid's settings (family-wise "
                "5 %): "
                f"{marked} of the {len(tested)} rows tested here. " if tested else "") +
            "Replicate k trains with the run seed + 1000 k (its split, initialisation, batches "
            f"and augmentation); {corpus}.")


def paper_table_rows(rows: list[dict], method: str, part: str) -> list[list]:
    """Rows of Table I (``train``) or II (``test``): per split and expression, ours beside the
    paper's R, nu_d, nu_d' and MSE."""
    out = []
    for r in rows:
        if r["method"] != method or r["part"] != part:
            continue
        p = PAPER_TABLES[part].get(r["expression"])
        out.append([r["split"], r["expression"],
                    _f(r["R"]), _f(p[0]) if p else "–",
                    _f(r["nu_d"]), _f(p[1]) if p else "–",
                    _f(r["nu_d_est"]), _f(p[2]) if p else "–",
                    _f(r["MSE"], 4), _f(p[3], 4) if p else "–"])
    return out


def lip_table_rows(rows: list[dict], method: str, part: str = "test") -> list[list]:
    """Rows of the Tables I–II companion (:mod:`analysis.lip_metrics`): per split and expression,
    LVE, FDD, R per region and closure on /p b m/ (of the estimate and of the truth); empty for
    a summary made before these metrics existed."""
    out = []
    for r in rows:
        if r["method"] != method or r["part"] != part or "LVE" not in r:
            continue
        n = r.get("bilabial_segments") or 0
        out.append([r["split"], r["expression"], _f(r["LVE"], 2), _f(r["FDD"], 2),
                    _f(r["R_lips"]), _f(r["R_cheeks"]), _f(r["R_forehead"]),
                    f"{_f(r['closure'], 2)} of {n}" if n else "–",
                    _f(r["closure_true"], 2) if n else "–"])
    return out


def _num(v):
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def lookahead_rows_for_report(ab: list[dict], split: str = "utterance") -> list[dict]:
    """The rows of the look-ahead table: the ablation rows of the curve (``lookahead-*``) and
    the paper's setting of the same methods, by method and latency; none without a curve."""
    curve = [r for r in ab if str(r["setting"]).startswith("lookahead-")]
    if not curve or f"{split}_R" not in curve[0]:
        return []
    methods = {r["method"] for r in curve}
    rows = curve + [r for r in ab if r["setting"] in ("paper", "baseline-gru")
                    and r["method"] in methods]
    return sorted(rows, key=lambda r: (r["method"], _num(r.get("latency_ms"))))


def lookahead_section(report, ab: list[dict], figure: Path, split: str = "utterance") -> None:
    """Accuracy against look-ahead: the ablation rows of the curve (``lookahead-*`` children
    and the paper's setting beside them), by method and algorithmic latency."""
    rows = lookahead_rows_for_report(ab, split)
    if not rows:
        return
    report.heading("Accuracy against look-ahead", level=2, stage="ablations")
    report.paragraph(
        "How much the paper's 100 ms of look-ahead buys: the same mapping trained with 0 to 5 "
        "frames of future context and its analysis window ending at the frame instant, so the "
        "algorithmic latency is the look-ahead alone (0 ms: no sample after the frame's instant "
        "is read), beside the paper's setting (3 frames, window centred: 112.5 ms). The rows "
        "with a centred window and no frame of look-ahead read only the 12.5 ms of the window "
        "past the instant. The GRU is unidirectional: its only look-ahead is its stacked future "
        "context. One MLflow child run per row and seed, in the ablation parent run. "
        "{label:lookahead} gives the figures" + (", {label:lookahead_fig} draws them."
                                                 if figure.is_file() else "."))
    report.table(f"Look-ahead: test figures against algorithmic latency ({split} split)",
                 ["setting", "method", "look-ahead (frames)", "window", "latency (ms)", "R",
                  "MSE", "LVE (px)", "/p b m/ closed"],
                 [[r["setting"], r["method"], r.get("look_ahead", "–"),
                   r.get("window_align", "–"), _f(_num(r.get("latency_ms")), 1),
                   r_cell(r, split), ci_cell(r, f"{split}_MSE", 4),
                   ci_cell(r, f"{split}_LVE", 2), ci_cell(r, f"{split}_closure", 2)]
                  for r in rows],
                 note="Mean over expressions of the test-set figures. " +
                      seeds_note(rows, split), key="lookahead")
    if figure.is_file():
        report.figure(figure, "Test R and closure on /p b m/ against algorithmic latency; "
                      "stars: the paper's setting (centred window).", key="lookahead_fig")


def ceiling_section(report, ceiling_dir: Path) -> None:
    """Where Table II stands: the steps of the ``ceiling`` stage (results.csv, ceiling.png)
    from our test R toward the oracle, the paper's value beside them."""
    path = ceiling_dir / "results.csv"
    if not path.is_file():
        return
    with open(path, newline="", encoding="utf-8-sig") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return
    paper = float(np.mean([v[0] for v in PAPER_TABLES["test"].values()]))
    report.heading("Where Table II stands: from our R to the ceiling", stage="ceiling")
    report.paragraph(
        f"The paper reports a mean test R of {paper:.3f}. Each row below is one measured run: "
        "the run's own corpus, then each nuisance of the corpus switched off in turn (a corpus "
        "and Motion Units of its own, the same seed and sentences), all of them together, and "
        "the oracle that reads the true phones and their timing instead of the audio — the "
        "ceiling of any audio model on that corpus. Both splits are shown: the paper's, which "
        "draws test frames at random from the training sentences, and the utterance split. "
        "The step 'tracked' (when the grid has it) goes toward the paper's data instead: it "
        "learns from the MUPs the MU-constrained tracker recovers from rendered video of the "
        "run's corpus (mapping.visual_source: tracked), as the paper's MUPs came from its "
        "tracker, and is scored against those tracked MUPs, as the paper's was. "
        "The defaults are never changed toward the paper's value; these runs explain the gap. "
        "{label:ceiling} gives every step" + (", {label:ceiling_fig} draws them."
                                             if (ceiling_dir / "ceiling.png").is_file() else "."))
    report.table("The ceiling decomposition: mean test figures per step",
                 ["step", "changes", "R (utterance)", "R (frame split)", "MSE (utterance)",
                  "LVE (px)", "/p b m/ closed"],
                 [[r["step"], escape(r["changes"]), r_cell(r, "utterance"),
                   r_cell(r, "random_frames"), ci_cell(r, "utterance_MSE", 4),
                   ci_cell(r, "utterance_LVE", 2), ci_cell(r, "utterance_closure", 2)]
                  for r in rows] + [["paper (Table II)", "their corpus, frame split", "–",
                                     _f(paper), "–", "–", "–"]],
                 note=seeds_note(rows, "utterance") + " Each step is an "
                      "MLflow child run of the ceiling parent run.", key="ceiling")
    fig = ceiling_dir / "ceiling.png"
    if fig.is_file():
        report.figure(fig, "Mean test R per step on both splits with their 95 % intervals over "
                           "seeds; the dashed line is the paper's Table II.", key="ceiling_fig")


def split_gap(rows: list[dict], method: str) -> float | None:
    """Mean test R on the frame split minus the utterance split (None if one is missing)."""
    def mean_r(split):
        v = [r["R"] for r in rows if r["method"] == method and r["split"] == split
             and r["part"] == "test"]
        return float(np.mean(v)) if v else None
    a, b = mean_r("random_frames"), mean_r("utterance")
    return None if a is None or b is None else a - b


def _visual_source_text(cfg: dict, tracked_dir: Path) -> str:
    """One paragraph: which MUPs the mapping learned from."""
    if cfg["mapping"].get("visual_source", "markers") != "tracked":
        return ("Visual data: the MUPs of the corpus markers (mapping.visual_source = markers). "
                "The paper's MUPs came from its tracker; --visual-source tracked trains on "
                "tracked MUPs instead.")
    done_path = tracked_dir / "done.json"
    done = json.loads(done_path.read_text()) if done_path.is_file() else {}
    t = cfg["tracker"]
    text = ("Visual data, as in the paper: the MUPs of the corpus tracked by the MU-constrained "
            f"tracker (mapping.visual_source = tracked). Every utterance was rendered as marker "
            f"video at image noise sd {t['corpus_noise_sd']:g} and tracked from the "
            f"{t['init']} placement of its first frame")
    if done:
        text += (f"; the tracked markers lie {done['error_px_mean']:.3f} px from the rendered "
                 f"ones on average (95th percentile {done['error_px_p95']:.3f} px) over "
                 f"{done['frames']} frames")
    return text + ". Ground truth below is the tracked MUP sequence."


def mapping_section(report, summary: dict, mapping_dir: Path, ablations_csv: Path | None,
                    forest: Path | None = None) -> None:
    """The mapping part of the report: settings, Tables I–II beside the paper's, the lip
    metrics, the split gap, the gate, the method ranking, the trajectories and (with
    ``ablations_csv``) the ablations and the look-ahead curve.

    Parameters
    ----------
    report : analysis.report.Report
        The report the section is added to.
    summary : dict
        The train stage's summary (``config``, ``rows``, ``gate``, ``ranking``,
        ``trajectories``).
    mapping_dir : Path
        The train stage's folder (its figures; the tracked corpus's ``done.json`` is read from
        ``mapping_dir.parent / "tracked"``).
    ablations_csv : Path or None
        The ablation stage's ``results.csv`` (``replicates.csv`` and ``lookahead.png`` beside
        it), or None without ablations.
    forest : Path or None
        The ablations' forest plot.
    """
    cfg = summary["config"]["mapping"]
    method = cfg["method"]
    rows = summary["rows"]
    report.heading("Audio-to-MUP mapping (§VI) and its evaluation (§VII-A)", stage="mapping",
                   key="mapping")
    report.paragraph(_mapping_settings_text(cfg, summary.get("expressions")))
    if summary.get("note"):
        report.paragraph(escape(summary["note"]))
    report.paragraph(_visual_source_text(summary["config"], mapping_dir.parent / "tracked"))
    _paper_tables(report, rows, method)
    gap = split_gap(rows, method)
    if gap is not None:
        report.paragraph(
            f"How much the frame split flatters: the mean test R over expressions is "
            f"{gap:+.3f} higher on random_frames than on utterance. Drawing frames at random puts "
            "the neighbours of a test frame, from the same sentence, in the training set.")
    _gate_paragraphs(report, summary["gate"], cfg, mapping_dir)
    _ranking_tables(report, summary["ranking"])
    traj = mapping_dir / summary["trajectories"]
    if traj.is_file():
        report.paragraph("{label:trajectories} sets the predicted MUPs of a test sentence "
                         "against the true ones, per expression.")
        report.figure(traj, "Predicted vs true MUPs of a test sentence per expression: the first "
                      "three utterance MUPs and the first expression MUP.", key="trajectories")
    if ablations_csv is not None:
        with open(ablations_csv, newline="", encoding="utf-8-sig") as f:
            ab = list(csv.DictReader(f))
        ablation_section(report, ab, ablations_csv.parent, forest)
        lookahead_section(report, ab, ablations_csv.parent / "lookahead.png")


def _mapping_settings_text(cfg: dict, corpus_expressions: list | None = None) -> str:
    """One paragraph: features, gate, bank and expression model as configured (none when the
    corpus, whose ``corpus_expressions`` the stage records, holds neutral speech only), and how
    the figures are computed."""
    expressions = (f"the cascade Υ<sub>k</sub> with {cfg['cascade_hidden']} hidden units"
                   if cfg["expression_model"] == "cascade" else "a bank retrained per expression")
    if corpus_expressions is not None:
        others = [e for e in corpus_expressions if e != "neutral"]
        expressions = (f"{expressions}, for {' and '.join(others)}" if others else
                       "none (the corpus holds neutral speech only)")
    return (
        f"Features: {cfg['n_mfcc']} MFCC per 30 fps frame{' with deltas' if cfg['deltas'] else ''}"
        f", context {cfg['context_back']} + 1 + {cfg['context_forward']} frames. Gate: one "
        f"Gaussian mixture ({cfg['gate_components']} {cfg['gate_covariance']} components) per "
        f"class, {cfg['n_classes']} classes; bank: one MLP per class with {cfg['hidden_min']}–"
        f"{cfg['hidden_max']} hidden units by subset size; expressions: "
        f"{expressions}."
        " Ground truth and estimates are both reconstructed from MUPs (the paper's ground truth is "
        "the tracked MUP sequence) and divided per marker coordinate by its maximum absolute "
        "displacement in the database. Splits: random_frames (the paper's, 80 % of frames drawn "
        "at random) and utterance (80 % of the sentences; no sentence on both sides).")


def _paper_tables(report, rows: list[dict], method: str) -> None:
    """Tables I and II, ours beside the paper's, and the lips-and-face table beside Table II
    (when the summary has its metrics)."""
    header = ["split", "expression", "R", "R paper", "ν<sub>d</sub>", "ν<sub>d</sub> paper",
              "ν<sub>d</sub>′", "ν<sub>d</sub>′ paper", "MSE", "MSE paper"]
    lip_rows = lip_table_rows(rows, method)
    report.paragraph("{label:table_i} and {label:table_ii} set our figures beside the paper's "
                     "Tables I (training set) and II (testing set)"
                     + ("; {label:lips_face} adds the lips and the face regions beside Table II."
                        if lip_rows else "."))
    for part in ("train", "test"):
        report.table(f"{_TABLE_NAME[part]}: {method} on the {_PART_NAME[part]}, ours vs the "
                     "paper's", header, paper_table_rows(rows, method, part),
                     note="Paper: Hong, Wen &amp; Huang (2002), Tables I and II (their split "
                          "draws frames at random).",
                     key="table_ii" if part == "test" else "table_i")
    if lip_rows:
        report.table(f"Lips and face beside Table II: {method} on the testing set",
                     ["split", "expression", "LVE (px)", "FDD (px)", "R lips", "R cheeks",
                      "R forehead", "/p b m/ closed", "closed (truth)"], lip_rows,
                     note="LVE: per frame the largest error over the 30 lip markers, averaged "
                          "(VOCA, FaceFormer). FDD: true minus estimated standard deviation "
                          "over time of each forehead marker's displacement length, averaged "
                          "(CodeTalker); positive means too still. R per region: Eq. 6 on that "
                          "region's normalised coordinates. /p b m/ closed: the fraction of "
                          "bilabial segments whose inner lips meet in the estimate (the truth's "
                          "own fraction beside it).", key="lips_face")


def _gate_paragraphs(report, gate: dict, cfg: dict, mapping_dir: Path) -> None:
    """The gate's frame accuracy and merged classes per split, and its confusion figure."""
    for key, g in gate.items():
        merges = ", ".join(f"{a}->{b}" for a, b in g["merges"].items()) or "none"
        report.paragraph(
            f"Gate ({key.split('/')[1]} split): frame accuracy on neutral frames "
            f"{100 * g['neutral_train']:.1f} % (training) and {100 * g['neutral_test']:.1f} % "
            f"(test); all test frames {100 * g['all_test']:.1f} %. Classes with fewer than "
            f"{cfg['min_class_frames']} training frames merged into their viseme's largest "
            f"class: {merges}.")
    conf = mapping_dir / "confusion_utterance.png"
    if conf.is_file():
        report.paragraph("{label:gate_confusion} shows which classes the gate confuses.")
        report.figure(conf, "The gate's confusion on the neutral test frames of the utterance "
                      "split (rows: the frame's phone class; merged classes have empty rows).",
                      width=0.8, key="gate_confusion")


def _ranking_tables(report, ranking: dict) -> None:
    """Every method ranked by mean test R, one table per split."""
    if ranking:
        report.paragraph("Every method of the run ranked by its mean test R: "
                         + ", ".join(f"{{label:ranking_{split}}} ({split} split)"
                                     for split in ranking) + ".")
    for split, rk in ranking.items():
        report.table(f"Methods ranked by mean test R ({split} split)",
                     ["rank", "method", "related work", "R", "MSE", "LVE (px)", "R lips",
                      "/p b m/ closed", "fit (s)"],
                     [[x["rank"], x["method"], escape(x["reference"]), _f(x["R"]),
                       _f(x["MSE"], 4), _f(x.get("LVE"), 2), _f(x.get("R_lips")),
                       _f(x.get("closure"), 2), f"{x['fit_seconds']:.1f}"] for x in rk],
                     note="Mean over expressions of the test-set figures. Baselines are trained "
                          "per expression on the same frames and evaluated the same way.",
                     key=f"ranking_{split}")


def ablation_section(report, ab: list[dict], ab_dir: Path, forest: Path | None) -> None:
    """Which setting is best, and does it really differ: the grid summary of the ablations
    (:func:`analysis.grid_summary.grid_summary` of replicates.csv, the figures of results.csv)
    as a table, and its forest plot."""
    reps = ab_dir / "replicates.csv"
    if not reps.is_file():
        return
    reference = next((r["setting"] for r in ab if str(r.get("utterance_R_differs",
                                                            r.get("random_frames_R_differs")))
                      == "reference"), ab[0]["setting"])
    summary = grid_summary(read_replicates(reps), reference=reference)
    split = summary[0]["split"]
    methods = {r["setting"]: r["method"] for r in ab}
    report.heading("Ablations: which setting is best, and does it really differ?", level=2,
                   stage="ablations", key="ablations_section")
    top = best(summary, split)
    report.paragraph(
        f"Every setting of configs/ablations.yaml trained with {summary[0]['seeds']} seeds and "
        f"compared with <b>{escape(reference)}</b> seed by seed (paired t-test of test R on the "
        f"{split} split, Holm-corrected over the {len(methods) - 1} comparisons; "
        "{label:ablations}). The best "
        f"setting is <b>{escape(top['setting'])}</b>"
        + ("." if top["verdict"] == "reference" else
           f" ({top['verdict']} than the reference)." if top["verdict"] in ("better", "worse")
           else f" ({top['verdict']} from the reference)."))
    report.table(f"Ablations: mean test R per setting ({split} split) against "
                 f"{escape(reference)}", ["setting", "method", *TABLE_HEADER[1:]],
                 [[row[0], methods.get(row[0], ""), *row[1:]]
                  for row in table_rows(summary, split)], key="ablations",
                 note=seeds_note(ab, split) + " Verdict: better or worse when the "
                 "Holm-corrected p is below 0.05. " + HOLM_NOTE + " Every setting and seed is "
                 "an MLflow child run of the ablation parent run, whose description holds this "
                 "table.")
    if forest is not None and forest.is_file():
        report.paragraph("The forest plot ({label:forest}) draws each difference with the "
                         "Holm-adjusted interval of the table: grey when it contains 0, "
                         "coloured when it does not.")
        report.figure(forest, "The ablations' differences from the reference with their "
                      "Holm-adjusted intervals over paired seeds (the table's; level in its CI "
                      "level column); filled: significant after Holm's correction.",
                      key="forest")
