"""Where the real speaker's Table II R goes (issue 39): the steps that need no trained mapping,
measured on the real speaker's *training* sentences only.

    python tools/real_speaker_steps.py [--corpus DIR] [--seed N] [--json]

Data. The built-in real speaker (``face_model/real_faces/grid-s1``) or ``--corpus``; its
training sentences of the pipeline's utterance split (:func:`mapping.dataset.training_sentences`
with the run seed + :data:`mapping.experiment.SPLIT_SEED_OFFSET` and ``mapping.train_fraction``,
as the real-speaker stage draws them). The held-out sentences are never read. The Motion Units
are fitted on those sentences (the units' default settings), the features are the pipeline's
(:func:`mapping.dataset.build_dataset`: MFCC at the run's ``mapping.mel_fmax_hz``).

Probe. A ridge regression (:func:`analysis.real_ceiling.offset_scores`) fitted on every other
training sentence and scored by Eq. 6 on the rest, then the other way round (mean R): one
fixed, fast model, so that the rows differ only in what they change.

Rows printed:

* the measurement floor: R of the markers against their Motion Units' reconstruction, and the
  R of the truth against its 3- and 5-frame moving average (landmark jitter);
* the audio–video offset: R for lags -6..6 frames and the best lag;
* the audio context: R for ±0, 3, 6, 10, 15 frames of MFCC context;
* the oracle: the true phones (one-hot, ±3, 6 and 10 frames of context) instead of the audio,
  and the phones with the audio;
* per Motion Unit: its share of the variance, where it moves (region and x shares) and the R
  the audio reaches on it alone (±6 frames).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.real_ceiling import (best_offset, offset_scores, phone_onehot,  # noqa: E402
                                   reconstruction_r, region_loadings, smoothing_floor)
from face_model.alignment import corpus_deformations  # noqa: E402
from face_model.corpus import Corpus, load_corpus  # noqa: E402
from face_model.layout import REGIONS  # noqa: E402
from face_model.motion_units import MotionUnits  # noqa: E402
from face_model.phones import N_PHONES  # noqa: E402
from mapping.dataset import build_dataset, training_sentences  # noqa: E402
from mapping.experiment import SPLIT_SEED_OFFSET  # noqa: E402
from talkingface.config import Config  # noqa: E402
from talkingface.stages.real_speaker import BUILTIN  # noqa: E402

LAGS = range(-6, 7)
CONTEXTS = (0, 3, 6, 10, 15)
ORACLE_CONTEXTS = (3, 6, 10)
PER_UNIT_CONTEXT = 6


def training_part(corpus: Corpus, seed: int, train_fraction: float) -> Corpus:
    """The corpus's utterances whose sentence is a training sentence of the utterance split."""
    train = training_sentences([u.text for u in corpus.utterances],
                               train_fraction=train_fraction, seed=seed + SPLIT_SEED_OFFSET)
    return Corpus(corpus.root, corpus.info, [u for u in corpus.utterances if u.text in train])


def measure(corpus_dir: Path, seed: int) -> dict:
    """Every row of the module text, as a dict."""
    cfg = Config()
    part = training_part(load_corpus(corpus_dir), seed, cfg.mapping.train_fraction)
    defs = corpus_deformations(part, model=cfg.units.alignment)
    units = MotionUnits(cfg.units.n_utterance, cfg.units.n_expression).fit(
        {"neutral": np.concatenate([defs[u.utt_id] for u in part.utterances])},
        metadata={"alignment": cfg.units.alignment})
    data = build_dataset(part, units, n_mfcc=cfg.mapping.n_mfcc,
                         mel_fmax_hz=cfg.mapping.mel_fmax_hz)
    feats, mups = [d.features for d in data], [d.mups for d in data]
    markers = [defs[d.utt_id] for d in data]
    recon = [units.inverse_transform(m) for m in mups]
    m_all = np.concatenate(markers)
    scale = np.where(np.abs(m_all).max(0) > 0, np.abs(m_all).max(0), 1.0)
    out = {"corpus": str(corpus_dir), "training_sentences": len(data),
           "frames": int(sum(len(f) for f in feats)),
           "reconstruction_r": reconstruction_r(m_all, np.concatenate(recon)),
           "smoothing_floor": {w: smoothing_floor([m / scale for m in markers], w)
                               for w in (3, 5)}}
    lags = offset_scores(feats, mups, LAGS)
    out["offset"] = {"r": lags, "best": best_offset(lags)}
    out["context"] = {k: offset_scores(feats, mups, [0], context=k)[0] for k in CONTEXTS}
    onehot = [phone_onehot(d.phones, N_PHONES) for d in data]
    out["oracle"] = {k: offset_scores(onehot, mups, [0], context=k)[0] for k in ORACLE_CONTEXTS}
    out["oracle_and_audio"] = offset_scores([np.hstack(p) for p in zip(onehot, feats)], mups,
                                            [0], context=PER_UNIT_CONTEXT)[0]
    share = units.variance_[:units.n_utterance] / units.variance_[:units.n_utterance].sum()
    where = region_loadings(units.components_[:units.n_utterance],
                            {k: v for k, v in REGIONS.items() if k != "glasses"})
    out["units"] = [{"unit": j, "variance_share": float(share[j]), **where[j],
                     "r_audio": offset_scores(feats, [m[:, j:j + 1] for m in mups], [0],
                                              context=PER_UNIT_CONTEXT)[0]}
                    for j in range(units.n_utterance)]
    return out


def show(res: dict) -> None:
    print(f"{res['corpus']}: {res['training_sentences']} training sentences, "
          f"{res['frames']} frames (held-out sentences not read)")
    print(f"measurement floor: markers vs their MU reconstruction R {res['reconstruction_r']:.3f};"
          " truth vs its moving average R " + ", ".join(
              f"{v:.3f} ({w} frames)" for w, v in res["smoothing_floor"].items()))
    print("audio-video offset (lag: R): " + ", ".join(
        f"{k:+d}: {v:.3f}" for k, v in res["offset"]["r"].items())
        + f"; best {res['offset']['best']:+d}")
    print("audio context (frames either side: R): " + ", ".join(
        f"{k}: {v:.3f}" for k, v in res["context"].items()))
    print("oracle, true phones (context: R): " + ", ".join(
        f"{k}: {v:.3f}" for k, v in res["oracle"].items())
        + f"; phones and audio: {res['oracle_and_audio']:.3f}")
    print(f"{'unit':>4s} {'var':>6s} {'lips':>6s} {'cheeks':>6s} {'brows':>6s} {'x':>6s} "
          f"{'R audio':>7s}")
    for u in res["units"]:
        print(f"{u['unit']:4d} {u['variance_share']:6.3f} {u['lips']:6.2f} {u['cheeks']:6.2f} "
              f"{u['forehead']:6.2f} {u['x']:6.2f} {u['r_audio']:7.3f}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--corpus", type=Path, default=BUILTIN)
    p.add_argument("--seed", type=int, default=Config().seed, help="the run seed")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    res = measure(args.corpus, args.seed)
    if args.json:
        print(json.dumps(res, indent=1, default=float))
    else:
        show(res)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
