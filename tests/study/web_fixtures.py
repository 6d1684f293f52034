"""Session-scoped fixtures for the web study's tests: a real, tiny stimulus set and its built
web folder. Import them into a test module (``from tests.study.web_fixtures import web_build,
web_stimuli  # noqa: F401``).

``web_stimuli``: every stimulus of :func:`study.design.required_stimuli`: 12-frame silent H.264
MP4s (30 fps) of the layout's neutral face drawn by :class:`face_model.render.FaceRenderer`, its
mouth opening and closing at a rate and depth of its own (so no two videos are the same), one
tone WAV per sentence (0.5 s, 16 kHz: a little longer than the videos, as a sentence may be),
and a ``manifest.csv`` with checksums. ``web_build``: :func:`study.web.build.build_web` of it.
"""
from __future__ import annotations

import csv

import numpy as np
import pytest

from face_model.layout import LOWER_INNER, LOWER_OUTER, default_layout
from face_model.render import FaceRenderer
from groundwork.audio import write_wav
from study.config import StudyConfig
from study.design import AUDIO, EXPRESSIONS, FACES, stimulus_id
from study.stimuli import COLUMNS, MANIFEST, load_manifest, sha256, write_silent_mp4
from study.web.build import build_web

WEB_FRAMES = 12
WEB_FPS = 30
WEB_SR = 16000
WEB_AUDIO_S = 0.5
WEB_SIZE = (92, 100)  # a quarter of the renderer's default; padded to 96 x 104


def face_frames(depth: float, cycles: float, n: int = WEB_FRAMES) -> list:
    """``n`` RGB frames of the neutral face, the lower lip moving ``depth`` pixels down and
    back ``cycles`` times."""
    neutral = np.asarray(default_layout().neutral, np.float64)
    lower = list(LOWER_INNER) + list(LOWER_OUTER)
    renderer = FaceRenderer(size=WEB_SIZE, mesh=False)
    frames = []
    for k in range(n):
        m = neutral.copy()
        m[lower, 1] += depth * 0.5 * (1 - np.cos(2 * np.pi * cycles * k / n))
        frames.append(renderer.render(m))
    return frames


def tone(freq_hz: float, seconds: float = WEB_AUDIO_S, sr: int = WEB_SR) -> np.ndarray:
    t = np.arange(int(seconds * sr)) / sr
    return 0.3 * np.sin(2 * np.pi * freq_hz * t) * np.hanning(len(t))


def make_web_stimuli(out):
    """Write the tiny stimulus set into the empty folder ``out``; returns ``out``."""
    rows = []

    def row(sid, kind, face, expr, audio, video=None, wav=None):
        r = {"stimulus_id": sid, "kind": kind, "face": face, "expression": expr,
             "audio": audio, "markers": "", "sha256_markers": "", "n_frames": WEB_FRAMES,
             "fps": WEB_FPS, "duration_s": f"{WEB_FRAMES / WEB_FPS:.4f}"}
        for key, p in (("video", video), ("wav", wav)):
            r[key] = str(p.relative_to(out)) if p else ""
            r[f"sha256_{key}"] = sha256(p) if p else ""
        return r

    (out / "audio").mkdir(parents=True)
    for i, a in enumerate(AUDIO):
        wav = out / "audio" / f"{stimulus_id('none', 'none', a)}.wav"
        write_wav(wav, tone(220.0 * (i + 2)), WEB_SR)
        rows.append(row(stimulus_id("none", "none", a), "audio", "none", "none", a, wav=wav))
        for j, e in enumerate(EXPRESSIONS):
            for f, face in enumerate(FACES):
                sid = stimulus_id(face, e, a)
                frames = face_frames(depth=4.0 + 3 * j + 2 * f, cycles=1 + i)
                video = write_silent_mp4(out / "video" / f"{sid}.mp4", frames, WEB_SIZE,
                                         fps=WEB_FPS)
                rows.append(row(sid, "video", face, e, a, video=video, wav=wav))
    with open(out / MANIFEST, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    return out


@pytest.fixture(scope="session")
def web_stimuli(tmp_path_factory):
    """A tiny, complete stimulus folder (read-only for the tests: copy it to damage it)."""
    out = make_web_stimuli(tmp_path_factory.mktemp("web_stimuli"))
    load_manifest(out)  # complete and consistent
    return out


@pytest.fixture(scope="session")
def web_build(web_stimuli, tmp_path_factory):
    """The web folder (a Path) built from ``web_stimuli`` with the default study settings
    (read-only for the tests)."""
    out = tmp_path_factory.mktemp("web_build") / "web"
    build_web(web_stimuli, out, study_cfg=StudyConfig(), progress=False)
    return out
