"""A grid stage's answer at a glance: which setting is best, and does it really differ?

From the seed replicates of a grid (the ablations, the ceiling steps: one row per setting and
seed, as ``replicates.csv`` holds them), :func:`grid_summary` gives one row per setting and split:
the mean test R over seeds with its 95 % interval, the difference from the reference setting with
the interval of the paired differences, the Holm-corrected p of the paired test (all from
:func:`analysis.replicates.summarise_replicates`, so every figure equals ``results.csv``'s), and a
verdict. :func:`forest_figure` draws the differences with their intervals, the significant ones
marked; :func:`summary_markdown` says it in words, with the table. These are what the MLflow
parent run of a grid and the report show.

The intervals that are drawn and printed beside a verdict are on the verdict's footing: Holm-
adjusted (:func:`holm_levels`). Holm's step-down test sorts the m raw p-values and tests the one
of rank i at α / (m − i + 1) until the first that fails, which fails with all after it. The
interval of the difference of rank i is the paired t-interval at level 1 − α / (m − j + 1), with
j = i for the settings Holm rejects and j = the rank of the first one it keeps for the others (the
step at which their decision was made). As the t-test and the t-interval share their statistic,
an interval excludes 0 exactly when the verdict is better or worse (``delta_ci_holm``,
``ci_level``); the unadjusted 95 % half-width stays in ``delta_ci95``.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

from matplotlib.lines import Line2D
from scipy import stats

from analysis.figures import report_figure
from analysis.replicates import paired_tests, summarise_replicates
from analysis.dev_rule import dev_choice

VERDICTS = ("reference", "better", "worse", "no difference", "not tested")
# The columns of a summary row, in order.
COLUMNS = ("split", "setting", "seeds", "R", "R_ci95", "delta", "delta_ci95", "p_holm",
           "verdict", "delta_ci_holm", "ci_level")
ALPHA = 0.05  # the family-wise error rate of the verdicts (analysis.replicates.paired_tests)


def read_replicates(path) -> list[dict]:
    """``replicates.csv`` as rows: numbers as floats (``seed`` and ``replicate`` as ints), the
    rest as text; a file that is missing or empty is an error naming it."""
    path = Path(path)
    with open(path, newline="", encoding="utf-8-sig") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise ValueError(f"{path}: no replicate rows")
    out = []
    for r in rows:
        row = {}
        for k, v in r.items():
            if k in ("seed", "replicate"):
                row[k] = int(v)
                continue
            try:
                row[k] = float(v)
            except (TypeError, ValueError):
                row[k] = v
        out.append(row)
    return out


def _num(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def verdict(row: dict, split: str, reference: str, key: str) -> str:
    """``reference``, ``better``/``worse`` (Holm-corrected paired test below 0.05, by the sign
    of the difference), ``no difference``, or ``not tested`` (fewer than two paired seeds)."""
    if row[key] == reference:
        return "reference"
    differs = row.get(f"{split}_R_differs")
    if differs in (True, "True"):
        return "better" if _num(row.get(f"{split}_R_diff")) > 0 else "worse"
    if differs in (False, "False"):
        return "no difference"
    return "not tested"


def holm_levels(p: dict, alpha: float = ALPHA) -> dict:
    """The confidence level of each comparison's Holm-adjusted interval.

    Parameters
    ----------
    p : dict
        ``{name: raw two-sided p}`` of the m comparisons of one family.
    alpha : float
        Family-wise error rate of Holm's step-down test.

    Returns
    -------
    dict
        ``{name: level}``: 1 − α / (m − j + 1), where j is the comparison's rank in Holm's
        order (raw p ascending) if Holm rejects it, else the rank of the first comparison Holm
        keeps (see the module docstring). A t-interval at that level excludes 0 iff Holm
        rejects (``p ≤ α / (m − j + 1)``, as statsmodels' ``multipletests`` decides).
    """
    names = sorted(p, key=lambda n: p[n])  # stable: ties keep their order
    m = len(names)
    first_kept = next((i for i, n in enumerate(names, 1) if not p[n] <= alpha / (m - i + 1)),
                      m + 1)
    return {n: 1 - alpha / (m - min(i, first_kept) + 1) for i, n in enumerate(names, 1)}


def _at_level(half95: float, n: int, level: float) -> float:
    """The half-width of a t-interval over ``n`` paired seeds at ``level``, from its 95 % one
    (:func:`analysis.replicates.interval`: quantile × standard error)."""
    if not (n >= 2 and math.isfinite(half95)):
        return math.nan
    return half95 * float(stats.t.ppf(0.5 + level / 2, n - 1) / stats.t.ppf(0.975, n - 1))


def _holm_intervals(reps: list[dict], reference: str, key: str, split: str) -> dict:
    """``{setting: (level, n pairs)}`` of the comparisons with ``reference`` on ``split``, paired
    as :func:`analysis.replicates.summarise_replicates` pairs them."""
    names = list(dict.fromkeys(r[key] for r in reps))
    by = {n: {r["seed"]: float(r[f"{split}_R"]) for r in reps if r[key] == n}
          for n in names if f"{split}_R" in next(r for r in reps if r[key] == n)}
    tests = paired_tests(by, reference, alpha=ALPHA)
    levels = holm_levels({n: t["p"] for n, t in tests.items()})
    return {n: (levels[n], t["n"]) for n, t in tests.items()}


def grid_summary(reps: list[dict], *, reference: str, key: str = "setting",
                 splits: tuple = ("utterance", "random_frames")) -> list[dict]:
    """One row per split and setting (:data:`COLUMNS`), the reference first, then the others
    by their difference from it (largest first); only the ``splits`` the grid was evaluated on.
    ``reps``: one row per setting and seed (:func:`read_replicates`). ``delta_ci_holm`` is the
    half-width of the Holm-adjusted interval of ``delta`` at level ``ci_level`` (module
    docstring); it excludes 0 iff the verdict is better or worse."""
    rows = summarise_replicates(reps, reference=reference, key=key)
    out = []
    for split in splits:
        have = [r for r in rows if math.isfinite(_num(r.get(f"{split}_R")))]
        if not have:
            continue
        holm = _holm_intervals(reps, reference, key, split)
        part = []
        for r in have:
            level, pairs = holm.get(r[key], (math.nan, 0))
            part.append({
                "split": split, "setting": r[key], "seeds": int(r["n_seeds"]),
                "R": _num(r[f"{split}_R"]), "R_ci95": _num(r.get(f"{split}_R_ci95")),
                "delta": 0.0 if r[key] == reference else _num(r.get(f"{split}_R_diff")),
                "delta_ci95": math.nan if r[key] == reference
                else _num(r.get(f"{split}_R_diff_ci95")),
                "p_holm": math.nan if r[key] == reference else _num(r.get(f"{split}_R_p_holm")),
                "verdict": verdict(r, split, reference, key),
                "delta_ci_holm": math.nan if r[key] == reference
                else _at_level(_num(r.get(f"{split}_R_diff_ci95")), pairs, level),
                "ci_level": level})
        part.sort(key=lambda x: (x["verdict"] != "reference",
                                 -x["delta"] if math.isfinite(x["delta"]) else math.inf))
        out += part
    return out


def best(summary: list[dict], split: str) -> dict | None:
    """The setting of ``split`` with the highest mean test R (the reference included)."""
    part = [r for r in summary if r["split"] == split and math.isfinite(r["R"])]
    return max(part, key=lambda r: r["R"]) if part else None


def fmt(x, digits: int = 3, *, sign: bool = False) -> str:
    """A figure as the report and the MLflow summary print it (NaN: an en dash)."""
    x = _num(x)
    if not math.isfinite(x):
        return "–"
    return f"{x:+.{digits}f}" if sign else f"{x:.{digits}f}"


def fmt_p(p) -> str:
    p = _num(p)
    if not math.isfinite(p):
        return "–"
    return "< 0.001" if p < 0.001 else f"{p:.3f}"


def fmt_level(level) -> str:
    """A confidence level as the table prints it (``98.3 %``; NaN: an en dash)."""
    level = _num(level)
    return "–" if not math.isfinite(level) else f"{100 * level:.1f} %"


def delta_cell(r: dict) -> str:
    """Δ R with the half-width of its Holm-adjusted interval (``+0.012 ± 0.020``)."""
    if r["verdict"] == "reference":
        return "–"
    dci = "" if not math.isfinite(r["delta_ci_holm"]) else f" ± {fmt(r['delta_ci_holm'])}"
    return fmt(r["delta"], sign=True) + dci


def table_rows(summary: list[dict], split: str) -> list[list[str]]:
    """The printed rows of one split: setting, seeds, R ± 95 % CI, Δ ± Holm-adjusted CI, the
    interval's level, p (Holm), verdict."""
    out = []
    for r in summary:
        if r["split"] != split:
            continue
        ci = "" if not math.isfinite(r["R_ci95"]) else f" ± {fmt(r['R_ci95'])}"
        out.append([r["setting"], str(r["seeds"]), fmt(r["R"]) + ci, delta_cell(r),
                    fmt_level(r["ci_level"]), fmt_p(r["p_holm"]), r["verdict"]])
    return out


TABLE_HEADER = ["setting", "seeds", "test R ± 95 % CI", "Δ R vs reference ± Holm-adjusted CI",
                "CI level", "p (Holm)", "verdict"]
# what the Holm-adjusted interval is, for a table's note or a figure's caption
HOLM_NOTE = ("Δ's interval is Holm-adjusted: the paired t-interval over seeds at level "
             "1 − 0.05/(m − j + 1), j the setting's rank in Holm's order (raw p ascending), or "
             "for a setting Holm keeps the rank of the first kept; it excludes 0 exactly when "
             "the verdict is better or worse.")


def summary_markdown(summary: list[dict], *, title: str, reference: str,
                     what: str = "setting") -> str:
    """The summary in words (the reference, the best, which differ), then its table, as
    Markdown (an MLflow run's description)."""
    lines = []
    for split in dict.fromkeys(r["split"] for r in summary):  # the answer first, one line each
        top = best(summary, split)
        if top is None:
            continue
        if top["verdict"] == "reference":
            lines.append(f"**Best ({split} split): the reference `{reference}` itself** — "
                         f"R {fmt(top['R'])} ± {fmt(top['R_ci95'])}")
        else:
            said = {"better": "**significantly better**", "worse": "significantly worse",
                    "no difference": "**not significantly different**",
                    "not tested": "not tested (one seed)"}[top["verdict"]]
            lines.append(f"**Best ({split} split): `{top['setting']}`** — Δ R "
                         f"{delta_cell(top)} ({fmt_level(top['ci_level'])} Holm-adjusted "
                         f"interval) vs `{reference}`, p (Holm) {fmt_p(top['p_holm'])}: {said}")
        lines.append("")
    lines += [f"### {title}", ""]
    for split in dict.fromkeys(r["split"] for r in summary):
        part = [r for r in summary if r["split"] == split]
        ref = next((r for r in part if r["verdict"] == "reference"), None)
        top = best(summary, split)
        seeds = sorted({r["seeds"] for r in part})
        lines.append(f"**{split} split** — mean test R over {'/'.join(map(str, seeds))} seeds "
                     f"per {what}; each {what} against `{reference}`, paired by seed, "
                     f"Holm-corrected over {len(part) - 1} comparisons (α 0.05).")
        lines.append("")
        if ref is not None:
            lines.append(f"- reference `{reference}`: R {fmt(ref['R'])} ± {fmt(ref['R_ci95'])}")
        if top is not None and top["verdict"] != "reference":
            lines.append(f"- best: `{top['setting']}`: R {fmt(top['R'])} ± "
                         f"{fmt(top['R_ci95'])}, Δ {delta_cell(top)} "
                         f"({fmt_level(top['ci_level'])}), p (Holm) {fmt_p(top['p_holm'])}: "
                         + ("**significantly better**" if top["verdict"] == "better"
                            else f"{top['verdict']} from the reference"))
        elif top is not None:
            lines.append(f"- best: the reference `{reference}` itself")
        for v in ("better", "worse"):
            names = [f"`{r['setting']}` ({fmt(r['delta'], sign=True)})" for r in part
                     if r["verdict"] == v]
            lines.append(f"- significantly {v}: " + (", ".join(names) if names else "none"))
        lines += ["", HOLM_NOTE, "", "| " + " | ".join(TABLE_HEADER) + " |",
                  "|" + "---|" * len(TABLE_HEADER)]
        lines += ["| " + " | ".join(row) + " |" for row in table_rows(summary, split)]
        lines.append("")
    return "\n".join(lines)


def forest_figure(summary: list[dict], path, *, reference: str, title: str = "",
                  what: str = "setting") -> Path:
    """Δ test R against the reference with its Holm-adjusted interval (``delta_ci_holm``: the
    paired t-interval at level ``ci_level``, module docstring), one row per setting and a panel
    per split; filled markers: significantly better (blue) or worse (red) after Holm's
    correction; hollow grey: no difference — so a grey interval contains 0 and a coloured one
    does not. Drawn at the report's text width, type ≥ 7 pt
    (:func:`analysis.figures.report_figure`)."""
    splits = list(dict.fromkeys(r["split"] for r in summary))
    n = max(sum(1 for r in summary if r["split"] == s and r["verdict"] != "reference")
            for s in splits)
    colours = {"better": "#1f5fbf", "worse": "#c62828"}
    with report_figure(path, width=1.0, height_in=1.3 + 0.17 * max(n, 3)) as fig:
        axes = fig.subplots(1, len(splits), squeeze=False)[0]
        for ax, split in zip(axes, splits):
            part = [r for r in summary if r["split"] == split and r["verdict"] != "reference"]
            part = part[::-1]  # the largest difference at the top
            for yi, r in enumerate(part):
                err = r["delta_ci_holm"] if math.isfinite(r["delta_ci_holm"]) else 0.0
                c = colours.get(r["verdict"], "0.45")
                ax.errorbar(r["delta"], yi, xerr=err, fmt="o", color=c, ecolor=c, capsize=2,
                            markersize=4, lw=1,
                            markerfacecolor=c if r["verdict"] in colours else "white")
            ax.axvline(0, color="k", lw=0.8)
            ax.set_yticks(range(len(part)), [r["setting"] for r in part])
            ax.set_xlabel(f"Δ test R vs {reference} (Holm-adjusted CI over seeds)")
            ax.set_title(f"{split} split")
            ax.grid(axis="x", alpha=0.3)
            ax.set_ylim(-0.7, len(part) - 0.3)
        handles = [Line2D([], [], marker="o", ls="none", color=colours["better"],
                          label="better (Holm p < 0.05)"),
                   Line2D([], [], marker="o", ls="none", color=colours["worse"],
                          label="worse (Holm p < 0.05)"),
                   Line2D([], [], marker="o", ls="none", color="0.45",
                          markerfacecolor="white", label=f"no difference from {reference}")]
        fig.legend(handles=handles, loc="outside lower center", ncol=3, frameon=False)
        if title:
            fig.suptitle(title)
    return Path(path)


def write_summary(summary: list[dict], path) -> Path:
    """The summary as a CSV of :data:`COLUMNS` (figures in full, as results.csv has them)."""
    path = Path(path)
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in summary:
            w.writerow([repr(r[c]) if isinstance(r[c], float) else r[c] for c in COLUMNS])
    return path


VOICE_FIGURES = (("viseme_acc", "viseme acc"), ("viseme_acc_stream_100ms", "viseme acc, stream"),
                 ("bilabial_closed_frac", "/p b m/ closed"), ("r_reference", "r vs reference"))


def voices_summary(voices: list[dict], speech: list[dict]) -> list[dict]:
    """One row per voice-robust model (``voices``: the voices stage's results.csv rows): its
    in-domain R (Table II's footing), its development score under the rule that picks the
    default (:func:`analysis.dev_rule.dev_choice`) and its figures on the unseen test
    speakers (``speech``: speech_eval's results.csv rows). One seed per model: no intervals."""
    _, scores = dev_choice(speech)
    test = {r["model"]: r for r in speech if r["split"] == "unseen-test"}
    out = []
    for v in voices:
        name = f"voices-{v['model']}"
        row = {"model": v["model"], "default": str(v.get("default")) == "True",
               "in_domain_R": _num(v.get("in_domain_R")),
               "dev_score": scores.get(name, math.nan)}
        for key, _ in VOICE_FIGURES:
            row[f"test_{key}"] = _num(test.get(name, {}).get(key))
        out.append(row)
    bar = next((r for r in test.values() if r["model"].startswith("pocketsphinx")), None)
    if bar is not None:
        out.append({"model": bar["model"], "default": False, "in_domain_R": math.nan,
                    "dev_score": math.nan,
                    **{f"test_{k}": _num(bar.get(k)) for k, _ in VOICE_FIGURES}})
    return out


def voices_markdown(rows: list[dict]) -> str:
    """The voices summary in words (the default, how it was chosen, the recogniser's bar) and
    as a table."""
    lines = ["### Voice-robust models", ""]
    default = next((r for r in rows if r["default"]), None)
    chosen = max((r for r in rows if math.isfinite(r["dev_score"])),
                 key=lambda r: r["dev_score"], default=None)
    if default is not None:
        lines.append(f"- default model: `{default['model']}` (used by animate, stream and the "
                     "study); on the unseen test speakers viseme accuracy "
                     f"{fmt(default['test_viseme_acc'], 2)}, streaming "
                     f"{fmt(default['test_viseme_acc_stream_100ms'], 2)}")
    if chosen is not None:
        lines.append(f"- the development rule (mean of viseme accuracy, /p b m/ closure, /f v/ "
                     f"contact and r on the unseen development speakers) picks "
                     f"`{chosen['model']}` ({fmt(chosen['dev_score'])})")
    bar = next((r for r in rows if r["model"].startswith("pocketsphinx")), None)
    if bar is not None:
        lines.append(f"- the recogniser's bar (`{bar['model']}`): viseme accuracy "
                     f"{fmt(bar['test_viseme_acc'], 2)}, streaming "
                     f"{fmt(bar['test_viseme_acc_stream_100ms'], 2)}")
    lines += ["- one training seed per model: no intervals", "",
              "| model | default | in-domain R | dev score | "
              + " | ".join(f"{label} (test)" for _, label in VOICE_FIGURES) + " |",
              "|" + "---|" * (4 + len(VOICE_FIGURES))]
    for r in rows:
        lines.append(f"| {r['model']} | {'yes' if r['default'] else ''} | "
                     f"{fmt(r['in_domain_R'])} | {fmt(r['dev_score'])} | "
                     + " | ".join(fmt(r[f'test_{k}'], 2) for k, _ in VOICE_FIGURES) + " |")
    return "\n".join(lines) + "\n"
