"""Real-time animation: per-frame compute of the streaming animator, its latency, and the speed
of offline animation (markers, rendering and H.264 encoding) as a multiple of real time.

Targets: streaming per-frame compute (MFCC of the new hop + gate + MLP + cascade + Eq. 2
reconstruction) p99 <= 1 ms on one core; algorithmic latency = 3-frame look-ahead + half an
analysis window. Runs on one core (BLAS and torch threads set to 1).
"""
from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[var] = "1"

import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from _common import parse_args, report  # noqa: E402

from data_synth.generate import synthesize_corpus  # noqa: E402
from face_model.corpus import load_corpus  # noqa: E402
from face_model.motion_units import fit_corpus_units  # noqa: E402
from face_model.render import FaceRenderer  # noqa: E402
from mapping import build_dataset, make_mapper, split_masks  # noqa: E402
from mapping.animator import FaceAnimator, StreamingAnimator  # noqa: E402
from mapping.checkpoint import AudioMapping, rest_mups  # noqa: E402
from talkingface.config import Config  # noqa: E402


def main() -> None:
    import torch

    torch.set_num_threads(1)
    args = parse_args(__doc__.splitlines()[0])
    cfg = Config()
    with tempfile.TemporaryDirectory() as tmp:
        synthesize_corpus(Path(tmp) / "corpus", cfg.synth, cfg.seed, progress=False)
        corpus = load_corpus(Path(tmp) / "corpus")
        units, _ = fit_corpus_units(corpus)
        data = build_dataset(corpus, units)
        masks = split_masks(data, "utterance", seed=cfg.seed)
        mapper = make_mapper("gated_mlp", cfg.mapping, n_utterance=units.n_utterance,
                             random_state=cfg.seed).fit(data, masks)
        sr = corpus.utterances[0].sample_rate
        anim = FaceAnimator(AudioMapping(mapper, sample_rate=sr, n_utterance=units.n_utterance,
                                         rest_mups=rest_mups(units)), units)
        test = [u for u, m in zip(corpus.utterances, masks) if not m.any()][:20]
        per_frame = []
        for _ in range(args.repeat):
            for u in test:
                s = StreamingAnimator(anim, u.expression)
                for i in range(0, len(u.audio), s.hop):  # one hop per push: one frame each
                    t0 = time.perf_counter()
                    out = s.push(u.audio[i:i + s.hop])
                    if out:
                        per_frame.append((time.perf_counter() - t0) / len(out))
        u = test[0]
        renderer = FaceRenderer()
        t0 = time.perf_counter()
        _, markers = anim.animate(u.audio, sr, u.expression)
        frames = [renderer.render(m) for m in markers]
        render_s = time.perf_counter() - t0
        from talkingface.animate import write_mp4
        wav = Path(tmp) / "corpus" / "audio" / f"{u.utt_id}.wav"
        t0 = time.perf_counter()
        write_mp4(Path(tmp) / "out.mp4", iter(frames), len(frames), renderer.size, fps=30,
                  audio_path=wav, progress=False)
        encode_s = time.perf_counter() - t0
    audio_s = len(u.audio) / sr
    pf = np.array(per_frame) * 1000
    report({"stream_frame_p50_ms": float(np.percentile(pf, 50)),
            "stream_frame_p99_ms": float(np.percentile(pf, 99)), "target_p99_ms": 1.0,
            "frames_measured": len(pf), "algorithmic_latency_ms": 1000 * s.latency_s,
            "animate_markers_render_x_realtime": audio_s / render_s,
            "animate_with_encoding_x_realtime": audio_s / (render_s + encode_s)}, args.json)


if __name__ == "__main__":
    main()
