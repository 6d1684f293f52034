"""The report's "Real speech" section: every model of the run scored on recordings of real
people (:mod:`analysis.speech_eval`), beside the reference recogniser and the in-domain Table II
figure of each model."""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

TARGETS = ("The project's targets on unseen speakers: viseme accuracy at least 0.75; /p b m/ "
           "closed in at least 90 % of segments, with a centre opening at most 0.4 x the median "
           "vowel opening; lip-opening correlation with the reference at least 0.7. They are "
           "measured and reported here, never tuned toward.")


# The rule that picks the default voice-robust model on the development speakers (never on the
# test speakers): the highest mean of these figures over the unseen development recordings.
DEV_RULE = ("viseme_acc", "bilabial_closed_frac", "labiodental_contact_frac", "r_reference")
SPLITS = (("unseen-test", "unseen speakers, test part"),
          ("unseen-test-independent", "unseen speakers, test part, labels independent of both "
                                      "recognisers"),
          ("unseen-test-aligned", "unseen speakers, test part, labels by pocketsphinx's "
                                  "alignment"),
          ("unseen-dev", "unseen speakers, development part"),
          ("seen", "seen speakers"))
RECOGNISERS = ("pocketsphinx", "hama")  # the recogniser rows' model names start so


def dev_choice(results: list[dict], prefix: str = "voices-") -> tuple[str | None, dict]:
    """``(model, {model: score})``: among the models named ``prefix``*, the one with the highest
    mean of :data:`DEV_RULE` on the ``unseen-dev`` rows of ``results`` (speech_eval's
    results.csv rows); None when no such model has development figures."""
    scores = {}
    for r in results:
        if r["split"] != "unseen-dev" or not r["model"].startswith(prefix):
            continue
        try:
            v = [float(r[k]) for k in DEV_RULE]
        except (KeyError, TypeError, ValueError):
            continue
        if all(math.isfinite(x) for x in v):
            scores[r["model"]] = sum(v) / len(v)
    best = max(scores, key=lambda m: (scores[m], m)) if scores else None
    return best, scores


def _rows(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8-sig") as f:
        return list(csv.DictReader(f))


BOOTSTRAP = 2000  # resamples of the recordings behind each interval of the real-speech tables
BOOTSTRAP_SEED = 0
# pooled figures with intervals: (results column, per-file hits column or None, per-file weight)
POOLED = (("viseme_acc", None, "frames"), ("viseme_acc_stream_100ms", None, "frames"),
          ("bilabial_closed_frac", "bilabial_closed", "bilabial_segments"))


def file_intervals(per_file: list[dict], model: str, split: str, *, level: float = 0.95,
                   n_boot: int = BOOTSTRAP, seed: int = BOOTSTRAP_SEED) -> dict:
    """``{figure: (lo, hi)}``: percentile bootstrap intervals of the pooled figures of
    :data:`POOLED` for ``model`` on ``split`` (``unseen-test``, ``unseen-dev``, ``seen``),
    resampling its recordings (per_file.csv rows) with replacement: the recordings, not the
    frames, are the independent units. A figure pools as its results.csv value does (hits over
    frames, closed over segments); figures missing for the model are left out."""
    where, _, rest = split.partition("-")
    part, _, labels = rest.partition("-")
    rows = [r for r in per_file if r["model"] == model and r["split"] == where
            and (not part or r["part"] == part) and (not labels or r.get("labels") == labels)]
    out = {}
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(rows), size=(n_boot, len(rows))) if rows else None
    for key, hits_col, weight_col in POOLED:
        try:
            w = np.array([float(r[weight_col]) for r in rows])
            h = (np.array([float(r[hits_col]) for r in rows]) if hits_col else
                 np.array([float(r[key]) for r in rows]) * w)
        except (KeyError, TypeError, ValueError):
            continue
        if picks is None or not np.isfinite(h).all() or w.sum() <= 0:
            continue
        with np.errstate(invalid="ignore", divide="ignore"):
            boots = h[picks].sum(1) / w[picks].sum(1)
        boots = boots[np.isfinite(boots)]
        if boots.size:
            out[key] = tuple(np.quantile(boots, [(1 - level) / 2, (1 + level) / 2]))
    return out


def _with_interval(v, interval) -> str:
    text = _num(v)
    if text == "–" or interval is None:
        return text
    return f"{text} [{interval[0]:.2f}, {interval[1]:.2f}]"


def _num(v, digits: int = 2) -> str:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return "–"
    return "–" if math.isnan(x) else f"{x:.{digits}f}"


def speech_section(rep, speech_dir: Path, voices_rows: list, *, table_ii_R: float | None,
                   default_model: str | None, given_corpus: bool = False) -> None:
    """Add the section from ``speech_eval/`` (results.csv, results.json, figures) and the rows
    of ``voices/results.csv``; ``given_corpus``: the run's corpus was given (recordings of its
    own speaker), not synthesised, and has no voice-robust models."""
    results = _rows(speech_dir / "results.csv")
    if not results:
        return
    per_file = _rows(speech_dir / "per_file.csv")
    rep.heading("Real speech", stage="speech_eval", key="speech")
    in_domain = {f"voices-{r['model']}": r for r in voices_rows}
    robust = f"voices-{default_model}" if default_model else None
    rep.paragraph(
        ("Every model above was trained on the given corpus's speech. " if given_corpus else
         "Every model above was trained on synthetic speech. ")
        + "Here each one animates recordings of "
        "real people that no one in this project made (the evaluation set of "
        "analysis/real_speech/, with its sources and licences), and is scored against their "
        "phone labels: the gate's frame accuracy (phone class and viseme), whether the inner "
        "lips meet on /p b m/ and the lower lip reaches the teeth on /f v/, and the correlation "
        "of the predicted lip opening with the trajectory the generator's own coarticulation "
        "model draws from the real labels. A recording is <i>seen</i> when its speaker is one of "
        "the voices of the model's training corpus (flite's and festival's slt are the CMU "
        "ARCTIC speaker slt; flite's awb and rms are ARCTIC awb and rms).")
    rep.paragraph(
        "Which model is which: Tables I-II are the paper's single-voice mapping "
        + ("(mapping/gated_mlp_*.tfmap, trained on the given corpus). " if given_corpus else
           "(mapping/gated_mlp_*.tfmap, one espeak voice). ")
        + (f"The models named voices-* are the voice-robust configurations of configs/voices.yaml "
           f"(stage voices): one-voice is the paper's espeak voice, many-* a corpus speaking "
           f"with ten synthetic voices; -cmvn, -warp and -augment add cepstral normalisation, "
           f"the VTLP warp and augmented copies; -recogniser takes the gate's phones from "
           f"pocketsphinx (trained on real speech) instead of mixtures on our MFCC; -phones "
           f"also feeds the MLPs the recogniser's window of phones instead of the MFCC; -hama "
           f"takes those phones from hama's multilingual phoneme model instead of "
           f"pocketsphinx; -labels trains the phone-input MLPs on the corpus's phone labels. "
           f"<b>{robust}</b> is the one `talkingface animate`, `talkingface "
           f"stream` and the study's synthetic face use by default." if robust else
           ("This run trained no voice-robust models (the corpus is given: the voices stage "
            "speaks a synthetic corpus with other voices), so `animate` and `stream` use the "
            "single-voice mapping." if given_corpus else
            "This run trained no voice-robust models (voices.grid: none), so `animate`, "
            "`stream` and the study use the single-voice mapping.")))
    best, scores = dev_choice(results)
    if best is not None:
        rep.paragraph(
            "Choosing on the development speakers only: the recordings are split by speaker into "
            "a development part (a configuration may be chosen on it) and a test part (reported; "
            "never chosen on). The rule — the highest mean of viseme accuracy, /p b m/ closure, "
            "/f v/ contact and r on the unseen development recordings — picks "
            f"<b>{best}</b> ({scores[best]:.3f}); the run's default is <b>{robust}</b>"
            + (" (the same)." if best == robust else
               f" ({scores.get(robust, float('nan')):.3f}), set in configs/voices.yaml."))
    for split, title in SPLITS:
        rows = [r for r in results if r["split"] == split and r.get("files") not in ("", "0")]
        if not rows:
            continue
        body = []
        for r in rows:
            dom = in_domain.get(r["model"], {})
            r_in = dom.get("in_domain_R") or (table_ii_R if r["model"] ==
                                              "gated_mlp_utterance" else None)
            ci = file_intervals(per_file, r["model"], split)
            body.append([r["model"], r["files"], _num(r.get("phone_acc")),
                         _with_interval(r.get("viseme_acc"), ci.get("viseme_acc")),
                         _with_interval(r.get("viseme_acc_stream_100ms"),
                                        ci.get("viseme_acc_stream_100ms")),
                         _with_interval(r.get("bilabial_closed_frac"),
                                        ci.get("bilabial_closed_frac")),
                         _num(r.get("bilabial_centre_rel_vowel")),
                         _num(r.get("labiodental_contact_frac")), _num(r.get("r_reference")),
                         _num(r_in, 3)])
        rep.table(f"Real speech, {title} ({rows[0].get('seconds') or '?'} s of audio)",
                  ["model", "files", "phone acc", "viseme acc", "viseme acc, stream 100 ms",
                   "/p b m/ closed", "/p b m/ centre / vowel", "/f v/ contact",
                   "r vs reference", "in-domain R (Table II)"], body,
                  note="The recogniser rows are pocketsphinx's and hama's phone recognisers "
                       "(trained on real speech), the bar a gate fed by them cannot pass; they "
                       "draw no face, so only their accuracies are given. In-domain R: test R on the run's "
                       "single-voice corpus, utterance split, as in Table II. [a, b]: 95 % "
                       f"percentile bootstrap interval over the recordings ({BOOTSTRAP:,} "
                       f"resamples, seed {BOOTSTRAP_SEED}). " + TARGETS,
                  key=f"speech_{split}")
    front_ends(rep, results, per_file, speech_dir)
    figure_model = robust or "gated_mlp_utterance"
    for model in dict.fromkeys([figure_model, "gated_mlp_utterance"]):
        fig = speech_dir / f"opening_{model}.png"
        if fig.is_file():
            rep.figure(fig, f"Predicted lip opening of {model} on a real sentence, against the "
                            "reference drawn from its phone labels; /p b m/ and /f v/ shaded.")


FRONT_END_SPLITS = (("unseen-test-independent", "test, independent labels"),
                    ("unseen-test-aligned", "test, pocketsphinx-aligned labels"),
                    ("unseen-test", "test, all"), ("unseen-dev", "development"))


def front_ends(rep, results: list, per_file: list, speech_dir: Path) -> None:
    """The recognisers alone, whole-utterance and streaming, on each kind of labels, and their
    look-ahead curve (``lookahead.csv`` / ``lookahead.png`` of speech_eval)."""
    rows = [r for r in results if r["model"].startswith(RECOGNISERS)
            and r.get("files") not in ("", "0", None)]
    body = []
    for split, title in FRONT_END_SPLITS:
        for r in (r for r in rows if r["split"] == split):
            ci = file_intervals(per_file, r["model"], split)
            body.append([r["model"], title, r["files"], r.get("seconds") or "–",
                         _num(r.get("phone_acc")),
                         _with_interval(r.get("viseme_acc"), ci.get("viseme_acc")),
                         _with_interval(r.get("viseme_acc_stream_100ms"),
                                        ci.get("viseme_acc_stream_100ms"))])
    if not body:
        return
    rep.table("The front ends alone: each recogniser's visemes against independent and "
              "aligner-made labels",
              ["recogniser", "recordings", "files", "seconds", "phone acc", "viseme acc",
               "viseme acc, stream 100 ms"], body,
              note="Independent labels: HTS (ARCTIC a0009), a TextGrid (praatio's bobby) and "
                   "GRID s1 sentences labelled from GRID's own word alignments with espeak-ng's "
                   "in-word phone durations (analysis/real_speech/README.md); aligned: "
                   "pocketsphinx's forced alignment of the transcript, which favours "
                   "pocketsphinx. Streaming at 100 ms: each frame is decided 100 ms after its "
                   "instant; hama decodes the last second of audio every 3 frames, so its "
                   "decision has heard 33–100 ms past the instant. [a, b]: 95 % bootstrap "
                   "interval over recordings.", key="speech_front_ends")
    fig = speech_dir / "lookahead.png"
    if fig.is_file():
        rep.figure(fig, "Streaming viseme accuracy of each recogniser against its look-ahead "
                        "(0–200 ms) on the unseen test speakers: solid, labels independent of "
                        "both recognisers; dashed, labels by pocketsphinx's alignment "
                        "(lookahead.csv).", width=0.8, key="speech_lookahead")
