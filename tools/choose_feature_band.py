"""Choose the mel filterbank's upper edge (``mapping.mel_fmax_hz``, issue 37) on development data.

    python tools/choose_feature_band.py [--seed N] [--run-seed N] [--json] [--check]

The question: which band should the MFCC read so that a model trained on 22,050 Hz audio
animates a 16 kHz (or 8 kHz) recording as well as its training-rate audio? A recording at
16 kHz has nothing above 8 kHz; filters up to sr/2 = 11,025 Hz read that empty band.

Data. The real speaker of the built-in corpus (``face_model/real_faces/grid-s1``), its
*training* sentences only: the pipeline's utterance split (:func:`mapping.dataset.split_masks`
with the run seed + :data:`mapping.experiment.SPLIT_SEED_OFFSET` and ``mapping.train_fraction``,
as :func:`mapping.experiment.run_experiment` draws it for the real-speaker stage) leaves its test
sentences untouched here; the training sentences are split again by sentence, 80/20 with
``--seed``, into fit and development sentences.

Candidates. The edge at sr/2 (11,025 Hz, the paper's filterbank), 8,000, 7,600 and 4,000 Hz.
For each, the Motion Units are fitted on the fit sentences' markers
(:func:`face_model.motion_units.fit_corpus_units`, the units' default settings) and the paper's
gated MLP (``MappingConfig`` defaults but the edge) is trained on the fit sentences by
:func:`mapping.experiment.train_method`, seeded with ``--seed``.

Scores, on the development sentences, with their audio resampled from 22,050 Hz down to each
input rate (22,050, 16,000, 8,000 Hz; :func:`groundwork.audio.resample`) and given to the model
at that rate (:meth:`mapping.checkpoint.AudioMapping.predict_audio` resamples it back to the
model's rate, as it does for any user's recording):

* ``r`` — Pearson r of the predicted inner-lip opening (:func:`face_model.layout.mouth_opening`
  of the markers the animator draws, :class:`mapping.animator.FaceAnimator`) against the real
  lips' opening (aligned markers), each clip centred and scaled to unit deviation before the
  frames of all clips are pooled; ``median clip r`` beside it;
* ``viseme`` — the gate's viseme accuracy per frame against the corpus's phone labels
  (:func:`analysis.speech_eval.group_viseme`; frames pooled).

Rule (fixed before the sweep was run; :func:`choose`): among the candidates whose pooled r drops
by at most :data:`MAX_DROP` from 22,050 to 16,000 Hz input, the one with the best mean pooled r
over the three input rates; means equal to three decimals go to the higher edge. If none
qualifies, the smallest 16 kHz drop. ``--check`` exits 1, with one line, when
``MappingConfig().mel_fmax_hz`` is not the pick.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.speech_eval import group_viseme, viseme_index  # noqa: E402
from face_model.alignment import align_markers  # noqa: E402
from face_model.config import UnitsConfig  # noqa: E402
from face_model.corpus import load_corpus  # noqa: E402
from face_model.layout import mouth_opening  # noqa: E402
from face_model.motion_units import fit_corpus_units  # noqa: E402
from groundwork.audio import resample  # noqa: E402
from mapping.animator import FaceAnimator  # noqa: E402
from mapping.checkpoint import AudioMapping, rest_mups  # noqa: E402
from mapping.config import MappingConfig  # noqa: E402
from mapping.dataset import build_dataset, split_masks  # noqa: E402
from mapping.experiment import SPLIT_SEED_OFFSET, train_method  # noqa: E402
from talkingface.config import Config  # noqa: E402

CORPUS = Path(__file__).resolve().parents[1] / "face_model" / "real_faces" / "grid-s1"
CANDIDATES = (0.0, 8000.0, 7600.0, 4000.0)  # Hz; 0 is sr/2 (11,025 Hz at 22,050 Hz)
RATES = (22050, 16000, 8000)  # Hz, the input rates scored
MAX_DROP = 0.02  # the largest 22.05 → 16 kHz drop of pooled r a pick may have
DEV_FRACTION = 0.2  # of the training sentences


def edge_hz(candidate: float, sr: int) -> float:
    """The upper edge in Hz a candidate value stands for (0: sr/2)."""
    return float(candidate) if candidate else sr / 2.0


def choose(table: dict, *, max_drop: float = MAX_DROP, rates=RATES, sr: int = 22050) -> float:
    """The rule of the module docstring on ``table``: ``{candidate: {rate: r}}``.

    Parameters
    ----------
    table : dict of float to dict of int to float
        Pooled r of each candidate (a ``mapping.mel_fmax_hz`` value, 0 for sr/2) at each input
        rate (Hz); the first of ``rates`` is the training rate.
    max_drop : float
        The largest drop from the training rate to 16,000 Hz that qualifies.
    rates : tuple of int
        The input rates averaged.
    sr : int
        The training rate (for the edge of candidate 0 in ties).

    Returns
    -------
    float
        The chosen candidate.
    """
    def drop(c):
        return table[c][rates[0]] - table[c][16000]

    qualified = [c for c in table if drop(c) <= max_drop + 1e-12]
    if not qualified:
        return min(table, key=lambda c: (round(drop(c), 3), -edge_hz(c, sr)))
    return max(qualified, key=lambda c: (round(float(np.mean([table[c][r] for r in rates])), 3),
                                         edge_hz(c, sr)))


def sentence_split(utts: list, fraction: float, seed: int) -> tuple[list, list]:
    """``(train, test)`` utterances by sentence (:func:`mapping.dataset.split_masks`)."""
    masks = split_masks(utts, "utterance", train_fraction=fraction, seed=seed)
    return ([u for u, m in zip(utts, masks) if m.all()],
            [u for u, m in zip(utts, masks) if not m.any()])


def development_sets(corpus, *, run_seed: int, seed: int) -> tuple[list, list, list]:
    """``(fit, dev, test)`` utterances: the pipeline's utterance split of ``run_seed``, then its
    training part split again 80/20 by sentence with ``seed``."""
    train, test = sentence_split(corpus.utterances, MappingConfig().train_fraction,
                                 run_seed + SPLIT_SEED_OFFSET)
    fit, dev = sentence_split(train, 1.0 - DEV_FRACTION, seed)
    assert not {u.text for u in fit + dev} & {u.text for u in test}
    return fit, dev, test


def _z(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    return (x - x.mean()) / (x.std() + 1e-12)


def score(animator: FaceAnimator, dev: list, rate: int, alignment: str) -> dict:
    """Pooled and median per-clip r of the lip opening, and the gate's viseme accuracy, of
    ``dev`` utterances given to the model at ``rate`` Hz."""
    mapping = animator.mapping
    reals, preds, clip_r, hits, frames = [], [], [], 0, 0
    for u in dev:
        y = resample(u.audio, sr_in=u.sample_rate, sr_out=rate)
        mups = mapping.predict_audio(y, rate)
        pred = mouth_opening(animator.markers(mups))
        real = mouth_opening(align_markers(u.markers, model=alignment))
        n = min(len(pred), len(real))
        zr, zp = _z(real[:n]), _z(pred[:n])
        reals.append(zr)
        preds.append(zp)
        clip_r.append(float(np.corrcoef(zr, zp)[0, 1]))
        gated = mapping.gate_classes(y, rate)
        truth = viseme_index(u.phone_per_frame())
        m = min(len(gated), len(truth))
        names = [mapping.mapper.class_names_[g] for g in gated[:m]]
        hits += int(np.sum(truth[:m] == np.array([group_viseme(x) for x in names])))
        frames += m
    pooled = float(np.corrcoef(np.concatenate(reals), np.concatenate(preds))[0, 1])
    return {"r": pooled, "median_clip_r": float(np.median(clip_r)), "viseme": hits / frames}


def sweep(*, seed: int, run_seed: int, candidates=CANDIDATES, progress: bool = True) -> dict:
    """Train and score every candidate; the record ``--json`` prints."""
    corpus = load_corpus(CORPUS)
    fit, dev, test = development_sets(corpus, run_seed=run_seed, seed=seed)
    fit_corpus = dataclasses.replace(corpus, utterances=fit)
    ucfg = UnitsConfig()
    units, _ = fit_corpus_units(fit_corpus, n_utterance=ucfg.n_utterance,
                                n_expression=ucfg.n_expression, alignment=ucfg.alignment)
    sr = fit[0].sample_rate
    rows = {}
    bar = tqdm(total=len(candidates) * (1 + len(RATES)), desc="band sweep", unit="step",
               disable=not progress)
    for c in candidates:
        mcfg = dataclasses.replace(MappingConfig(), mel_fmax_hz=float(c))
        data = build_dataset(fit_corpus, units, n_mfcc=mcfg.n_mfcc, deltas=mcfg.deltas,
                             window_align=mcfg.window_align, mel_fmax_hz=mcfg.mel_fmax_hz)
        masks = [np.ones(d.n_frames, bool) for d in data]
        trained = train_method("gated_mlp", data, masks, mcfg, n_utterance=units.n_utterance,
                               split="utterance", seed=seed)
        bar.update()
        mapping = AudioMapping(trained.mapper, sample_rate=sr, fps=fit[0].fps,
                               n_mfcc=mcfg.n_mfcc, deltas=mcfg.deltas,
                               n_utterance=units.n_utterance, rest_mups=rest_mups(units),
                               window_align=mcfg.window_align, mel_fmax_hz=mcfg.mel_fmax_hz)
        animator = FaceAnimator(mapping, units)
        rows[c] = {}
        for rate in RATES:
            rows[c][rate] = score(animator, dev, rate, ucfg.alignment)
            bar.update()
    bar.close()
    table = {c: {rate: v["r"] for rate, v in rs.items()} for c, rs in rows.items()}
    pick = choose(table, sr=sr)
    return {"corpus": str(CORPUS.relative_to(CORPUS.parents[2])), "seed": seed,
            "run_seed": run_seed, "sample_rate": sr,
            "sentences": {"fit": len({u.text for u in fit}), "dev": len({u.text for u in dev}),
                          "test_untouched": len({u.text for u in test})},
            "utterances": {"fit": len(fit), "dev": len(dev), "test_untouched": len(test)},
            "dev_utterances": [u.utt_id for u in dev], "max_drop": MAX_DROP,
            "results": [{"mel_fmax_hz": c, "edge_hz": edge_hz(c, sr),
                         **{f"{k}_{rate}": rs[rate][k] for rate in RATES
                            for k in ("r", "median_clip_r", "viseme")},
                         "drop_16k": rs[RATES[0]]["r"] - rs[16000]["r"],
                         "drop_8k": rs[RATES[0]]["r"] - rs[8000]["r"],
                         "mean_r": float(np.mean([rs[rate]["r"] for rate in RATES]))}
                        for c, rs in rows.items()],
            "pick": pick}


def print_table(record: dict) -> None:
    """The table of the sweep, one candidate per line, and the pick."""
    print(f"{record['corpus']}: fit {record['utterances']['fit']} / development "
          f"{record['utterances']['dev']} utterances of the training sentences (seed "
          f"{record['seed']}); {record['utterances']['test_untouched']} test utterances of run "
          f"seed {record['run_seed']} untouched")
    head = "".join(f"  {f'r@{r / 1000:g}k':>8}  {f'clip@{r / 1000:g}k':>11}  "
                   f"{f'vis@{r / 1000:g}k':>10}" for r in RATES)
    print(f"{'edge Hz':>8}{head}  drop16  drop8  mean r")
    for row in record["results"]:
        cells = "".join(f"  {row[f'r_{r}']:8.3f}  {row[f'median_clip_r_{r}']:11.3f}"
                        f"  {row[f'viseme_{r}']:10.3f}" for r in RATES)
        print(f"{row['edge_hz']:8.0f}{cells}  {row['drop_16k']:6.3f}  {row['drop_8k']:5.3f}"
              f"  {row['mean_r']:6.3f}")
    print(f"pick (best mean r over the rates among 16 kHz drops <= {record['max_drop']}; ties: "
          f"the higher edge): mapping.mel_fmax_hz = {record['pick']:g}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=0,
                    help="the fit/development split and the training seed (default 0)")
    ap.add_argument("--run-seed", type=int, default=Config().seed,
                    help="the run seed whose utterance split's test sentences stay untouched "
                         "(default: the config's)")
    ap.add_argument("--json", action="store_true", help="print the record as JSON")
    ap.add_argument("--check", action="store_true",
                    help="exit 1 when MappingConfig's mel_fmax_hz is not the pick")
    args = ap.parse_args(argv)
    record = sweep(seed=args.seed, run_seed=args.run_seed, progress=not args.json)
    if args.json:
        print(json.dumps(record, indent=1))
    else:
        print_table(record)
    default = MappingConfig().mel_fmax_hz
    if args.check and edge_hz(default, record["sample_rate"]) != edge_hz(record["pick"],
                                                                        record["sample_rate"]):
        print(f"mapping.mel_fmax_hz default {default:g} differs from the development pick "
              f"{record['pick']:g} (tools/choose_feature_band.py)")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
