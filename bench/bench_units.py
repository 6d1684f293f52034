"""Wall time to fit the Motion Units (alignment + deformations + PCA) on the paper-size corpus.

Target: <= 5 s on the 2-core machine. Prints the best of --repeat runs.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

from _common import parse_args, report

from data_synth.generate import synthesize_corpus
from face_model.corpus import load_corpus
from face_model.motion_units import fit_corpus_units
from talkingface.config import Config


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    cfg = Config()
    with tempfile.TemporaryDirectory() as tmp:
        synthesize_corpus(Path(tmp) / "corpus", cfg.synth, cfg.seed, progress=False)
        corpus = load_corpus(Path(tmp) / "corpus")
    times = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        units, _ = fit_corpus_units(corpus)
        times.append(time.perf_counter() - t0)
    report({"mu_fit_s": min(times), "frames": corpus.n_frames, "target_s": 5.0,
            **{f"explained_{k}": v for k, v in units.variance_explained().items()}}, args.json)


if __name__ == "__main__":
    main()
