"""Statistics and model fits of the perception study, as report text, tables and a figure
(from the dicts of :func:`analysis.stats.summary` and :func:`analysis.planning.fit_study`)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.figures import report_figure


def _p(p) -> str:
    if p is None or (isinstance(p, float) and np.isnan(p)):
        return "n/a"
    return "<0.001" if p < 0.001 else f"{p:.3f}"


def stats_section(report, s: dict) -> None:
    report.heading("Synthetic vs real face: paired tests", level=2)
    report.paragraph(
        "The same participants saw both faces, so each cell compares them pairwise: exact and "
        "mid-p McNemar on face-consistent vs not, Stuart-Maxwell on the four responses (where "
        "any category has discordant pairs), and the exact paired permutation test of the mean "
        "difference. A chi-square on the tallies would treat the two columns as independent "
        "groups, which they are not. {label:paired_cells} gives each cell's tests, "
        "{label:hit_rates} the unbiased hit rates of the visual-only block.")
    rows = []
    for c in s["paired_cells"]:
        cell = c["expression"] if c["block"] == "visual" else f"{c['expression']} + {c['audio']}"
        rows.append([c["block"], cell, f"{c['correct_synthetic']}/{c['n']}",
                     f"{c['correct_real']}/{c['n']}", f"{c['b']}/{c['c']}", _p(c["p_exact"]),
                     _p(c["p_midp"]), _p(c["sm_p"]), _p(c["perm_p"])])
    report.table("Face-consistent responses per cell, synthetic (S) vs real (R)",
                 ["block", "cell", "S", "R", "b/c", "McNemar", "mid-p", "Stuart-Maxwell",
                  "permutation"], rows,
                 note="b: consistent with S only; c: with R only. n/a: the test is undefined "
                      "(no discordant pairs).", key="paired_cells")
    a = s["audio_vs_chance"]
    report.paragraph("Audio only against chance (" + f"{a[0]['chance']:.3f}, one of three "
                     "emotions; not sure counts as incorrect): " + "; ".join(
                         f"\"{x['audio']}\" {x['correct']}/{x['n']} {x['emotion']}, binomial "
                         f"p {_p(x['p'])}" for x in a) + ".")
    co = s["crossover"]
    report.paragraph(
        f"Order (SR/RS crossover, outcome: {co['outcome']}): the synthetic face did better for "
        f"{co['synthetic_better']} participants, the real face for {co['real_better']}, "
        f"{co['ties']} ties. Face effect: Mainland-Gart p {_p(co['mainland_gart_face']['p'])}, "
        f"Prescott p {_p(co['prescott_face']['p'])}; period effect: Mainland-Gart p "
        f"{_p(co['mainland_gart_period']['p'])}, Prescott p {_p(co['prescott_period']['p'])}.")
    g = s["gee"]
    g = g if isinstance(g, dict) else g.__dict__
    if g["estimable"]:
        fw = g["face_wald"]
        report.paragraph(
            f"GEE logistic model ({g['formula']}; {g['n_clusters']} participants, bias-reduced "
            f"sandwich): the face terms together, Wald chi2 {fw['chi2']:.2f} on {fw['df']} df, "
            f"p {_p(fw['p'])}.")
    else:
        report.paragraph(f"GEE logistic model ({g['formula']}): not estimable here — "
                         f"{g['reason']}.")
    vc = s["visual_capture"]
    per = vc["per_face"]
    report.paragraph(
        "Visual capture in the incongruent bimodal cells (face and sentence disagree): the "
        f"response followed the face {100 * per['synthetic']['p_follows_face']:.0f} % of the "
        f"time for the synthetic face and {100 * per['real']['p_follows_face']:.0f} % for the "
        f"real face (paired permutation p {_p(vc['paired']['p'])}).")
    rows = []
    for face in ("synthetic", "real"):
        for h in s["hit_rates"]["visual"][face]:
            rows.append([face, h["stimulus"], f"{h['hit_rate']:.2f}", f"{h['hu']:.2f}",
                         f"{h['chance']:.2f}"])
    report.table("Unbiased hit rates Hu (Wagner 1993), visual only", ["face", "expression",
                 "hit rate", "Hu", "chance"], rows, key="hit_rates")


def fit_figure(models: dict, path: Path, *, width: float = 0.8) -> Path:
    """Observed vs predicted response proportions for each face and model."""
    with report_figure(path, width=width, height_in=2.9) as fig:
        axes = fig.subplots(1, 2, sharey=True)
        for ax, face in zip(axes, ("synthetic", "real")):
            f = models["faces"][face]
            obs = np.asarray(f["observed"]["bimodal"], dtype=float) if "observed" in f else None
            for model, marker in (("flmp", "o"), ("wtav", "x")):
                pred = np.asarray(f[model]["predicted"]["bimodal"], dtype=float).ravel()
                if obs is not None:
                    ax.scatter(obs.ravel(), pred, marker=marker, s=12,
                               label=f"{model.upper()} (RMSD {f[model]['rmsd']:.3f})")
            ax.plot([0, 1], [0, 1], color="0.6", lw=0.8)
            ax.set(xlim=(-0.03, 1.03), ylim=(-0.03, 1.03), aspect="equal")
            ax.set_title(f"{face} face")
            ax.set_xlabel("observed proportion")
            ax.grid(alpha=0.3)
            ax.legend(loc="upper left")
        axes[0].set_ylabel("predicted proportion")
    return Path(path)


def models_section(report, m: dict, out_dir: Path) -> None:
    report.heading("How audio and face combine: FLMP and WTAV per face", level=2)
    report.paragraph(
        f"Both models fitted per face by multinomial maximum likelihood with an L2 prior on the "
        f"logits (lambda {m['lam']}); {m['notes']}. Cross-validation leaves one participant out "
        "at a time. {label:models} compares the fits"
        + (", {label:model_fit} sets them against the observed proportions."
           if all("observed" in m["faces"][f] for f in ("synthetic", "real")) else "."))
    rows = []
    for face in ("synthetic", "real"):
        f = m["faces"][face]
        c = f["comparison"]
        for model in ("flmp", "wtav"):
            r = f[model]
            rows.append([face, model.upper(), r["n_params"], f"{r['rmsd']:.3f}",
                         f"{r['g2']:.1f} ({r['df']})", f"{r['bic']:.1f}",
                         f"{c['cv_loglik'][model]:.1f}" if "cv_loglik" in c else "",
                         "yes" if c["preferred"] == model else ""])
    report.table("Model comparison", ["face", "model", "parameters", "RMSD", "G2 (df)", "BIC",
                                      "CV log-lik", "preferred"], rows, key="models")
    b = m["bootstrap"]
    d = b["own_difference"]["flmp"]
    w = b["w"]
    report.paragraph(
        f"Comparable in the model's terms: the FLMP visual support of each expression for its "
        f"own emotion, synthetic minus real, with {int(100 * b['level'])} % bootstrap intervals "
        f"({b['B']} resamples of participants, seed {b['seed']}): " + "; ".join(
            f"{k} {v['estimate']:+.3f} [{v['lo']:+.3f}, {v['hi']:+.3f}]" for k, v in d.items())
        + f". WTAV weight on the audio: synthetic {w['synthetic']['estimate']:.2f} "
        f"[{w['synthetic']['lo']:.2f}, {w['synthetic']['hi']:.2f}], real "
        f"{w['real']['estimate']:.2f} [{w['real']['lo']:.2f}, {w['real']['hi']:.2f}].")
    if all("observed" in m["faces"][f] for f in ("synthetic", "real")):
        report.figure(fit_figure(m, Path(out_dir) / "model_fit.png"), "Bimodal response "
                      "proportions: observed against the fitted FLMP and WTAV, per face.",
                      width=0.8, key="model_fit")
    p = m.get("power")
    if p and "error" in p:
        report.paragraph(f"Planning: the power simulation could not run on these data "
                         f"({p['error']}).")
    elif p:
        report.paragraph(
            f"Planning: to detect a {100 * p['drop']:.0f}-point drop in visual-only recognition "
            f"of the synthetic face (simulated from the fitted real-face FLMP, the synthetic "
            f"face's supports shrunk until recognition falls by that much; exact paired test "
            f"per {p['unit']}, alpha {p['alpha']}) with {100 * p['target']:.0f} % power needs "
            f"{p['n_required']} participants ({p['n_sims']} simulations per n, seed "
            f"{p['seed']}); with 20, the power is "
            f"{p['power'][p['n_grid'].index(20)]:.2f}." if 20 in p["n_grid"] else "")
