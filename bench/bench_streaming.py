"""Real-time animation: per-frame compute of the streaming animator, its latency, and the speed
of offline animation (markers, rendering and H.264 encoding) as a multiple of real time.

Targets: streaming per-frame compute (MFCC of the new hop + gate + MLP + cascade + Eq. 2
reconstruction) p99 <= 1 ms on one core; algorithmic latency = 3-frame look-ahead + half an
analysis window. Runs on one core (BLAS and torch threads set to 1).

``--cmvn MODE`` streams a model trained with that causal cepstral normalisation (issue 12);
``--cmvn compare`` trains one model without CMVN and one with "meanvar" on the same data, streams
the same utterances through both (interleaved, so machine load hits both alike) and reports the
per-frame cost of each and their ratio (target: <= 1.25). ``--front-end phones`` streams the
phone-input model (the recogniser gate and MLPs reading its phones, issue 12 part 6: the
default voice-robust model's front end); ``--front-end compare`` streams it beside the paper's
MFCC model in the same way and reports the ratio (target: <= 1.25). ``--sentences N`` shrinks
the corpus. Every run also breaks the first model's per-frame compute into its parts (issue 13):
the MFCC of the new hop with its normalisation (the floor), the gate, the MLP bank, the
expression cascade and the reconstruction of the markers (Eq. 2), the rest being the stream's
bookkeeping and the silence rule, and prints the whole as a multiple of the floor (target: <= 3).
``--look-ahead N`` and ``--window-align right`` set the models' context look-ahead
(frames) and analysis-window alignment; the algorithmic latency printed follows from them exactly.

The recognisers alone (issues 29, 40): every recording of the real-speech set (at 22,050 Hz,
pushed one video frame at a time, the look-ahead 3 frames) through pocketsphinx's, hama's and
the shipped causal front end's streams (mapping.recogniser.RECOGNISERS), interleaved recording
by recording; per-frame cost p50 / p99 / mean and the decision latency. Target: p99 <= 3 ms per
frame. ``--no-recognisers`` skips it.
"""
from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[var] = "1"

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from _common import report  # noqa: E402

from data_synth.generate import synthesize_corpus  # noqa: E402
from face_model.corpus import load_corpus  # noqa: E402
from face_model.motion_units import fit_corpus_units  # noqa: E402
from face_model.render import FaceRenderer  # noqa: E402
from mapping import build_dataset, make_mapper, split_masks  # noqa: E402
from mapping.animator import FaceAnimator, StreamingAnimator  # noqa: E402
from mapping.checkpoint import AudioMapping, rest_mups  # noqa: E402
from talkingface.config import Config  # noqa: E402


def parse_args() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.add_argument("--repeat", type=int, default=3, help="timed passes over the test utterances")
    p.add_argument("--cmvn", choices=("none", "mean", "meanvar", "compare"), default="none",
                   help="the model's cepstral normalisation, or 'compare' (none vs meanvar)")
    p.add_argument("--front-end", choices=("mfcc", "phones", "compare"), default="mfcc",
                   help="the MLPs' input: the MFCC (the paper), the recogniser's phones, or "
                        "'compare' (mfcc vs phones)")
    p.add_argument("--look-ahead", type=int, default=None,
                   help="context look-ahead in frames (mapping.context_forward; default 3)")
    p.add_argument("--window-align", choices=("centre", "right"), default="centre",
                   help="the analysis window centred on the frame instant or ending there")
    p.add_argument("--no-recognisers", action="store_true",
                   help="skip the recognisers' own per-frame cost")
    p.add_argument("--sentences", type=int, default=0,
                   help="corpus sentences (default: the paper's config)")
    return p.parse_args()


def stream_costs(anims: dict, test, repeat: int) -> dict:
    """Per-frame seconds of StreamingAnimator.push for each animator, one hop per push."""
    per_frame = {k: [] for k in anims}
    for _ in range(repeat):
        for u in test:
            for name, anim in anims.items():
                s = StreamingAnimator(anim, u.expression)
                for i in range(0, len(u.audio), s.hop):  # one hop per push: one frame each
                    t0 = time.perf_counter()
                    out = s.push(u.audio[i:i + s.hop])
                    if out:
                        per_frame[name].append((time.perf_counter() - t0) / len(out))
    return {k: np.array(v) * 1000 for k, v in per_frame.items()}


PARTS = (("mfcc", "_feature"), ("gate", "gate_"), ("mlp", "bank_"), ("cascade", "experts_"),
         ("reconstruction", "markers"))


def part_costs(anim, test, repeat: int) -> dict:
    """Mean milliseconds per frame of each part of :data:`PARTS` and of the whole push, from
    one streaming run: each part's method is wrapped with a timer on its instance while the
    test utterances stream one hop per push, then unwrapped."""
    spent = {name: 0.0 for name, _ in PARTS}
    total, frames = 0.0, 0

    def wrap(obj, attr, name):
        inner = getattr(obj, attr)

        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            out = inner(*args, **kwargs)
            spent[name] += time.perf_counter() - t0
            return out
        setattr(obj, attr, timed)
        return obj, attr

    mapper = anim.mapping.mapper
    wrapped = [wrap(anim, "markers", "reconstruction"), wrap(mapper.bank_, "predict", "mlp")]
    if getattr(mapper, "gate_", None) is not None:
        wrapped.append(wrap(mapper.gate_, "predict", "gate"))
    wrapped += [wrap(net, "predict", "cascade") for net in mapper.experts_.values()]
    try:
        for _ in range(repeat):
            for u in test:
                s = StreamingAnimator(anim, u.expression)
                wrap(s, "_feature", "mfcc")
                for i in range(0, len(u.audio), s.hop):
                    t0 = time.perf_counter()
                    out = s.push(u.audio[i:i + s.hop])
                    total += time.perf_counter() - t0
                    frames += len(out)
    finally:
        for obj, attr in wrapped:
            delattr(obj, attr)  # the class's own method again
    out = {f"part_{name}_ms": 1000 * v / frames for name, v in spent.items()}
    out["part_other_ms"] = 1000 * total / frames - sum(out.values())
    out["part_total_ms"] = 1000 * total / frames
    out["total_over_mfcc_floor"] = total / spent["mfcc"] if spent["mfcc"] else float("nan")
    out["target_total_over_mfcc_floor"] = 3.0
    return out


def recogniser_costs(repeat: int, look_ahead: int = 3) -> dict:
    """Per-frame cost (ms) of each recogniser's stream on the real-speech set, pushed one video
    frame of 22,050 Hz audio at a time, the recognisers interleaved per recording."""
    import soxr

    from analysis.speech_set import load_speech_set
    from mapping.recogniser import RECOGNISERS, phone_stream

    sr, fps = 22050, 30
    hop = sr // fps
    clips = [soxr.resample(it.audio, it.sr, sr).astype(np.float32) for it in load_speech_set()]
    costs = {r: [] for r in RECOGNISERS}
    decodes = 0
    for _ in range(repeat):
        for y in clips:
            for r in RECOGNISERS:
                stream = phone_stream(r, sr, fps, look_ahead, 3)
                for i in range(0, len(y), hop):
                    t0 = time.perf_counter()
                    stream.push_windows(y[i:i + hop])
                    costs[r].append(1000 * (time.perf_counter() - t0))
                stream.flush_windows()
                decodes += getattr(stream, "decodes", 0)
    out = {"recogniser_frames": len(costs[RECOGNISERS[0]]),
           "recogniser_lookahead_ms": 1000 * look_ahead / fps}
    for r, c in costs.items():
        out.update({f"{r}_frame_p50_ms": float(np.percentile(c, 50)),
                    f"{r}_frame_p99_ms": float(np.percentile(c, 99)),
                    f"{r}_frame_mean_ms": float(np.mean(c))})
    out["hama_decodes"] = decodes
    out["target_recogniser_p99_ms"] = 3.0
    return out


def main() -> None:
    import torch

    torch.set_num_threads(1)
    args = parse_args()
    cfg = Config()
    if args.sentences:
        cfg = dataclasses.replace(cfg, synth=dataclasses.replace(cfg.synth,
                                                                 n_sentences=args.sentences))
    timing = {"window_align": args.window_align}
    if args.look_ahead is not None:
        timing["context_forward"] = args.look_ahead
    cfg = dataclasses.replace(cfg, mapping=dataclasses.replace(cfg.mapping, **timing))
    phones = dataclasses.replace(cfg.mapping, gate_front_end="recogniser", mlp_input="phones")
    if args.cmvn == "compare":
        what = "cmvn"
        configs = {m: dataclasses.replace(cfg.mapping, cmvn=m) for m in ("none", "meanvar")}
    elif args.front_end == "compare":
        what = "front_end"
        configs = {"mfcc": dataclasses.replace(cfg.mapping, cmvn=args.cmvn), "phones": phones}
    else:
        what = None
        configs = {args.front_end: (phones if args.front_end == "phones"
                                    else dataclasses.replace(cfg.mapping, cmvn=args.cmvn))}
    with tempfile.TemporaryDirectory() as tmp:
        synthesize_corpus(Path(tmp) / "corpus", cfg.synth, cfg.seed, progress=False)
        corpus = load_corpus(Path(tmp) / "corpus")
        units, _ = fit_corpus_units(corpus)
        context = (phones.context_back, phones.context_forward)
        data = build_dataset(corpus, units, recognise_context=(
            context if any(c.mlp_input == "phones" for c in configs.values()) else None),
            window_align=cfg.mapping.window_align, mel_fmax_hz=cfg.mapping.mel_fmax_hz)
        masks = split_masks(data, "utterance", seed=cfg.seed)
        sr = corpus.utterances[0].sample_rate
        anims = {}
        for mode, mcfg in configs.items():
            mapper = make_mapper("gated_mlp", mcfg, n_utterance=units.n_utterance,
                                 random_state=cfg.seed).fit(data, masks)
            anims[mode] = FaceAnimator(AudioMapping(mapper, sample_rate=sr,
                                                    n_utterance=units.n_utterance,
                                                    rest_mups=rest_mups(units),
                                                    window_align=mcfg.window_align,
                                                    mel_fmax_hz=mcfg.mel_fmax_hz), units)
        test = [u for u, m in zip(corpus.utterances, masks) if not m.any()][:20]
        costs = stream_costs(anims, test, args.repeat)
        anim = anims[next(iter(configs))]
        parts = part_costs(anim, test, args.repeat)
        s = StreamingAnimator(anim)
        u = test[0]
        renderer = FaceRenderer()
        t0 = time.perf_counter()
        _, markers = anim.animate(u.audio, sr, u.expression)
        frames = [renderer.render(m) for m in markers]
        render_s = time.perf_counter() - t0
        from talkingface.cli.animate import write_mp4
        wav = Path(tmp) / "corpus" / "audio" / f"{u.utt_id}.wav"
        t0 = time.perf_counter()
        write_mp4(Path(tmp) / "out.mp4", iter(frames), len(frames), renderer.size, fps=30,
                  audio_path=wav, progress=False)
        encode_s = time.perf_counter() - t0
    audio_s = len(u.audio) / sr
    figures = {}
    for mode, pf in costs.items():
        tag = "" if len(costs) == 1 else f"_{mode}"
        figures.update({f"stream_frame_p50_ms{tag}": float(np.percentile(pf, 50)),
                        f"stream_frame_mean_ms{tag}": float(np.mean(pf)),
                        f"stream_frame_p99_ms{tag}": float(np.percentile(pf, 99))})
    if what is not None:
        a, b = (costs[k] for k in configs)
        figures.update({f"{what}_cost_ratio_p50": float(np.percentile(b, 50)
                                                        / np.percentile(a, 50)),
                        f"{what}_cost_ratio_mean": float(np.mean(b) / np.mean(a)),
                        f"target_{what}_cost_ratio": 1.25})
    rec = {} if args.no_recognisers else recogniser_costs(max(1, args.repeat - 1))
    report({"cmvn": args.cmvn, "front_end": args.front_end, **figures, **parts, **rec,
            "target_p99_ms": 1.0,
            "frames_measured": sum(len(v) for v in costs.values()),
            "algorithmic_latency_ms": 1000 * s.latency_s,
            "animate_markers_render_x_realtime": audio_s / render_s,
            "animate_with_encoding_x_realtime": audio_s / (render_s + encode_s)}, args.json)


if __name__ == "__main__":
    main()
