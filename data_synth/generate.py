"""Generate the synthetic audio-visual corpus (``talkingface synth``).

For every speaker × expression × sentence: synthesise speech with phone timing, pad it with
silence to a whole number of 30 fps frames, coarticulate the phones into articulatory trajectories,
drive the parametric face with them (and with the expression's envelope), add head motion and
marker noise, and write the corpus contract of DESIGN.md. Every random draw comes from a generator
seeded by ``(seed, speaker, expression, sentence)``, so the corpus does not depend on the order or
the number of worker processes, and the same seed gives byte-identical files.

With ``synth.voices`` set, each utterance also draws its voice (:func:`draw_voice`, its own
stream: no other draw changes), independently of the face: the manifest then has a ``voice``
column (``engine:voice``) and ``corpus.json`` a ``voices`` list with each voice's real source
speaker. With ``synth.voices`` empty the corpus is exactly that of the single-voice design.
"""
from __future__ import annotations

import json
import os
import platform
import shutil
from dataclasses import asdict, dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from data_synth.articulation import (articulation_file, articulation_model, coarticulate,
                                     file_sha256)
from data_synth.backends import (check_voices_installed, get_backend, parse_voice,
                                 voice_backend, voice_sample_rate, voice_speaker)
from data_synth.face import Speaker, articulate, expression_envelope, make_speaker
from data_synth.nuisance import add_marker_noise, apply_head_motion, brow_track, head_motion
from data_synth.speech import SynthRequest, phone_segments
from data_synth.text import select_sentences
from face_model.corpus import EXPRESSIONS, FPS, write_manifest, write_utterance
from face_model.layout import LAYOUT_VERSION
from groundwork.atomic import fresh_partial_folder, swap_in
from groundwork.audio import seconds_to_samples
from groundwork.errors import ParameterError


@dataclass(frozen=True)
class UtterancePlan:
    utt_id: str
    speaker: int
    expression: str
    sentence_index: int
    text: str
    request: SynthRequest
    voice: str = ""  # "engine:voice" when synth.voices is set


VOICE_STREAM = 48611  # tags the voice draw's generator, apart from every other draw


def draw_voice(cfg, seed: int, speaker: int, expression: str, sentence: int) -> str:
    """The voice (one of ``cfg.voices``, by ``cfg.voice_weights``) of one utterance.

    Drawn from its own generator, seeded by ``(seed, VOICE_STREAM, speaker, expression,
    sentence)``: the same utterance gets the same voice whatever else the corpus holds, and no
    other draw of the corpus changes. A voice of weight 0 is never drawn.

    Parameters
    ----------
    cfg : SynthConfig
        Its ``voices`` (``engine:voice`` strings) and ``voice_weights`` (equal when empty).
    seed : int
        The corpus seed.
    speaker : int
        The speaker's index.
    expression : str
        One of the corpus expressions.
    sentence : int
        The sentence's index.

    Returns
    -------
    str
        ``engine:voice``.
    """
    w = np.asarray(cfg.voice_weights or [1.0] * len(cfg.voices), dtype=np.float64)
    rng = np.random.default_rng([seed, VOICE_STREAM, speaker, EXPRESSIONS.index(expression),
                                 sentence])
    return cfg.voices[int(rng.choice(len(w), p=w / w.sum()))]


def _check(cfg) -> None:
    bad = [e for e in cfg.expressions if e not in EXPRESSIONS]
    if bad or not cfg.expressions:
        raise ParameterError(f"synth.expressions {list(cfg.expressions)}: allowed values are "
                             f"{', '.join(EXPRESSIONS)}")
    if cfg.speakers < 1:
        raise ParameterError(f"synth.speakers must be >= 1, got {cfg.speakers}")
    if cfg.marker_noise_px < 0 or cfg.head_rotation_deg < 0 or cfg.head_translation_px < 0:
        raise ParameterError("synth nuisance magnitudes must be >= 0")


def plan_corpus(cfg, seed: int) -> tuple[list[Speaker], list[UtterancePlan]]:
    """The speakers and the utterances to generate, in manifest order.

    Parameters
    ----------
    cfg : SynthConfig
    seed : int
        The corpus seed.

    Returns
    -------
    speakers : list of Speaker
    plans : list of UtterancePlan
        Speaker by speaker, expression by expression, sentence by sentence.

    Raises
    ------
    ParameterError
        An unknown expression, no speaker, or a negative nuisance magnitude.
    """
    _check(cfg)
    sentences = select_sentences(cfg.n_sentences, cfg.text_file)
    speakers = [make_speaker(i, cfg, seed) for i in range(cfg.speakers)]
    prosody = {"neutral": (0, 0), "smile": (cfg.smile_pitch_delta, cfg.smile_rate_delta),
               "sad": (cfg.sad_pitch_delta, cfg.sad_rate_delta)}
    plans = []
    for spk in speakers:
        for expr in cfg.expressions:
            dp, dr = prosody[expr]
            for i, text in enumerate(sentences):
                spec = draw_voice(cfg, seed, spk.index, expr, i) if cfg.voices else ""
                req = SynthRequest(text=text,
                                   voice=parse_voice(spec)[1] if spec else spk.voice,
                                   rate_wpm=spk.rate_wpm + dr,
                                   pitch=int(np.clip(spk.pitch + dp, 0, 100)),
                                   pitch_range=cfg.pitch_range)
                plans.append(UtterancePlan(f"s{spk.index:02d}_{expr}_{i:03d}", spk.index, expr,
                                           i, text, req, spec))
    return speakers, plans


def build_utterance(plan: UtterancePlan, speaker: Speaker, result, backend, cfg, seed: int):
    """Audio, phone segments and markers of one utterance (paper §IV-A).

    Parameters
    ----------
    plan : UtterancePlan
    speaker : Speaker
    result
        The speech engine's output for ``plan`` (PCM16 ``audio`` at ``sample_rate`` Hz, with
        its phone timing).
    backend
        The speech engine that produced it.
    cfg : SynthConfig
        Silence before and after the speech (s), noise, coarticulation, expression and head
        motion settings.
    seed : int
        The corpus seed (with the speaker, expression and sentence it seeds the utterance's
        draws).

    Returns
    -------
    audio : ndarray, shape (n_frames · sr / 30,), float64
        The speech padded with ``cfg.lead_silence_s`` and at least ``cfg.trail_silence_s`` of
        silence, plus noise, full scale 1.
    segments : list of PhoneSegment
        Contiguous 44-class phones covering ``audio`` (start and end in seconds).
    markers : ndarray, shape (n_frames, 79, 2), float32
        Image coordinates in pixels at 30 fps, head motion and marker noise included.

    Raises
    ------
    ParameterError
        A sample rate without an integer hop at 30 fps.
    """
    rng = np.random.default_rng([seed, plan.speaker, EXPRESSIONS.index(plan.expression),
                                 plan.sentence_index])
    sr = result.sample_rate
    if sr % FPS:
        raise ParameterError(f"{backend.name} produced {sr} Hz audio, which has no integer hop "
                             f"at {FPS} fps")
    hop = sr // FPS
    speech = result.audio.astype(np.float64) / 32768.0
    lead = seconds_to_samples(cfg.lead_silence_s, sr)
    n_frames = int(np.ceil((lead + len(speech) + cfg.trail_silence_s * sr) / hop))
    audio = np.zeros(n_frames * hop)
    audio[lead:lead + len(speech)] = speech
    audio += 10.0 ** (cfg.audio_noise_dbfs / 20.0) * rng.standard_normal(len(audio))
    segs = phone_segments(result, backend, text=plan.text, lead_samples=lead,
                          total_samples=len(audio))
    times = np.arange(n_frames) / FPS
    artic = coarticulate(segs, times, articulation_model(cfg))
    if plan.expression == "neutral":
        env = np.zeros(n_frames)
    else:
        env = expression_envelope(n_frames, FPS, onset_s=rng.uniform(*cfg.expression_onset_s),
                                  offset_s=rng.uniform(*cfg.expression_offset_s),
                                  intensity=rng.uniform(*cfg.expression_intensity),
                                  delay_s=rng.uniform(0.0, 0.1))
    brow = brow_track(audio, n_frames, hop) * rng.uniform(0.5, 1.0)
    face = articulate(speaker, artic, brow, expression=plan.expression, envelope=env, cfg=cfg)
    motion = head_motion(rng, n_frames, FPS, rotation_deg=cfg.head_rotation_deg,
                         scale=cfg.head_scale, translation_px=cfg.head_translation_px)
    markers = add_marker_noise(rng, apply_head_motion(face, motion), cfg.marker_noise_px)
    return audio, segs, markers.astype(np.float32)


def _check_out(out: Path, overwrite: bool) -> None:
    """Refuse a target that holds anything but a corpus, or a corpus without ``overwrite``."""
    if out.exists() and not out.is_dir():
        raise ParameterError(f"corpus folder {out} is a file; give a folder to create")
    above = next((p for p in out.parents if p.exists()), None)
    if above is not None and not above.is_dir():
        raise ParameterError(f"corpus folder {out}: {above} is a file, not a folder")
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise ParameterError(f"corpus folder {out} already exists and is not empty; "
                                 "choose another folder or pass --overwrite")
        if not (out / "manifest.csv").is_file():
            raise ParameterError(f"{out} is not empty and holds no manifest.csv: refusing to "
                                 "overwrite a folder that is not a corpus")


def package_versions() -> dict:
    names = ("numpy", "scipy", "espeakng-loader", "scikit-learn", "torch", "librosa", "mlflow")
    out = {"python": platform.python_version()}
    for n in names:
        try:
            out[n] = version(n)
        except PackageNotFoundError:  # an optional package that is not installed is not listed
            continue
    return out


def synthesize_corpus(out, cfg, seed: int, *, overwrite: bool = False,
                      progress: bool = True) -> Path:
    """Generate the corpus into folder ``out`` and return its path.

    Parameters
    ----------
    out : path-like
        Target folder; refused if it exists and is not empty, unless ``overwrite`` (and then only
        if it is a corpus folder). The corpus is built beside it and renamed into place when
        complete, so a failure leaves an existing corpus as it was.
    cfg : talkingface.config.SynthConfig
    seed : int
    """
    final = Path(out)
    speakers, plans = plan_corpus(cfg, seed)
    _check_out(final, overwrite)
    if cfg.voices:  # a missing program or voice package is refused before any work
        used = list(dict.fromkeys(p.voice for p in plans))
        check_voices_installed(used)
        backends = {spec: voice_backend(spec) for spec in used}
    else:
        backends = {"": get_backend(cfg.backend)}
    # built beside the target and swapped in when complete: a failure keeps the old corpus
    out = fresh_partial_folder(final)
    try:
        _build_corpus(out, cfg, seed, speakers, plans, backends, progress)
    except BaseException:  # a full disk, a failed voice, Ctrl-C: no half corpus left behind
        shutil.rmtree(out, ignore_errors=True)
        raise
    return swap_in(out, final)


def _build_corpus(out: Path, cfg, seed: int, speakers, plans, backends, progress: bool) -> None:
    """Every utterance, the manifest and ``corpus.json`` of a corpus, written into ``out``."""
    workers = cfg.workers if cfg.workers > 0 else (os.cpu_count() or 1)
    results: list = [None] * len(plans)
    with tqdm(total=len(plans), desc="speech", unit="utt", disable=not progress) as bar:
        for spec, backend in backends.items():
            idx = [i for i, p in enumerate(plans) if p.voice == spec]
            done = backend.synthesize_many([plans[i].request for i in idx], workers=workers,
                                           progress=bar.update)
            for i, res in zip(idx, done):
                results[i] = res
    rows = []
    for plan, res in tqdm(list(zip(plans, results)), desc="faces", unit="utt",
                          disable=not progress):
        audio, segs, markers = build_utterance(plan, speakers[plan.speaker], res,
                                               backends[plan.voice], cfg, seed)
        rel = write_utterance(out, utt_id=plan.utt_id, audio=audio, sr=res.sample_rate,
                              markers=markers, phones=segs)
        rows.append({"utt_id": plan.utt_id, "speaker": f"s{plan.speaker:02d}",
                     "expression": plan.expression, "text": plan.text,
                     "n_frames": markers.shape[0], "fps": FPS, "sample_rate": res.sample_rate,
                     **rel, **({"voice": plan.voice} if cfg.voices else {})})
    write_manifest(out, rows)
    # Generator settings; `workers` is left out: it changes how fast, never what is made; and
    # `voices` / `voice_weights` when empty, so the single-voice corpus is described as before.
    skip = {"workers"} | (set() if cfg.voices else {"voices", "voice_weights"}) \
        | ({"articulation"} if articulation_file(cfg) is None else set())
    info = {
        "generator": "talkingface.data_synth",
        "seed": seed,
        "layout_version": LAYOUT_VERSION,
        "backend": "; ".join(dict.fromkeys(b.version() for b in backends.values())),
        "settings": {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(cfg).items()
                     if k not in skip},
        "sentences": list(dict.fromkeys(p.text for p in plans)),
        "speakers": [{"id": f"s{s.index:02d}",
                      **({} if cfg.voices else {"voice": s.voice}), "rate_wpm": s.rate_wpm,
                      "pitch": s.pitch, "neutral": np.round(s.neutral, 4).tolist()}
                     for s in speakers],
        "n_utterances": len(rows),
        "n_frames": int(sum(r["n_frames"] for r in rows)),
        "versions": package_versions(),
    }
    model_file = articulation_file(cfg)
    if model_file is not None:  # the fitted model the faces were drawn with, by content
        info["articulation"] = {"file": str(model_file), "sha256": file_sha256(model_file),
                                "source": articulation_model(cfg).record.get("source", "")}
    if cfg.voices:
        info["voices"] = [{"voice": spec, "source_speaker": voice_speaker(spec),
                           "native_sample_rate": voice_sample_rate(spec),
                           "backend": backends[spec].version(),
                           "n_utterances": sum(p.voice == spec for p in plans)}
                          for spec in backends]
    (out / "corpus.json").write_text(json.dumps(info, indent=1))
