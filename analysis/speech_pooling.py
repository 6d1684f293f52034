"""Per-recording rows of the real-speech set pooled into the figures the report shows, with the
speaker as the unit (DESIGN.md, "Evaluation on real data"): the splits, the speakers and
recordings behind each row, speaker-level intervals (:mod:`analysis.speaker_bootstrap`), the
per-speaker table and paired comparisons of two systems on the same recordings.

Every pooled figure is a ratio of sums over recordings (:data:`FIGURES`: numerator and
denominator columns of the per-file rows), so a bootstrap draw pools exactly as the figure does;
its chance baseline (:mod:`analysis.speech_scores`) pools with the same denominator.
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from analysis.speaker_bootstrap import (LEVEL, MIN_SPEAKERS, N_BOOT, SEED, Interval, _draws,
                                        paired_speaker_interval, pooled, speaker_interval)

# the splits of the per-file rows: name → predicate on a row (split = seen|unseen, part, labels)
SPLITS = {
    "seen": lambda r: r["split"] == "seen",
    "unseen": lambda r: r["split"] == "unseen",
    "all": lambda r: True,
    "test": lambda r: r["part"] == "test",
    "unseen-dev": lambda r: r["split"] == "unseen" and r["part"] == "dev",
    # the development part's two kinds of recording (analysis.speech_set.SpeechItem.kind), which
    # the development rule weighs apart (analysis.dev_rule)
    "unseen-dev-sentences": lambda r: (r["split"] == "unseen" and r["part"] == "dev"
                                       and r.get("kind") == "sentences"),
    "unseen-dev-digits": lambda r: (r["split"] == "unseen" and r["part"] == "dev"
                                    and r.get("kind") == "digits"),
    "unseen-test": lambda r: r["split"] == "unseen" and r["part"] == "test",
    "unseen-test-independent": lambda r: (r["split"] == "unseen" and r["part"] == "test"
                                          and r["labels"] == "independent"),
    "unseen-test-aligned": lambda r: (r["split"] == "unseen" and r["part"] == "test"
                                      and r["labels"] == "aligned"),
}
INTERVAL_SPLITS = ("seen", "unseen-dev", "unseen-test", "unseen-test-independent")


@lru_cache(maxsize=64)
def _draw_index(speakers: tuple, n_boot: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The draws :func:`analysis.speaker_bootstrap.speaker_interval` makes for recordings of
    ``speakers`` (the same generator, seed and order), concatenated, with each draw's start."""
    spk = np.asarray(speakers, dtype=object)
    groups = [np.flatnonzero(spk == s) for s in sorted(set(speakers))]
    draws = _draws(groups, n_boot, np.random.default_rng(seed))
    starts = np.cumsum([0] + [len(d) for d in draws[:-1]])
    return np.concatenate(draws), starts


def _boot_ratio(index, starts, hits, weights) -> np.ndarray:
    num, den = np.add.reduceat(hits[index], starts), np.add.reduceat(weights[index], starts)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1), np.nan)


def _percentile_interval(boots, n_spk: int, n_rec: int) -> Interval:
    boots = boots[np.isfinite(boots)]
    if not boots.size:
        return Interval(None, None, n_spk, n_rec, "no finite resample")
    lo, hi = np.quantile(boots, [(1 - LEVEL) / 2, (1 + LEVEL) / 2])
    return Interval(float(lo), float(hi), n_spk, n_rec)


def paired_interval(speakers, hits_a, hits_b, weights, *, n_boot: int = N_BOOT,
                    seed: int = SEED) -> Interval:
    """:func:`analysis.speaker_bootstrap.paired_speaker_interval` (the same interval of
    pooled(a) − pooled(b), the same draws for both), summed at once like :func:`interval`."""
    a, b = np.asarray(hits_a, np.float64), np.asarray(hits_b, np.float64)
    w = np.asarray(weights, np.float64)
    n_spk = len(set(speakers))
    if n_spk < MIN_SPEAKERS or not (np.isfinite(a).all() and np.isfinite(b).all()
                                    and np.isfinite(w).all()) or np.any(w < 0):
        return paired_speaker_interval(speakers, a, b, w, n_boot=n_boot, seed=seed)
    index, starts = _draw_index(tuple(speakers), n_boot, seed)
    return _percentile_interval(_boot_ratio(index, starts, a, w)
                                - _boot_ratio(index, starts, b, w), n_spk, len(a))


def interval(speakers, hits, weights, *, n_boot: int = N_BOOT, seed: int = SEED) -> Interval:
    """:func:`analysis.speaker_bootstrap.speaker_interval`, the same interval, with the draws
    shared by every figure and system scored on the same recordings (cached) and summed at
    once: the set's many rows cost one set of draws per split."""
    hits, weights = np.asarray(hits, np.float64), np.asarray(weights, np.float64)
    n_spk = len(set(speakers))
    if n_spk < MIN_SPEAKERS or not np.isfinite(hits).all() or not np.isfinite(weights).all() \
            or np.any(weights < 0):
        return speaker_interval(speakers, hits, weights, n_boot=n_boot, seed=seed)
    index, starts = _draw_index(tuple(speakers), n_boot, seed)
    return _percentile_interval(_boot_ratio(index, starts, hits, weights), n_spk, len(hits))


def figures(stream_key: str) -> dict:
    """Pooled figure → (numerator column, denominator column, chance numerator or None)."""
    return {"phone_acc": ("phone_hits", "frames", None),
            "viseme_acc": ("viseme_hits", "frames", "chance_viseme_hits"),
            stream_key: ("viseme_stream_hits", "frames", None),
            "bilabial_closed_frac": ("bilabial_closed", "bilabial_segments", "chance_closed"),
            "labiodental_contact_frac": ("labiodental_contact", "labiodental_segments", None),
            "r_reference": ("r_terms", "speech_frames", "chance_r_terms")}


def interval_figures(stream_key: str) -> tuple:
    """The figures given with a speaker-level interval."""
    return ("viseme_acc", stream_key, "bilabial_closed_frac", "r_reference")


def _f(row: dict, key: str) -> float:
    try:
        v = float(row.get(key))
    except (TypeError, ValueError):
        return float("nan")
    return v


def _count(rows: list, key: str) -> int | None:
    """The integer sum of ``key`` over ``rows`` (None when a row has none)."""
    v = [_f(r, key) for r in rows]
    return int(sum(v)) if all(math.isfinite(x) for x in v) else None


def _ratio(rows: list, num: str, den: str) -> float:
    h = np.array([_f(r, num) for r in rows])
    w = np.array([_f(r, den) for r in rows])
    if not len(rows) or not np.isfinite(h).all():
        return float("nan")
    return pooled(h, w)


def _median(values) -> float:
    values = [v for v in values if math.isfinite(v)]
    return float(np.median(values)) if values else float("nan")


def pool_rows(rows: list, split: str, stream_key: str, *, intervals: bool = False,
              n_boot: int = N_BOOT, seed: int = SEED) -> dict:
    """One pooled row of the per-file ``rows`` of one model and input rate on ``split``:
    recordings (``files``), speakers (count and ``speaker_ids``), seconds, every figure of
    :func:`figures` with its ``chance_`` baseline, and with ``intervals`` the speaker-level
    interval of :func:`interval_figures` (``<figure>_lo``/``_hi``, or the reason there is none
    in ``interval_note``)."""
    sel = [r for r in rows if SPLITS[split](r)]
    speakers = sorted({r["speaker"] for r in sel})
    out = {"split": split, "files": len(sel), "speakers": len(speakers),
           "speaker_ids": ";".join(speakers),
           "seconds": round(sum(_f(r, "seconds") for r in sel), 2)}
    if not sel:
        return out
    for fig, (num, den, chance) in figures(stream_key).items():
        out[fig] = _ratio(sel, num, den)
        if chance:
            out[f"chance_{fig}"] = _ratio(sel, chance, den)
    vmed = _median([_f(r, "vowel_median_px") for r in sel])
    out["bilabial_centre_rel_vowel"] = _median(
        [_f(r, "bilabial_centre_px") for r in sel]) / vmed if sel else float("nan")
    out["silence_rel_vowel"] = _median([_f(r, "silence_px") for r in sel]) / vmed
    out["speech_frames"] = _count(sel, "speech_frames")
    if intervals:
        notes = []
        for fig in interval_figures(stream_key):
            num, den, _ = figures(stream_key)[fig]
            if not math.isfinite(out[fig]):
                out[f"{fig}_lo"] = out[f"{fig}_hi"] = None
                continue
            iv = interval([r["speaker"] for r in sel], [_f(r, num) for r in sel],
                          [_f(r, den) for r in sel], n_boot=n_boot, seed=seed)
            out[f"{fig}_lo"], out[f"{fig}_hi"] = (iv.lo, iv.hi) if iv.ok else (None, None)
            if not iv.ok:
                notes.append(iv.reason)
        out["interval_note"] = "; ".join(dict.fromkeys(notes))
    return out


def summarise(per_file: list, stream_key: str, *, splits=tuple(SPLITS),
              interval_splits=INTERVAL_SPLITS) -> list:
    """Pooled rows (:func:`pool_rows`) of every model × input rate × split of ``per_file``
    (rows with ``model`` and ``input_rate``); intervals on ``interval_splits`` at the native
    rate (the rate rows compare a model with itself and are read as differences)."""
    out = []
    keys = dict.fromkeys((r["model"], str(r.get("input_rate", "native"))) for r in per_file)
    for model, rate in keys:
        rows = [r for r in per_file if r["model"] == model
                and str(r.get("input_rate", "native")) == rate]
        for split in splits:
            sel = [r for r in rows if SPLITS[split](r)]
            noted = [r for r in sel if r.get("rate_note")]
            notes = "; ".join(sorted({r["rate_note"] for r in noted}))
            out.append({"model": model, "input_rate": rate,
                        **pool_rows(rows, split, stream_key,
                                    intervals=split in interval_splits and rate == "native"),
                        "rate_note": f"{len(noted)} recordings scored as recorded ({notes})"
                        if noted else ""})
    return out


def per_speaker(per_file: list, stream_key: str, *, part: str = "test",
                input_rate: str = "native") -> list:
    """Model × speaker on the ``part`` recordings at ``input_rate``: the speaker's kind of
    recording (sentences or digits, :attr:`analysis.speech_set.SpeechItem.kind`), recordings,
    seconds, seen or not, viseme accuracy (offline and streaming), closure and r, with chance."""
    out = []
    rows = [r for r in per_file if r["part"] == part
            and str(r.get("input_rate", "native")) == input_rate]
    for model in dict.fromkeys(r["model"] for r in rows):
        mine = [r for r in rows if r["model"] == model]
        for spk in sorted({r["speaker"] for r in mine}):
            sel = [r for r in mine if r["speaker"] == spk]
            pooled_row = pool_rows(sel, "all", stream_key)
            out.append({"model": model, "speaker": spk, "seen": sel[0]["split"] == "seen",
                        "kind": "/".join(sorted({str(r.get("kind") or "") for r in sel})),
                        "input_rate": input_rate, "files": len(sel),
                        "seconds": pooled_row["seconds"], "frames": int(sum(
                            _f(r, "frames") for r in sel)),
                        **{k: pooled_row.get(k) for k in (
                            "viseme_acc", "chance_viseme_acc", stream_key,
                            "bilabial_closed_frac", "chance_bilabial_closed_frac",
                            "r_reference", "chance_r_reference")},
                        "bilabial_segments": _count(sel, "bilabial_segments")})
    return out


def compare(per_file: list, model_a: str, model_b: str, figure: str, stream_key: str, *,
            split: str = "unseen-test", input_rate: str = "native") -> dict | None:
    """``model_a`` − ``model_b`` on ``figure`` over the recordings both were scored on in
    ``split`` at ``input_rate``, with the paired speaker-level interval (the same draws for
    both); None when they share no recording with the figure."""
    num, den, _ = figures(stream_key)[figure]

    def rows(model):
        return {r["id"]: r for r in per_file if r["model"] == model and SPLITS[split](r)
                and str(r.get("input_rate", "native")) == input_rate}

    a, b = rows(model_a), rows(model_b)
    ids = [i for i in a if i in b and math.isfinite(_f(a[i], num))
           and math.isfinite(_f(b[i], num)) and _f(a[i], den) > 0 and _f(b[i], den) > 0]
    if not ids:
        return None
    spk = [a[i]["speaker"] for i in ids]
    # b's per-recording figure on a's weights (frame counts may differ by one frame of rounding)
    w = [_f(a[i], den) for i in ids]
    ha = [_f(a[i], num) for i in ids]
    hb = [_f(b[i], num) / _f(b[i], den) * wi for i, wi in zip(ids, w)]
    iv = paired_interval(spk, ha, hb, w)
    return {"model_a": model_a, "model_b": model_b, "figure": figure, "split": split,
            "input_rate": input_rate, "files": len(ids), "speakers": len(set(spk)),
            "a": pooled(ha, w), "b": pooled(hb, w), "difference": pooled(ha, w) - pooled(hb, w),
            "lo": iv.lo, "hi": iv.hi, "interval_note": iv.reason}
