"""Wall time to generate the paper-size corpus (100 sentences x 3 expressions, one speaker).

Target: <= 60 s on the 2-core machine. Prints the best of --repeat runs.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

from _common import parse_args, report

from data_synth.generate import synthesize_corpus
from face_model.corpus import load_corpus
from talkingface.config import Config


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    cfg = Config()
    times = []
    for _ in range(args.repeat):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            synthesize_corpus(Path(tmp) / "corpus", cfg.synth, cfg.seed, progress=False)
            times.append(time.perf_counter() - t0)
            corpus = load_corpus(Path(tmp) / "corpus")
    report({"corpus_generation_s": min(times), "corpus_generation_s_all": [round(t, 3) for t in times],
            "utterances": len(corpus), "frames": corpus.n_frames,
            "frames_per_s": corpus.n_frames / min(times), "target_s": 60.0}, args.json)


if __name__ == "__main__":
    main()
