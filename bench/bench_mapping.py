"""Training and inference speed of the paper's audio-to-MUP mapping on the paper-size corpus.

Targets (2-core machine): training the full mapping (features, gate, MLP bank and the
expression cascade, paper's random_frames split) <= 120 s; batch inference (features + gate +
MLP + cascade, from audio samples to MUPs) >= 1000x real time. Prints the best of --repeat runs.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

from _common import parse_args, report

from data_synth.generate import synthesize_corpus
from face_model.corpus import load_corpus
from face_model.motion_units import fit_corpus_units
from mapping import build_dataset, make_mapper, split_masks
from mapping.checkpoint import AudioMapping, rest_mups
from talkingface.config import Config


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    cfg = Config()
    m = cfg.mapping
    with tempfile.TemporaryDirectory() as tmp:
        synthesize_corpus(Path(tmp) / "corpus", cfg.synth, cfg.seed, progress=False)
        corpus = load_corpus(Path(tmp) / "corpus")
    units, _ = fit_corpus_units(corpus)
    train_times, infer_times = [], []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        data = build_dataset(corpus, units, n_mfcc=m.n_mfcc, deltas=m.deltas,
                             mel_fmax_hz=m.mel_fmax_hz)
        masks = split_masks(data, "random_frames", train_fraction=m.train_fraction, seed=cfg.seed)
        mapper = make_mapper("gated_mlp", m, n_utterance=units.n_utterance,
                             random_state=cfg.seed).fit(data, masks)
        train_times.append(time.perf_counter() - t0)
        model = AudioMapping(mapper, sample_rate=corpus.utterances[0].sample_rate,
                             n_mfcc=m.n_mfcc, deltas=m.deltas, n_utterance=units.n_utterance,
                             rest_mups=rest_mups(units), mel_fmax_hz=m.mel_fmax_hz)
        t0 = time.perf_counter()
        for u in corpus.utterances:
            model.predict_audio(u.audio, u.sample_rate, u.expression)
        infer_times.append(time.perf_counter() - t0)
    audio_s = sum(len(u.audio) / u.sample_rate for u in corpus.utterances)
    report({"train_s": min(train_times), "train_target_s": 120.0, "frames": corpus.n_frames,
            "audio_s": audio_s, "inference_s": min(infer_times),
            "inference_x_realtime": audio_s / min(infer_times), "inference_target_x": 1000.0},
           args.json)


if __name__ == "__main__":
    main()
