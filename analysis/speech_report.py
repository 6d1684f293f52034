"""The report's "Real speech" section: every model of the run scored on recordings of real
people (:mod:`analysis.speech_eval`), beside the phone recognisers trained on real speech, the
lip-sync tools users already use, and the in-domain Table II figure of each model — with the
speaker as the unit: every table states its speakers and recordings and its input rate, every
interval resamples speakers (:mod:`analysis.speaker_bootstrap`), every figure has its chance
baseline beside it, and the targets are quoted from the run's ``targets`` section
(:class:`analysis.config.TargetsConfig`)."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from analysis.config import TargetsConfig
from analysis.speaker_bootstrap import N_BOOT, SEED, speaker_interval
from analysis.dev_rule import (LATENCY_FILE, audio_splits, deciding_half, dev_choice, dev_parts,
                               excluded_by_latency, latency_p99, lip_rule_figures,
                               read_latency)
from analysis.speech_pooling import SPLITS as KEEP

SPLITS = (("unseen-test", "unseen speakers, test part"),
          ("unseen-test-independent", "unseen speakers, test part, labels independent of both "
                                      "recognisers"),
          ("unseen-dev", "unseen speakers, development part"),
          ("seen", "speakers the model was trained on (seen)"))
RECOGNISERS = ("pocketsphinx", "hama", "causal")  # the recogniser rows' model names start so


def _rows(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8-sig") as f:
        return list(csv.DictReader(f))




def _num(v, digits: int = 2) -> str:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return "–"
    return "–" if math.isnan(x) else f"{x:.{digits}f}"


def _with_interval(v, interval) -> str:
    text = _num(v)
    if text == "–" or interval is None:
        return text
    return f"{text} [{interval[0]:.2f}, {interval[1]:.2f}]"


def _hits_column(key: str) -> tuple[str, str]:
    """The per-file numerator and denominator behind a pooled figure."""
    return {"viseme_acc": ("viseme_hits", "frames"),
            "bilabial_closed_frac": ("bilabial_closed", "bilabial_segments"),
            "r_reference": ("r_terms", "speech_frames")}.get(
        key, ("viseme_stream_hits", "frames"))


def file_intervals(per_file: list[dict], model: str, split: str) -> dict:
    """``{figure: (lo, hi)}`` of ``model`` on ``split`` from its per_file.csv rows: the
    speaker-level (two-stage) bootstrap of :func:`analysis.speaker_bootstrap.speaker_interval`
    (the name is kept for :mod:`analysis.findings`; recordings are no longer resampled as if
    independent). Figures without an interval (fewer than 3 speakers) are left out."""
    rows = [r for r in per_file if r["model"] == model and KEEP[split](r)
            and str(r.get("input_rate") or "native") == "native"]
    out = {}
    keys = {"viseme_acc", "bilabial_closed_frac", "r_reference",
            *[k for r in rows[:1] for k in r if k.startswith("viseme_acc_stream_")]}
    for key in keys:
        num, den = _hits_column(key)
        try:
            iv = speaker_interval([r["speaker"] for r in rows], [float(r[num]) for r in rows],
                                  [float(r[den]) for r in rows])
        except (KeyError, TypeError, ValueError):
            continue
        if iv.ok:
            out[key] = (iv.lo, iv.hi)
    return out


def _cell(r: dict, key: str, *, chance: bool = True) -> str:
    """``value [lo, hi] (chance c)`` of a results row; † when the row has no interval."""
    text = _num(r.get(key))
    if text == "–":
        return text
    lo, hi = r.get(f"{key}_lo"), r.get(f"{key}_hi")
    if _num(lo) != "–" and _num(hi) != "–":
        text += f" [{float(lo):.2f}, {float(hi):.2f}]"
    elif f"{key}_lo" in r:
        text += " †"
    if chance and _num(r.get(f"chance_{key}")) != "–":
        text += f" ({_num(r.get(f'chance_{key}'))})"
    return text


def _who(r: dict) -> str:
    return f"{r.get('speakers') or 0} / {r.get('files') or 0}"


def targets_text(t: TargetsConfig) -> str:
    """The targets this section measures, quoted from the run's ``targets`` section."""
    return (f"Targets (config section targets, stated before the run, never tuned toward): on "
            f"unseen speakers, streaming viseme accuracy at {t.lookahead_ms:g} ms at least "
            f"{t.viseme_accuracy:g}; /p b m/ closed in at least {t.bilabial_closed:g} of "
            f"segments with a centre opening at most {t.bilabial_centre_rel_vowel:g} x the "
            f"median vowel opening; r with the reference at least {t.speech_r_reference:g}; "
            f"a score at 16 kHz within {t.rate_tolerance:g} of the same score at the native "
            "rate.")


def _reasons(rows: list) -> str:
    notes = sorted({r.get("interval_note") for r in rows if r.get("interval_note")})
    return (" †: no interval (" + "; ".join(notes) + ").") if notes else ""


def set_part_text(info: dict) -> str:
    """The sentence that says the figures come from a part of the set, from speech_eval's
    results.json ``info`` (``recordings``, ``speakers`` and ``speech_set``: the setting
    ``speech_set.per_speaker`` and how many recordings the set lists); empty when every
    recording was scored (or the file predates the setting)."""
    chosen = info.get("speech_set") or {}
    k, total = chosen.get("per_speaker") or 0, chosen.get("set_recordings")
    n = len(info.get("recordings") or [])
    if not k or not total or n >= total:
        return ""
    return (f"<b>A part of the set:</b> this run scored {n} of {total} recordings (the first "
            f"{k} of each speaker and part, speech_set.per_speaker = {k}) of "
            f"{len(info.get('speakers') or [])} speakers; every figure below is of that part, "
            "not of the whole set. ")


def speech_section(rep, speech_dir: Path, voices_rows: list, *, table_ii_R: float | None,
                   default_model: str | None, given_corpus: bool = False,
                   targets: TargetsConfig = TargetsConfig(),
                   real_faces: list | None = None) -> None:
    """Add the section from ``speech_eval/`` (results.csv, per_speaker.csv, comparisons.csv,
    rates.csv, lookahead.csv and the figures) and the rows of ``voices/results.csv``;
    ``given_corpus``: the run's corpus was given (recordings of its own speaker), not
    synthesised; ``targets``: the run's :class:`~analysis.config.TargetsConfig`, quoted."""
    results = _rows(speech_dir / "results.csv")
    if not results:
        return
    rep.heading("Real speech", stage="speech_eval", key="speech")
    in_domain = {f"voices-{r['model']}": r for r in voices_rows}
    robust = f"voices-{default_model}" if default_model else None
    default = robust or next((r["model"] for r in results if r["model"].startswith(
        "gated_mlp")), results[0]["model"])
    key = next((k for k in results[0] if k.startswith("viseme_acc_stream_")),
               "viseme_acc_stream_100ms")
    ms = key.rsplit("_", 1)[-1]
    info = _json(speech_dir / "results.json")
    trained = (info.get("training_speakers") or {}).get(default) or []
    shown = [s for s, _ in SPLITS if any(r["split"] == s and r.get("files") not in ("", "0")
                                         for r in results)]
    rep.paragraph(
        set_part_text(info)
        + ("Every model above was trained on the given corpus's speech. " if given_corpus else
           "Every model above was trained on synthetic speech. ")
        + "Here each one animates recordings of real people that no one in this project made "
        "(analysis/real_speech/, with its sources and licences), scored against their phone "
        "labels: the gate's viseme accuracy, whether the inner lips meet on /p b m/, and the r "
        "of the predicted lip opening with the opening the generator's own coarticulation "
        "draws from the real labels, on speech frames, each clip centred and scaled before "
        "pooling. The speaker is the unit: a recording is <i>seen</i> when its speaker id is "
        f"one of the model's training speakers ({default}: "
        f"{', '.join(trained) or 'none recorded'}; each model's are in results.json); "
        "intervals resample speakers, then recordings, and a part of fewer than 3 speakers "
        "gets none. Beside every figure, in brackets after it, its chance baseline: the same "
        "prediction circularly shifted by a third and a half of its length. The split tables ("
        + ", ".join(f"{{label:speech_{s}}}" for s in shown) + ") give the models, the phone "
        "recognisers (trained on real speech, the bar a gate fed by them cannot pass) and the "
        f"peers side by side. The streaming column ({ms}) is the recognisers' labels decided "
        f"{ms} after each frame and the models' live output, " + _stream_text(info, default)
        + " " + targets_text(targets))
    rep.paragraph(
        "Which model is which: Tables I-II are the paper's single-voice mapping "
        + ("(trained on the given corpus). " if given_corpus else "(one espeak voice). ")
        + (f"The models named voices-* are the voice-robust configurations of "
           f"configs/voices.yaml (stage voices); <b>{robust}</b> is the one `talkingface "
           f"animate`, `stream` and the study use by default." if robust else
           "This run trained no voice-robust models, so `animate` and `stream` use the "
           "single-voice mapping."))
    _dev_rule(rep, results, speech_dir, robust, targets, real_faces)
    for split, title in SPLITS:
        rows = [r for r in results if r["split"] == split and r.get("files") not in ("", "0")]
        if not rows:
            continue
        body = []
        for r in rows:
            dom = in_domain.get(r["model"], {})
            r_in = dom.get("in_domain_R") or (table_ii_R if r["model"] ==
                                              "gated_mlp_utterance" else None)
            body.append([r["model"], _who(r), _cell(r, "viseme_acc"),
                         _cell(r, key, chance=False), _cell(r, "bilabial_closed_frac"),
                         _num(r.get("bilabial_centre_rel_vowel")),
                         _cell(r, "r_reference"), _num(r.get("silence_rel_vowel")),
                         _num(r_in, 3)])
        spk = rows[0].get("speaker_ids", "").replace(";", ", ")
        rep.table(f"Real speech, {title}, native input rate ({rows[0].get('seconds') or '?'} s; "
                  f"speakers: {spk})",
                  ["system", "speakers / recordings", "viseme acc", f"stream {ms}",
                   "/p b m/ closed", "/p b m/ centre / vowel", "r speech frames",
                   "silence / vowel", "in-domain R"], body,
                  note="[a, b]: 95 % speaker-level bootstrap interval "
                       f"({N_BOOT:,} resamples, seed {SEED}); (c): chance baseline. Peers "
                       "(loudness, openfacefx, pylipsync) close on their m viseme. Silence / "
                       "vowel: median opening on silence frames over the median vowel opening. "
                       "In-domain R: test R on the run's training corpus, utterance split "
                       "(Table II)." + _reasons(rows), key=f"speech_{split}")
    _per_speaker(rep, speech_dir, default)
    _comparisons(rep, speech_dir, default, key)
    _rates(rep, speech_dir, default, key, targets)
    front_ends(rep, results, speech_dir, key)
    for model in dict.fromkeys([default, "gated_mlp_utterance"]):
        fig = speech_dir / f"opening_{model}.png"
        if fig.is_file():
            k = f"speech_opening_{model}"
            rep.paragraph(f"{{label:{k}}} shows {model}'s predicted lip opening on one real "
                          "sentence against the reference drawn from its labels.")
            rep.figure(fig, f"Predicted lip opening of {model} on a real sentence, against the "
                            "reference drawn from its phone labels; /p b m/ and /f v/ shaded.",
                       key=k)


def _dev_rule(rep, results: list, speech_dir: Path, robust: str | None,
              targets: TargetsConfig, real_faces: list | None = None) -> None:
    """The development rule's pick beside the run's default, and the bound on live latency it
    applies (``targets.stream_latency_p99_ms``) with each candidate's measured latency
    (``latency.json``; absent: said not measured, and the bound not applied); with
    ``real_faces`` (the ``real_faces`` stage's rows) the lips on the development faces weigh
    half the score, and the paragraph says which half decided."""
    latency, bound = read_latency(speech_dir), targets.stream_latency_p99_ms
    p99 = latency_p99(latency)
    best, scores = dev_choice(results, latency=p99, bound_ms=bound, real_faces=real_faces)
    if not scores:
        return
    out = excluded_by_latency(results, p99, bound)
    bound_text = (f"{bound:.1f} ms (targets.stream_latency_p99_ms; the paper's window plus one "
                  "frame)")
    if latency is None:
        lat = (f"The live latency of the candidates was not measured (no {LATENCY_FILE}), so "
               f"the bound on it, {bound_text}, was not applied. ")
    else:
        lat = ("A model whose measured live latency (99th percentile) exceeds "
               f"{bound_text}, or whose latency was not measured, cannot be the pick, whatever "
               "its score; the bound excluded "
               + (", ".join(f"<b>{m}</b>" for m in sorted(out)) if out else "none")
               + " ({label:speech_latency}). ")
    pick = (f"<b>{best}</b> ({scores[best]:.3f})" if best is not None else
            "none (the bound excluded every model with a score)")
    same = best is not None and best == robust
    lips = bool(lip_rule_figures(real_faces))
    decided = (deciding_half(dev_parts(results, real_faces=real_faces), best, scores, out)
               if best is not None else "")
    kinds = audio_splits(results)
    heard = ("the mean of viseme accuracy, /p b m/ closure, /f v/ contact and r on the "
             "development recordings" + (" (each kind's figures it measures: sentences, GRID "
                                         "s26, and digits, FSDD, weighed equally)"
                                         if len(kinds) > 1 else ""))
    rule = (f"half {heard}, half the mean of lip r on speech frames and /p b m/ "
            "closed on the development faces (real_faces, GRID s26)" if lips else
            f"the highest of {heard}")
    rep.paragraph(
        "The development rule, computed on the development part only (unseen speakers, "
        "independent labels; a configuration may be chosen there, never on the test part): "
        f"{rule} picks {pick}" + (f", decided by {decided}" if decided else "") + ". "
        + lat + f"The run's default is <b>{robust}</b>"
        + (" (the same)." if same else
           f" ({scores.get(robust, float('nan')):.3f}"
           + (", over the latency bound" if robust in out else "")
           + "), set in configs/voices.yaml."))
    if latency is not None:
        _latency_table(rep, latency, scores, out, bound)


def _latency_table(rep, latency: dict, scores: dict, out: dict, bound: float) -> None:
    """Each candidate's and each measured model's live latency, and the bound's verdict."""
    measured = latency.get("models") or {}
    body = []
    for m in dict.fromkeys([*sorted(scores), *measured]):
        v = measured.get(m, {})
        verdict = ("not a candidate" if m not in scores else
                   ("excluded: not measured" if out[m] is None else "excluded") if m in out
                   else "within")
        body.append([m, _num(scores.get(m), 3), _num(v.get("latency_p50_ms"), 0),
                     _num(v.get("latency_p99_ms"), 0), _num(v.get("compute_p99_ms"), 1),
                     _num(v.get("algorithmic_latency_ms"), 1), verdict])
    rep.table(f"Live latency of each model in `talkingface stream`, and the bound of "
              f"{bound:.1f} ms on its 99th percentile",
              ["model", "development score", "latency p50, ms", "latency p99, ms",
               "compute p99, ms", "look-ahead + window, ms", "bound"], body,
              note=f"{latency.get('recording', '?')} ({_num(latency.get('seconds'), 1)} s) "
                   f"streamed in chunks of {1000 * float(latency.get('chunk_s') or 0):g} ms, "
                   "paced in real time, one model after the other "
                   "(talkingface/stages/latency.py); latency of a frame: the wall-clock time "
                   "it was emitted minus the time its instant was captured (look-ahead, "
                   "buffering and compute); –: not measured, or not paced.",
              key="speech_latency")


def _stream_text(info: dict, default: str) -> str:
    """What the models' streaming figure is: their live output, its look-ahead, and whether it
    was checked equal to the offline output (results.json, stream)."""
    check = (info.get("stream") or {}).get(default) or {}
    la = check.get("lookahead_s")
    if la is None:
        return f"which {default} cannot give (it estimates whole utterances)."
    same = check.get("stream_equals_offline")
    return (f"which for {default} waits {1000 * la:.1f} ms (its context and half its analysis "
            "window) and "
            + (f"equals its offline output (checked on {check.get('checked_on')}: largest "
               f"marker difference {check.get('max_marker_diff_px', 0):.1g} px)."
               if same else "differs from its offline output, so it is not given."))


def _json(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}


PHONES_FED = "voices-one-voice-phones-labels"  # the mapping gated by pocketsphinx's phones


def speaker_tally(speech_dir: Path, default: str, key: str, *, input_rate: str = "native",
                  kind: str = "sentences") -> dict | None:
    """On the test part's unseen ``kind`` speakers at ``input_rate`` (``per_speaker.csv``),
    ``{"better": speakers where ``default``'s ``key`` figure is at least pocketsphinx's,
    "speakers": every such speaker with both figures, "pocketsphinx": its model name}``; None
    when the run scored no pocketsphinx or the default on such a speaker."""
    rows = [r for r in _rows(speech_dir / "per_speaker.csv")
            if r.get("input_rate", "native") == input_rate and r.get("kind") == kind
            and r.get("seen") != "True"]
    ps = next((r["model"] for r in rows if r["model"].startswith("pocketsphinx")), None)
    if ps is None:
        return None
    by = {(r["model"], r["speaker"]): r for r in rows}
    speakers, better = [], []
    for spk in sorted({r["speaker"] for r in rows}):
        a, b = by.get((default, spk), {}).get(key), by.get((ps, spk), {}).get(key)
        try:
            a, b = float(a), float(b)
        except (TypeError, ValueError):
            continue
        if math.isfinite(a) and math.isfinite(b):
            speakers.append(spk)
            if a >= b:
                better.append(spk)
    return {"better": better, "speakers": speakers, "pocketsphinx": ps} if speakers else None


def tally_text(t: dict | None, what: str) -> str:
    """``"at least pocketsphinx's on N of M sentence speakers (names)"``, or empty."""
    if not t:
        return ""
    return (f"at least pocketsphinx's on {len(t['better'])} of {len(t['speakers'])} "
            f"{what} (" + (", ".join(t["better"]) or "none") + ")")


def _per_speaker(rep, speech_dir: Path, default: str) -> None:
    every = _rows(speech_dir / "per_speaker.csv")
    key = next((k for k in (every[0] if every else {}) if k.startswith("viseme_acc_stream_")),
               "viseme_acc_stream_100ms")
    ms = key.rsplit("_", 1)[-1]
    systems = list(dict.fromkeys(
        [r["model"] for r in every if r["model"].startswith(RECOGNISERS)]
        + [m for m in (PHONES_FED,) if m != default and any(r["model"] == m for r in every)]))
    for rate, label in (("native", "native input rate"), ("16000", "16 kHz")):
        rows = [r for r in every if r.get("input_rate", "native") == rate]
        mine = [r for r in rows if r["model"] == default]
        if not mine:
            continue
        by = {(r["model"], r["speaker"]): r for r in rows}
        body = []
        for r in sorted(mine, key=lambda r: (r.get("kind") != "sentences", r["speaker"])):
            cells = [r["speaker"], r.get("kind", ""), "yes" if r["seen"] == "True" else "",
                     r["files"],
                     f"{_num(r.get('viseme_acc'))} ({_num(r.get('chance_viseme_acc'))})",
                     _num(r.get(key)),
                     f"{_num(r.get('bilabial_closed_frac'))} "
                     f"({_num(r.get('chance_bilabial_closed_frac'))})",
                     f"{_num(r.get('r_reference'))} ({_num(r.get('chance_r_reference'))})"]
            cells += [_num(by.get((m, r["speaker"]), {}).get(key)) for m in systems]
            body.append(cells)
        k = "speech_per_speaker" if rate == "native" else f"speech_per_speaker_{rate}"
        tally = speaker_tally(speech_dir, default, key, input_rate=rate)
        rep.paragraph(
            f"{{label:{k}}} splits the test part by speaker ({label}): the pooled figures "
            "above are these rows weighted by their frames and segments, so a speaker with "
            "many recordings weighs as much as its recordings do. Streaming at "
            f"{ms}, {default}'s viseme accuracy is "
            + (tally_text(tally, "unseen sentence speakers") or "not compared with "
               "pocketsphinx's (not scored)") + ".")
        rep.table(f"Per speaker, test part, {label}: {default}, the recognisers and the "
                  f"pocketsphinx-fed model (every system: per_speaker.csv)",
                  ["speaker", "kind", "seen", "recordings", "viseme acc", f"stream {ms}",
                   "/p b m/ closed", "r speech frames",
                   *[f"{m.split()[0]} stream {ms}" for m in systems]], body,
                  note="(c): chance baseline. No intervals: one speaker per row. Kind: "
                       "sentences (continuous speech) or digits (isolated words).",
                  key=k)


def _comparisons(rep, speech_dir: Path, default: str, key: str) -> None:
    rows = [r for r in _rows(speech_dir / "comparisons.csv") if r["split"] == "unseen-test"]
    if not rows:
        return
    rep.paragraph(f"{{label:speech_comparisons}} compares {default} with each recogniser "
                  "(both streaming, at the same look-ahead) and each peer on the same "
                  "recordings: the interval of the difference draws the same speakers and "
                  "recordings for both.")
    body = []
    for r in rows:
        iv = (f"[{float(r['lo']):+.2f}, {float(r['hi']):+.2f}]" if _num(r.get("lo")) != "–"
              else f"none: {r.get('interval_note')}")
        label = {key: "viseme acc, streaming", "viseme_acc": "viseme acc",
                 "bilabial_closed_frac": "/p b m/ closed",
                 "r_reference": "r speech frames"}.get(r["figure"], r["figure"])
        body.append([r["model_b"], label,
                     _who(r), _num(r["a"]), _num(r["b"]),
                     f"{float(r['difference']):+.2f}", iv])
    rep.table(f"{default} against the recognisers and peers, unseen test speakers, native "
              "input rate", ["other system", "figure", "speakers / recordings", default,
                             "other", "difference", "95 % paired interval"], body,
              note="Paired speaker-level bootstrap of the difference "
                   f"({N_BOOT:,} resamples, seed {SEED}).", key="speech_comparisons")


def _rates(rep, speech_dir: Path, default: str, key: str, targets: TargetsConfig) -> None:
    rows = [r for r in _rows(speech_dir / "rates.csv")
            if r["model"] == default and r["split"] == "unseen-test"
            and r.get("files") not in ("", "0")]
    if len(rows) < 2:
        return
    native = next((r for r in rows if r["input_rate"] == "native"), rows[0])
    figs = (("viseme_acc", "viseme acc"), (key, "stream"),
            ("bilabial_closed_frac", "/p b m/ closed"), ("r_reference", "r"))
    body = []
    for r in rows:
        cells = []
        for k, _ in figs:
            v, n0 = r.get(k), native.get(k)
            drop = (float(n0) - float(v)) if _num(v) != "–" and _num(n0) != "–" else None
            flag = "" if drop is None or drop <= targets.rate_tolerance else " !"
            cells.append(_num(v) + ("" if drop is None or r is native else
                                    f" ({-drop:+.2f}{flag})"))
        body.append([r["input_rate"], _who(r), *cells,
                     (r.get("rate_note") or "").split(" (")[0]])
    rep.paragraph(f"{{label:speech_rates}} gives {default} on the same recordings at the "
                  "rates users record at: each recording resampled down to 16 kHz and 8 kHz "
                  "and given to the model at that rate.")
    rep.table(f"{default} by input rate, unseen test speakers",
              ["input rate", "speakers / recordings", *[lab for _, lab in figs], "note"], body,
              note=f"(d): change from the native rate; !: a drop larger than the target's "
                   f"{targets.rate_tolerance:g} (targets.rate_tolerance). Recordings already at "
                   "or below a rate are given as recorded.", key="speech_rates")


FRONT_END_SPLITS = (("unseen-test-independent", "test, independent labels"),
                    ("unseen-test-aligned", "test, pocketsphinx-aligned labels"),
                    ("unseen-test", "test, all"), ("unseen-dev", "development"))


def front_ends(rep, results: list, speech_dir: Path, key: str = "viseme_acc_stream_100ms"
               ) -> None:
    """The recognisers alone, whole-utterance and streaming, on each kind of labels, and their
    look-ahead curve (``lookahead.csv`` / ``lookahead.png`` of speech_eval)."""
    rows = [r for r in results if r["model"].startswith(RECOGNISERS)
            and r.get("files") not in ("", "0", None)]
    body = []
    for split, title in FRONT_END_SPLITS:
        for r in (r for r in rows if r["split"] == split):
            body.append([r["model"], title, _who(r), r.get("seconds") or "–",
                         _num(r.get("phone_acc")), _cell(r, "viseme_acc"),
                         _cell(r, key, chance=False)])
    if not body:
        return
    fig = speech_dir / "lookahead.png"
    rep.paragraph("{label:speech_front_ends} reads each recogniser alone against labels made "
                  "independently of it and against labels its own aligner made"
                  + (", and {label:speech_lookahead} its streaming accuracy against look-ahead."
                     if fig.is_file() else "."))
    rep.table("The front ends alone, native input rate: each recogniser's visemes against "
              "independent and aligner-made labels",
              ["recogniser", "recordings", "speakers / recordings", "seconds", "phone acc",
               "viseme acc", "viseme acc, streaming"], body,
              note="Independent labels: HTS, a TextGrid, GRID's own word alignments and FSDD "
                   "word spans with espeak-ng's in-word phone durations "
                   "(analysis/real_speech/README.md); aligned: pocketsphinx's forced "
                   "alignment, which favours pocketsphinx. [a, b]: speaker-level interval; "
                   "(c): chance." + _reasons(rows), key="speech_front_ends")
    if fig.is_file():
        rep.figure(fig, "Streaming viseme accuracy of each recogniser against its look-ahead "
                        "(0–200 ms) on the unseen test speakers: solid, labels independent of "
                        "both recognisers; dashed, labels by pocketsphinx's alignment "
                        "(lookahead.csv).", width=0.8, key="speech_lookahead")
