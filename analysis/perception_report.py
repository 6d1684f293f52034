"""The perception study's analysis in the PDF: Tables III–VII beside the paper's, the tallies as
bars with Wilson intervals, the statistics and the FLMP/WTAV fits. Works on any study folder —
simulated participants from a replication or a real study's data alone
(``talkingface report --study-data DIR``)."""
from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
from matplotlib.patches import Patch
from statsmodels.stats.proportion import proportion_confint

from analysis.figures import report_figure
from analysis.perception_models import face_counts
from analysis.perception_stats_report import models_section, stats_section
from analysis.planning import fit_study
from analysis.report import escape
from analysis.stats import summary as stats_summary
from analysis.study_data import (
    PAPER_TALLIES,
    RESPONSE_LABEL,
    Tally,
    read_study,
    tallies,
)
from study.design import N_TRIALS

TITLES = {"III": "TABLE III: emotion inference based on the animation sequences without audio",
          "IV": "TABLE IV: emotion inference based on the audio",
          "V": "TABLE V: bimodal emotion inference using audio track 1 (\"It is normal.\")",
          "VI": "TABLE VI: bimodal emotion inference using audio track 2 (\"It is good.\")",
          "VII": "TABLE VII: bimodal emotion inference using audio track 3 (\"It is bad.\")"}
AUDIO_LABEL = {"normal": "Audio 1", "good": "Audio 2", "bad": "Audio 3"}


def tally_rows(t, paper: np.ndarray | None) -> tuple[list, list]:
    """Header and rows of one table: each cell 'ours (paper)'."""
    if t.name == "IV":
        header = ["Emotion"] + [AUDIO_LABEL[a] for a in t.columns]
    else:
        header = ["Emotion"] + [f"{e.capitalize()} {f}" for e, f in t.columns]
    rows = []
    for i, r in enumerate(t.rows):
        cells = [str(int(c)) if paper is None else f"{int(c)} ({int(paper[i, j])})"
                 for j, c in enumerate(t.counts[i])]
        rows.append([RESPONSE_LABEL[r], *cells])
    return header, rows


def tally_figure(tabs: dict, path: Path, *, width: float = 1.0) -> Path:
    """Tables III–VII as the proportion of each response per column, with Wilson 95 %
    intervals; synthetic (S) beside real (R) face. A column without responses draws neither
    bar nor whisker (it says n = 0); a response nobody gave in a column with responses draws
    its whisker up from 0."""
    colors = {"neutral": "#8c8c8c", "happy": "#e0a030", "sad": "#3b6fb6", "not_sure": "#c04040"}
    panels = {"III": "face only", "IV": "audio only", "V": "bimodal, audio 1",
              "VI": "bimodal, audio 2", "VII": "bimodal, audio 3"}
    with report_figure(path, width=width, height_in=4.4) as fig:
        grid = fig.add_gridspec(2, 3)
        slots = {"III": grid[0, 0], "IV": grid[0, 1], "V": grid[1, 0], "VI": grid[1, 1],
                 "VII": grid[1, 2]}
        first = None
        for name, slot in slots.items():
            ax = fig.add_subplot(slot, sharey=first)
            first = first or ax
            t = tabs[name]
            n = t.column_totals()
            seen = n > 0
            x = np.arange(len(t.columns))
            bar_w = 0.8 / len(t.rows)
            for k, r in enumerate(t.rows):
                xs = x[seen] + (k - (len(t.rows) - 1) / 2) * bar_w
                counts = t.counts[k][seen]
                if not len(xs):
                    continue
                p = counts / n[seen]
                lo, hi = proportion_confint(counts, n[seen], method="wilson")
                ax.bar(xs, p, bar_w, color=colors[r],
                       yerr=[np.clip(p - lo, 0, 1), np.clip(hi - p, 0, 1)],
                       error_kw={"lw": 0.7, "capsize": 1.5})
            for j in x[~seen]:
                ax.text(j, 0.03, "n = 0", ha="center", va="bottom", rotation=90, fontsize=7.5,
                        color="0.35")
            if name == "IV":
                ax.set_xticks(x, [AUDIO_LABEL[a] for a in t.columns])
                ax.set_xlabel("audio track")
            else:
                ax.set_xticks(x, [f"{e[:3]}\n{f}" for e, f in t.columns])
                ax.set_xlabel("expression, face")
            ax.set_title(f"Table {name}: {panels[name]}")
            ax.set_xlim(-0.5, len(x) - 0.5)
            ax.set_ylim(0, 1.05)
            ax.grid(axis="y", alpha=0.3)
            if name in ("III", "V"):
                ax.set_ylabel("proportion of participants")
            else:
                ax.tick_params(labelleft=False)
        key = fig.add_subplot(grid[0, 2])
        key.axis("off")
        key.legend([Patch(color=colors[r]) for r in colors],
                   [RESPONSE_LABEL[r] for r in colors], title="response", loc="center left",
                   frameon=False)
        key.text(0, 0.02, "S synthetic face, R real face;\nwhiskers: Wilson 95 % intervals",
                 fontsize=7.5, va="bottom", transform=key.transAxes)
    return Path(path)


def analyze_study(study_dir, out_dir, *, seed: int = 0, bootstrap: int = 200,
                  allow_incomplete: bool = False) -> dict:
    """Tallies, statistics and model fits of a study folder into ``out_dir`` (JSON, CSV, PNG);
    returns the summary the report is built from.

    A folder with an incomplete session is refused (:func:`analysis.study_data.read_study`)
    unless ``allow_incomplete``: then the complete sessions are analysed and the summary's
    ``incomplete`` lists the others (participant, judgments, slot status, reason, whether
    analysed); it is ``[]`` for a complete data set.
    """
    study = read_study(study_dir, allow_incomplete=allow_incomplete)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    df = study.trials
    tabs = tallies(df)
    summary = {"study_dir": str(study_dir), "study_path": str(Path(study_dir).resolve()),
               "participants": int(df["participant_id"].nunique()),
               "incomplete": [asdict(i) for i in study.incomplete],
               "sequences": {s: int(df[df["sequence"] == s]["participant_id"].nunique())
                             for s in ("SR", "RS")},
               "sites": session_sites(df),
               "simulated": bool(df["simulated"].all()),
               "any_simulated": bool(df["simulated"].any()),
               "tallies": {k: {"rows": list(t.rows), "columns": [list(c) if isinstance(c, tuple)
                                                                 else c for c in t.columns],
                               "counts": t.counts.tolist()} for k, t in tabs.items()}}
    for k, t in tabs.items():
        header, rows = tally_rows(t, None)
        (out / f"table_{k}.csv").write_text(
            "\n".join(",".join(map(str, r)) for r in [header, *rows]) + "\n")
    summary["figure"] = tally_figure(tabs, out / "tallies.png").name
    summary["stats"] = stats_summary(df, seed=seed)
    models = fit_study(df, seed=seed, bootstrap=bootstrap)
    for face, fc in face_counts(df).items():  # observed proportions, for the fit figure
        bim = fc.cells()[2].astype(float)
        models["faces"][face]["observed"] = {
            "bimodal": (bim / np.maximum(bim.sum(-1, keepdims=True), 1)).tolist()}
    summary["models"] = models
    (out / "analysis.json").write_text(json.dumps(summary, indent=1, default=_json))
    return json.loads((out / "analysis.json").read_text())


def _json(v):
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return float(v)
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (np.bool_,)):
        return bool(v)
    if hasattr(v, "__dataclass_fields__"):
        return asdict(v)
    return str(v)


def session_sites(df) -> dict:
    """Where the participants' sessions ran (``lab``, ``web``, ``none``: simulated files, and
    ``unknown`` for files written before the ``site`` column), and of the web participants how
    many left fullscreen or lost the page's focus during at least one trial (the browser's
    measures: an analysis may exclude them)."""
    site = df["site"].fillna("").astype(str).replace("", "unknown") if "site" in df else \
        "unknown"
    frame = df.assign(site=site)
    first = frame.groupby("participant_id")["site"].first()
    out = {k: int(v) for k, v in first.value_counts().sort_index().items()}
    web = frame[frame["site"] == "web"]

    def broke(col: str) -> int:
        flags = web[col].astype(str).str.lower() == "false"
        return int(web[flags]["participant_id"].nunique())
    out["web_left_fullscreen"] = broke("fullscreen") if len(web) else 0
    out["web_lost_focus"] = broke("focused") if len(web) else 0
    return out


def sites_sentence(summary: dict) -> str:
    """Where the sessions ran, for the perception section ("" for a summary without it)."""
    sites = summary.get("sites")
    if not sites:
        return ""
    names = {"lab": "in the lab (PsychoPy)", "web": "online (a browser, study serve)",
             "none": "simulated without a session", "unknown": "at a site the files do not "
             "record (written before the site column)"}
    parts = [f"{sites[k]} {names[k]}" for k in names if sites.get(k)]
    text = " Sessions: " + "; ".join(parts) + "."
    if sites.get("web"):
        text += (f" Of the online participants, {sites['web_left_fullscreen']} left fullscreen "
                 f"and {sites['web_lost_focus']} lost the page's focus during at least one "
                 "trial (columns fullscreen and focused of the data files).")
    return text


def incomplete_sentence(summary: dict) -> str:
    """The sentence the perception section adds for a summary made with ``allow_incomplete``
    from a folder with incomplete sessions (who was left out, who was analysed); "" else."""
    items = summary.get("incomplete") or []
    if not items:
        return ""
    left = [i for i in items if not i["analysed"]]
    kept = [i for i in items if i["analysed"]]
    parts = []
    if left:
        many = len(left) != 1
        parts.append(f"{len(left)} incomplete session{'s' * many} {'are' if many else 'is'} "
                     "left out: " + ", ".join(f"{escape(i['participant_id'])} "
                                              f"({i['judgments']} of {N_TRIALS} judgments)"
                                              for i in left))
    if kept:
        parts.append(", ".join(escape(i["participant_id"]) for i in kept)
                     + f" gave all {N_TRIALS} judgments but their allocation slot is not marked "
                     "complete, and are analysed")
    return (" The data set is incomplete (analysed with --allow-incomplete): "
            + "; ".join(parts) + ".")


def perception_section(report, summary: dict, out_dir: Path) -> None:
    """Tables III–VII (ours beside the paper's), the tally figure, statistics and models."""
    n, seqs = summary["participants"], summary["sequences"]
    who = ("simulated participants (FLMP observers, study/simulate.py)" if summary["simulated"]
           else "participants (real)" if not summary["any_simulated"]
           else "participants, some of them simulated")
    report.heading("Perception study results (Tables III–VII)", stage="analysis",
                   key="perception")
    report.paragraph(
        f"{n} {who}: {seqs['SR']} saw the synthetic face first in the bimodal blocks (SR), "
        f"{seqs['RS']} the real face first (RS). Each cell below is our count and, in "
        "parentheses, the paper's count of its 20 subjects. S: synthetic face; R: real face. "
        "Data: " + escape(summary["study_dir"]) + "." + sites_sentence(summary)
        + incomplete_sentence(summary)
        + " Tables III–VII are " + ", ".join(f"{{label:tally_{k}}}" for k in
                                             ("III", "IV", "V", "VI", "VII"))
        + "; {label:tallies} draws them as proportions.")
    for k in ("III", "IV", "V", "VI", "VII"):
        t = summary["tallies"][k]
        tally = Tally(k, TITLES[k], tuple(t["rows"]),
                      tuple(tuple(c) if isinstance(c, list) else c for c in t["columns"]),
                      np.array(t["counts"]))
        header, rows = tally_rows(tally, PAPER_TALLIES[k])
        report.table(TITLES[k] + " — ours (paper)", header, rows,
                     note="Paper: Hong, Wen &amp; Huang (2002), Table " + k + ".",
                     key=f"tally_{k}")
    report.figure(out_dir / summary["figure"], "Tallies as proportions with Wilson 95 % "
                  "intervals: visual-only (Table III) and bimodal with audio tracks 1–3 "
                  "(Tables V–VII); each expression for the synthetic (S) and real (R) face.",
                  key="tallies")
    if "stats" in summary:
        stats_section(report, summary["stats"])
    if "models" in summary:
        models_section(report, summary["models"], out_dir)
