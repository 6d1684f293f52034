"""Build the perception study's web page (paper §VII-C, run online; issue 41).

:func:`build_web` turns a stimulus folder (:mod:`study.stimuli`) into one static folder that a
plain web server can serve (``talkingface study serve``, :mod:`study.web.app`)::

    index.html, experiment.js, style.css     the page (copied from study/web/static)
    vendor/                                  jsPsych and its plugins, copied from
                                             study/web/node_modules; vendor/NOTICE.md
    stimuli/<sid>.mp4                        each face video muxed with its sentence (AAC):
                                             one file, so sound and face cannot drift apart
    stimuli/<sid>-silent.mp4                 the *-normal videos without sound (visual block)
    stimuli/<sid>-last.png                   each video's last frame (the response screen)
    stimuli/audio-<a>.wav                    the audio-only tracks
    study.json                               what every participant's page shares: texts (the
                                             lab's own, from :mod:`study.runner`), keys, timing,
                                             file names, the stimuli's digest

Nothing is fetched from elsewhere when the page runs. The H.264 video is copied, not re-encoded;
ffmpeg runs with bit-exact flags and without metadata, so the same stimuli give the same bytes.
The folder is built beside its target and swapped in only when complete
(:mod:`groundwork.atomic`).
"""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

from PIL import Image
from tqdm.auto import tqdm

from groundwork.atomic import fresh_partial_folder, swap_in
from groundwork.errors import ParameterError
from groundwork.movie import VideoError, check_mp4
from study import runner
from study.design import AUDIO, RESPONSES, VISUAL_AUDIO
from study.session import PRACTICE
from study.stimuli import load_manifest, manifest_digest, read_video_frames

FORMAT = 1
TITLE = "talkingface emotion-perception study"
HERE = Path(__file__).resolve().parent
STATIC = HERE / "static"
NODE_MODULES = HERE / "node_modules"
PAGE_FILES = ("index.html", "experiment.js", "style.css")
# vendor/<name> <- node_modules/<path>; index.html loads them in this order
VENDOR = {
    "jspsych.js": "jspsych/dist/index.browser.min.js",
    "jspsych.css": "jspsych/css/jspsych.css",
    **{f"plugin-{p}.js": f"@jspsych/plugin-{p}/dist/index.browser.min.js"
       for p in ("preload", "html-button-response", "browser-check", "fullscreen",
                 "html-keyboard-response", "audio-keyboard-response",
                 "video-keyboard-response", "call-function")},
}
AUDIO_CHECK = {"stimulus_id": "audio-good", "answer": "good", "choices": list(AUDIO)}
# ffmpeg: no metadata, no encoder version strings, index first (playback starts while loading)
_EXACT = ["-map_metadata", "-1", "-fflags", "+bitexact", "-flags:v", "+bitexact",
          "-flags:a", "+bitexact", "-movflags", "+faststart"]


def _ffmpeg(args: list, out: Path) -> None:
    """Run ffmpeg into ``out``; a failure raises VideoError with ffmpeg's last words."""
    import imageio_ffmpeg  # heavy and optional: imported when used

    cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-v", "error", *args, *_EXACT, str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        raise VideoError(f"{out.name}: ffmpeg exited with status {done.returncode}: {last}")
    check_mp4(out)


def mux(video, wav, out) -> Path:
    """The silent H.264 ``video`` (copied) with ``wav`` as AAC audio, in one MP4 ``out``.

    The file lasts as long as its longer track (a sentence outlasting its animation holds the
    last frame, as the lab's runner does)."""
    out = Path(out)
    _ffmpeg(["-i", str(video), "-i", str(wav), "-map", "0:v:0", "-map", "1:a:0",
             "-c:v", "copy", "-c:a", "aac", "-b:a", "128k"], out)
    return out


def silent(video, out) -> Path:
    """``video``'s H.264 stream alone (copied), with the index first."""
    out = Path(out)
    _ffmpeg(["-i", str(video), "-map", "0:v:0", "-c:v", "copy", "-an"], out)
    return out


def _copy_vendor(src: Path, dst: Path) -> None:
    """Copy a vendor file without its ``//# sourceMappingURL=`` line: it points at unpkg.com,
    which a browser's developer tools would fetch (the maps are not shipped)."""
    lines = src.read_bytes().splitlines(keepends=True)
    dst.write_bytes(b"".join(ln for ln in lines if not ln.startswith(b"//# sourceMappingURL=")))


def _vendor_sources() -> dict[str, Path]:
    """The vendor files in node_modules, checked."""
    if not NODE_MODULES.is_dir():
        raise ParameterError(f"{NODE_MODULES} not found: the web page's jsPsych files are "
                             "installed by `bash tools/setup.sh web`")
    out = {name: NODE_MODULES / rel for name, rel in VENDOR.items()}
    absent = [str(p) for p in out.values() if not p.is_file()]
    if absent:
        raise ParameterError(f"{absent[0]} not found in {NODE_MODULES}: reinstall it with "
                             "`bash tools/setup.sh web`")
    return out


def _packages() -> list[tuple[str, str, str]]:
    """(name, version, licence) of every copied package, from its package.json."""
    seen = {}
    for rel in VENDOR.values():
        parts = Path(rel).parts
        pkg = Path(*parts[:2]) if parts[0].startswith("@") else Path(parts[0])
        meta = json.loads((NODE_MODULES / pkg / "package.json").read_text())
        seen[meta["name"]] = (meta["name"], meta["version"], meta.get("license", "unknown"))
    return list(seen.values())


def _notice() -> str:
    lines = ["# Third-party files in this folder", "",
             "Copied from npm packages (installed by `bash tools/setup.sh web` from "
             "study/web/package-lock.json), unchanged but for the last line of each script, "
             "its `//# sourceMappingURL=` comment (the maps are not shipped); the page loads "
             "them from here, nothing from elsewhere.", "",
             "| file | package | version | licence |", "|---|---|---|---|"]
    by_name = {n: (v, lic) for n, v, lic in _packages()}
    for name, rel in VENDOR.items():
        parts = Path(rel).parts
        pkg = "/".join(parts[:2]) if parts[0].startswith("@") else parts[0]
        v, lic = by_name[pkg]
        lines.append(f"| {name} | {pkg} | {v} | {lic} |")
    lines += ["", "jsPsych (https://www.jspsych.org) and its plugins are by Josh de Leeuw and "
              "the jsPsych contributors, under the MIT licence:", "",
              "Permission is hereby granted, free of charge, to any person obtaining a copy of "
              "this software and associated documentation files (the \"Software\"), to deal in "
              "the Software without restriction, including without limitation the rights to "
              "use, copy, modify, merge, publish, distribute, sublicense, and/or sell copies of "
              "the Software, and to permit persons to whom the Software is furnished to do so, "
              "subject to the following conditions:", "",
              "The above copyright notice and this permission notice shall be included in all "
              "copies or substantial portions of the Software.", "",
              "THE SOFTWARE IS PROVIDED \"AS IS\", WITHOUT WARRANTY OF ANY KIND, EXPRESS OR "
              "IMPLIED, INCLUDING BUT NOT LIMITED TO THE WARRANTIES OF MERCHANTABILITY, FITNESS "
              "FOR A PARTICULAR PURPOSE AND NONINFRINGEMENT. IN NO EVENT SHALL THE AUTHORS OR "
              "COPYRIGHT HOLDERS BE LIABLE FOR ANY CLAIM, DAMAGES OR OTHER LIABILITY, WHETHER IN "
              "AN ACTION OF CONTRACT, TORT OR OTHERWISE, ARISING FROM, OUT OF OR IN CONNECTION "
              "WITH THE SOFTWARE OR THE USE OR OTHER DEALINGS IN THE SOFTWARE.", ""]
    return "\n".join(lines)


def study_json(stimuli: dict, *, study_cfg, source: Path, digest: str) -> dict:
    """The page's settings shared by every participant (web_contract.md: study.json)."""
    entries = {}
    for sid in sorted(stimuli):
        s = stimuli[sid]
        if s.kind == "video":
            e = {"kind": "video", "bimodal": f"stimuli/{sid}.mp4"}
            if s.audio == VISUAL_AUDIO:
                e["silent"] = f"stimuli/{sid}-silent.mp4"
            e["last_frame"] = f"stimuli/{sid}-last.png"
        else:
            e = {"kind": "audio", "audio": f"stimuli/{sid}.wav"}
        entries[sid] = e
    return {
        "format": FORMAT, "title": TITLE,
        "consent": study_cfg.consent,
        "keys": dict(zip(RESPONSES, study_cfg.keys)), "labels": dict(runner.LABELS),
        "texts": {"welcome": runner.WELCOME, "question": runner.QUESTION,
                  "practice": runner.PRACTICE_TEXT, "continue": runner.CONTINUE,
                  "practice_over": runner.PRACTICE_OVER, "end": runner.END_TEXT,
                  "blocks": {f"{b}-{p}": t for (b, p), t in runner.BLOCK_TEXT.items()}},
        "fixation_s": float(study_cfg.fixation_s), "iti_s": float(study_cfg.iti_s),
        "practice": bool(study_cfg.practice),
        "practice_trial": {"stimulus_id": PRACTICE.stimulus_id},
        "stimuli": entries, "audio_check": dict(AUDIO_CHECK),
        "manifest_digest": digest, "source": str(source),
        "versions": {name: version for name, version, _ in _packages()},
    }


def _write_stimuli(stimuli: dict, folder: Path, progress: bool) -> None:
    folder.mkdir()
    for sid in sorted(s for s in stimuli if stimuli[s].kind == "audio"):
        shutil.copyfile(stimuli[sid].wav, folder / f"{sid}.wav")
    videos = sorted(s for s in stimuli if stimuli[s].kind == "video")
    for sid in tqdm(videos, desc="web stimuli", unit="video", disable=not progress):
        s = stimuli[sid]
        mux(s.video, s.wav, folder / f"{sid}.mp4")
        if s.audio == VISUAL_AUDIO:
            silent(s.video, folder / f"{sid}-silent.mp4")
        frames, _ = read_video_frames(s.video)
        Image.fromarray(frames[-1]).save(folder / f"{sid}-last.png", format="PNG")


def build_web(stimuli_dir, out_dir, *, study_cfg, overwrite: bool = False,
              progress: bool = True) -> dict:
    """Build the web study's static folder ``out_dir`` from the stimuli in ``stimuli_dir``.

    Parameters
    ----------
    stimuli_dir : path
        A stimulus folder with its ``manifest.csv`` (checksums verified).
    out_dir : path
        The folder to write; an existing one is replaced only with ``overwrite``.
    study_cfg : study.config.StudyConfig
        Keys, timing, practice and consent text.
    overwrite : bool
        Replace an existing ``out_dir`` (the new folder is swapped in when complete).
    progress : bool
        A progress bar over the videos.

    Returns
    -------
    dict
        ``{"out": str, "n_files": int, "bytes": int, "manifest_digest": str}``.

    Raises
    ------
    ParameterError
        An existing ``out_dir`` without ``overwrite``, a stimulus folder that does not load
        (:func:`study.stimuli.load_manifest`), or jsPsych not installed in study/web/node_modules.
    """
    out = Path(out_dir)
    if out.exists() and not overwrite:
        raise ParameterError(f"web folder {out} already exists; pass --overwrite to replace it")
    if out.exists() and not out.is_dir():
        raise ParameterError(f"web folder {out} is a file; give a folder")
    vendor = _vendor_sources()
    source = Path(stimuli_dir).resolve()
    stimuli = load_manifest(source, verify=True)
    digest = manifest_digest(stimuli)
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = fresh_partial_folder(out)
    try:
        for name in PAGE_FILES:
            shutil.copyfile(STATIC / name, partial / name)
        (partial / "vendor").mkdir()
        for name, src in vendor.items():
            _copy_vendor(src, partial / "vendor" / name)
        (partial / "vendor" / "NOTICE.md").write_text(_notice())
        _write_stimuli(stimuli, partial / "stimuli", progress)
        info = study_json(stimuli, study_cfg=study_cfg, source=source, digest=digest)
        (partial / "study.json").write_text(json.dumps(info, indent=1) + "\n")
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    swap_in(partial, out)
    files = sorted(p for p in out.rglob("*") if p.is_file())
    return {"out": str(out), "n_files": len(files),
            "bytes": sum(p.stat().st_size for p in files), "manifest_digest": digest}
