"""The perception study's stimuli (paper §VII-C) and their manifest.

``build_stimuli`` makes, for the three sentences ("It is normal.", "It is good.", "It is bad.")
× the three expressions:

* the **synthetic face**: the trained mapping's MUPs from the sentence's audio with the
  expression (``FaceAnimator``), drawn on the speaker's neutral face;
* the **"real" face**: the ground-truth markers of the same sentence spoken with that expression
  by the corpus generator (the same speaker and seed as the run's corpus), with the head motion
  taken out by the glasses markers, as the synthetic face has none;
* the **audio tracks**: each sentence read calmly. The paper's tracks carry no emotion, so the
  expressions' own prosody (pitch and rate changes) is switched off for the stimulus sentences:
  all three expressions of a sentence then share its timing, and the neutral reading's audio is
  in sync with every face of that sentence.

Both faces are rendered by the same :class:`face_model.render.FaceRenderer` into silent H.264
MP4s (30 fps, frame k at k/30 s); the marker trajectories behind each video are kept, and a
contact sheet shows the middle frame of every video.

``manifest.csv`` lists every stimulus: ``stimulus_id, kind (video|audio), face, expression,
audio, video, wav, markers, n_frames, fps, duration_s`` and a SHA-256 of each file. Paths are
relative to the stimulus folder or absolute. **To use your own recordings for the real face**,
point a ``real-*`` row's ``video`` and ``wav`` at your files (any frame size; 30 fps) and clear or
update its checksums and ``markers`` (:func:`load_manifest` fills blank checksums in and records
them with each session; a stale checksum is an error naming the file). Simulated participants
need ``markers`` for every video they judge.
"""
from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from data_synth.generate import synthesize_corpus
from face_model.alignment import align_markers, speaker_neutrals
from face_model.corpus import load_corpus, read_manifest
from face_model.render import FaceRenderer, face_grid
from groundwork.audio import write_wav
from groundwork.errors import ParameterError
from groundwork.movie import write_mp4
from study.design import (AUDIO, EXPRESSIONS, FACES, SENTENCES, check_stimulus_id,
                          required_stimuli, stimulus_id)

MANIFEST = "manifest.csv"
COLUMNS = ("stimulus_id", "kind", "face", "expression", "audio", "video", "wav", "markers",
           "n_frames", "fps", "duration_s", "sha256_video", "sha256_wav", "sha256_markers")
FPS = 30


def sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@dataclass(frozen=True)
class Stimulus:
    """One manifest row with absolute paths (``video``/``markers`` None for audio-only)."""

    stimulus_id: str
    kind: str
    face: str
    expression: str
    audio: str
    video: Path | None
    wav: Path | None
    markers: Path | None
    n_frames: int
    fps: int
    duration_s: float
    sha256: dict


def write_silent_mp4(path, frames, size, *, fps: int = FPS) -> Path:
    """RGB frames (h, w, 3) uint8 → H.264 MP4 without audio (:func:`groundwork.movie.write_mp4`
    at quality 8, frame sizes padded to a multiple of 8 pixels)."""
    return write_mp4(path, frames, len(frames) if hasattr(frames, "__len__") else None, size,
                     fps=fps, audio_path=None, progress=False, quality=8, macro_block_size=8)


def read_video_frames(path) -> tuple[np.ndarray, float]:
    """All frames of a video as uint8 (n, h, w, 3) and its frame rate."""
    import imageio_ffmpeg

    gen = imageio_ffmpeg.read_frames(str(path), pix_fmt="rgb24")
    meta = next(gen)
    w, h = meta["size"]
    frames = [np.frombuffer(b, np.uint8).reshape(h, w, 3) for b in gen]
    if not frames:
        raise ParameterError(f"{path}: the video holds no frames")
    return np.stack(frames), float(meta.get("fps", FPS))


def stimulus_synth_config(synth_cfg, sentences_file: Path):
    """The run's synthesis settings for the three stimulus sentences, read calmly."""
    return dataclasses.replace(synth_cfg, n_sentences=len(SENTENCES), speakers=1,
                               text_file=str(sentences_file), smile_pitch_delta=0,
                               smile_rate_delta=0, sad_pitch_delta=0, sad_rate_delta=0)


def build_stimuli(out_dir, *, animator, synth_cfg, seed: int, progress: bool = True) -> list[dict]:
    """Synthesise, animate and render the stimulus set into ``out_dir`` (see the module text).

    Parameters
    ----------
    out_dir : path
        A new folder (an existing one is refused).
    animator : mapping.animator.FaceAnimator
        The trained mapping and its Motion Units (its ``neutral`` is replaced by the stimulus
        speaker's own neutral face).
    synth_cfg : SynthConfig
        The run's synthesis settings (speaker and face generation).
    seed : int
        The run seed (the stimulus speaker is the run corpus's first speaker).
    """
    out = Path(out_dir)
    if out.exists() and any(out.iterdir()):
        raise ParameterError(f"{out} exists and is not empty; stimuli are never overwritten "
                             "(choose another folder)")
    out.mkdir(parents=True, exist_ok=True)
    text = out / "sentences.txt"
    text.write_text("".join(SENTENCES[a] + "\n" for a in AUDIO))
    corpus = load_corpus(synthesize_corpus(out / "source", stimulus_synth_config(synth_cfg, text),
                                           seed, progress=False))
    speaker = corpus.utterances[0].speaker
    neutral = speaker_neutrals(corpus)[speaker]
    # the same animator on the stimulus speaker's face (its class, not an import of
    # mapping.animator, which loads torch: this module stays light for the session runner)
    anim = type(animator)(animator.mapping, animator.units, neutral=neutral)
    renderer = FaceRenderer(mesh=False)
    rows, stills, titles = [], [], []
    jobs = [(a, i, e) for i, a in enumerate(AUDIO) for e in EXPRESSIONS]
    for a, i, e in tqdm(jobs, desc="stimuli", unit="sentence", disable=not progress):
        calm = corpus[f"{speaker}_neutral_{i:03d}"]
        if e == "neutral":
            wav = out / "audio" / f"{stimulus_id('none', 'none', a)}.wav"
            wav.parent.mkdir(parents=True, exist_ok=True)
            write_wav(wav, calm.audio, calm.sample_rate)
            rows.append(_row(out, stimulus_id("none", "none", a), "audio", "none", "none", a,
                             None, wav, None, calm.n_frames))
        wav = out / "audio" / f"{stimulus_id('none', 'none', a)}.wav"
        real = align_markers(np.asarray(corpus[f"{speaker}_{e}_{i:03d}"].markers,
                                        dtype=np.float64))
        _, synth = anim.animate(calm.audio, calm.sample_rate, e)
        n = min(len(real), len(synth), calm.n_frames)
        for face, markers in (("synthetic", synth[:n]), ("real", real[:n])):
            sid = stimulus_id(face, e, a)
            mk = out / "markers" / f"{sid}.npy"
            mk.parent.mkdir(parents=True, exist_ok=True)
            np.save(mk, markers.astype(np.float32), allow_pickle=False)
            video = write_silent_mp4(out / "video" / f"{sid}.mp4",
                                     (renderer.render(m) for m in markers), renderer.size)
            rows.append(_row(out, sid, "video", face, e, a, video, wav, mk, n))
            if a == "normal":
                stills.append(renderer.render(markers[n // 2]))
                titles.append(f"{face} {e}")
    with open(out / MANIFEST, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    face_grid(stills, titles, out / "contact_sheet.png", ncols=len(FACES))
    (out / "stimuli.json").write_text(json.dumps(
        {"seed": seed, "speaker": speaker, "sentences": SENTENCES,
         "model": str(animator.mapping.metadata.get("split", "")),
         "mapping_corpus_hash": animator.mapping.metadata.get("corpus_hash", ""),
         "n_stimuli": len(rows)}, indent=1))
    return rows


def _row(root: Path, sid, kind, face, expression, audio, video, wav, markers, n) -> dict:
    rel = lambda p: "" if p is None else str(Path(p).relative_to(root))  # noqa: E731
    return {"stimulus_id": sid, "kind": kind, "face": face, "expression": expression,
            "audio": audio, "video": rel(video), "wav": rel(wav), "markers": rel(markers),
            "n_frames": n, "fps": FPS, "duration_s": f"{n / FPS:.4f}",
            "sha256_video": sha256(video) if video else "",
            "sha256_wav": sha256(wav) if wav else "",
            "sha256_markers": sha256(markers) if markers else ""}


def load_manifest(stim_dir, *, verify: bool = True) -> dict[str, Stimulus]:
    """The stimulus set of a folder, checked: every id a session plays is listed once, with
    the files it needs; checksums match (blank ones are computed). Errors name the file and
    the row."""
    root = Path(stim_dir)
    path = root / MANIFEST
    rows = read_manifest(path, COLUMNS, error=ParameterError,
                         not_found="make the stimuli with `talkingface study stimuli`")
    out: dict[str, Stimulus] = {}
    for line, r in enumerate(rows, start=2):
        where = f"{path}, line {line}"
        sid = r["stimulus_id"]
        try:
            check_stimulus_id(sid)
        except ParameterError as exc:
            raise ParameterError(f"{where}: {exc}") from None
        if sid in out:
            raise ParameterError(f"{where}: stimulus {sid!r} listed twice")
        if r["kind"] not in ("video", "audio"):
            raise ParameterError(f"{where}: kind {r['kind']!r}; allowed: video, audio")
        if r["face"] not in (*FACES, "none") or r["expression"] not in (*EXPRESSIONS, "none") \
                or r["audio"] not in AUDIO:
            raise ParameterError(f"{where}: face/expression/audio {r['face']!r}/"
                                 f"{r['expression']!r}/{r['audio']!r} not in the design")
        files, sums = {}, {}
        for key in ("video", "wav", "markers"):
            p = (root / r[key]) if r[key] and not Path(r[key]).is_absolute() else (
                Path(r[key]) if r[key] else None)
            if p is not None and not p.is_file():
                raise ParameterError(f"{where}: {key} file {p} not found")
            files[key] = p
            if p is not None and verify:
                digest = sha256(p)
                want = r[f"sha256_{key}"]
                if want and want != digest:
                    raise ParameterError(f"{where}: {p} does not match its checksum in the "
                                         "manifest (the file changed; update sha256_"
                                         f"{key} or restore the file)")
                sums[key] = digest
        if r["kind"] == "video" and files["video"] is None:
            raise ParameterError(f"{where}: a video stimulus needs a video file")
        if files["wav"] is None:
            raise ParameterError(f"{where}: every stimulus needs its sentence's wav file")
        try:
            n, fps = int(r["n_frames"] or 0), int(r["fps"] or FPS)
            dur = float(r["duration_s"] or 0)
        except ValueError as exc:
            raise ParameterError(f"{where}: n_frames, fps and duration_s must be numbers") \
                from exc
        out[sid] = Stimulus(sid, r["kind"], r["face"], r["expression"], r["audio"],
                            files["video"], files["wav"], files["markers"], n, fps, dur, sums)
    absent = [s for s in required_stimuli() if s not in out]
    if absent:
        raise ParameterError(f"{path}: the design needs stimuli {absent}, which are not listed")
    return out


def manifest_digest(stimuli: dict[str, Stimulus]) -> str:
    """One SHA-256 over every stimulus file's checksum (recorded with each session)."""
    h = hashlib.sha256()
    for sid in sorted(stimuli):
        for key in sorted(stimuli[sid].sha256):
            h.update(f"{sid}:{key}:{stimuli[sid].sha256[key]}\n".encode())
    return h.hexdigest()
