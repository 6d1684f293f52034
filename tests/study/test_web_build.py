"""The web study's built folder (study/web/build.py) and its page (study/web/static), checked
against web_contract.md: the files, the muxed videos, reproducible bytes, refusals, and whole
sessions run by jsPsych's data-only simulation under Node + jsdom (tests/study/simulate_web.cjs).
"""
from __future__ import annotations

import csv
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from groundwork.errors import ParameterError
from study import runner
from study.config import StudyConfig
from study.design import RESPONSES, required_stimuli, session_trials
from study.stimuli import MANIFEST, load_manifest, manifest_digest, read_video_frames
from study.web import build as web
from tests.study.web_fixtures import WEB_FRAMES, web_build, web_stimuli  # noqa: F401

SIMULATE = Path(__file__).with_name("simulate_web.cjs")
PLUGIN_FILES = [f"vendor/{n}" for n in web.VENDOR]


def _files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


def _ffprobe(path) -> list[dict]:
    out = subprocess.run(["ffprobe", "-v", "error", "-count_frames", "-show_entries",
                          "stream=codec_type,codec_name,nb_read_frames", "-of", "json",
                          str(path)], capture_output=True, text=True, check=True)
    return json.loads(out.stdout)["streams"]


# --- the folder --------------------------------------------------------------------------------
def test_the_folder_holds_exactly_the_contract_files(web_build, web_stimuli):  # noqa: F811
    study = json.loads((web_build / "study.json").read_text())
    videos = [s for s in required_stimuli() if not s.startswith("audio-")]
    expected = {"index.html", "experiment.js", "style.css", "study.json", "vendor/NOTICE.md",
                *PLUGIN_FILES,
                *(f"stimuli/{s}.mp4" for s in videos), *(f"stimuli/{s}-last.png" for s in videos),
                *(f"stimuli/{s}-silent.mp4" for s in videos if s.endswith("-normal")),
                *(f"stimuli/{s}.wav" for s in required_stimuli() if s.startswith("audio-"))}
    assert set(_files(web_build)) == expected
    assert len(videos) == 18 and sum(s.endswith("-normal") for s in videos) == 6
    for sid, entry in study["stimuli"].items():  # every path study.json names is there
        for key in ("bimodal", "silent", "last_frame", "audio"):
            if key in entry:
                assert (web_build / entry[key]).is_file(), (sid, key)
    assert set(study) >= {"format", "title", "consent", "keys", "labels", "texts", "fixation_s",
                          "iti_s", "practice", "practice_trial", "stimuli", "audio_check",
                          "manifest_digest", "source"}
    cfg = StudyConfig()
    assert study["keys"] == dict(zip(RESPONSES, cfg.keys))
    assert study["labels"] == runner.LABELS
    assert study["texts"]["welcome"] == runner.WELCOME
    assert study["texts"]["question"] == runner.QUESTION
    assert study["texts"]["blocks"]["bimodal-2"] == runner.BLOCK_TEXT[("bimodal", 2)]
    assert study["manifest_digest"] == manifest_digest(load_manifest(web_stimuli))
    assert study["source"] == str(Path(web_stimuli).resolve())
    assert (study["fixation_s"], study["iti_s"]) == (cfg.fixation_s, cfg.iti_s)
    assert study["consent"] == cfg.consent
    assert study["audio_check"]["answer"] in study["audio_check"]["choices"]
    notice = (web_build / "vendor" / "NOTICE.md").read_text()
    assert "| jspsych.js | jspsych | 8.3.0 | MIT |" in notice


def test_nothing_is_fetched_from_elsewhere(web_build):  # noqa: F811
    url = re.compile(r"https?://", re.I)
    comments = re.compile(r"/\*.*?\*/|<!--.*?-->|^\s*//[^\n]*", re.S | re.M)
    for name in ("index.html", "experiment.js", "style.css"):
        text = comments.sub("", (web_build / name).read_text())
        assert not url.findall(text), name
    html = (web_build / "index.html").read_text()
    refs = [r for r in re.findall(r'(?:src|href)="([^"]+)"', html) if r != "data:,"]
    assert set(refs) == {"experiment.js", "style.css", *PLUGIN_FILES} - {"vendor/NOTICE.md"}
    for name in PLUGIN_FILES:  # no source map fetched from unpkg by the developer tools
        assert b"sourceMappingURL" not in (web_build / name).read_bytes(), name


def test_muxed_videos_hold_the_face_and_its_sentence(web_build, web_stimuli):  # noqa: F811
    stimuli = load_manifest(web_stimuli)
    for sid, s in stimuli.items():
        if s.kind != "video":
            continue
        streams = _ffprobe(web_build / "stimuli" / f"{sid}.mp4")
        assert [(x["codec_type"], x["codec_name"]) for x in streams] == \
            [("video", "h264"), ("audio", "aac")], sid
        assert int(streams[0]["nb_read_frames"]) == s.n_frames == WEB_FRAMES
        frames, _ = read_video_frames(s.video)
        png = np.asarray(Image.open(web_build / "stimuli" / f"{sid}-last.png").convert("RGB"))
        assert np.array_equal(png, frames[-1]), sid
        if sid.endswith("-normal"):
            silent = _ffprobe(web_build / "stimuli" / f"{sid}-silent.mp4")
            assert [(x["codec_type"], x["codec_name"], int(x["nb_read_frames"]))
                    for x in silent] == [("video", "h264", WEB_FRAMES)]
        else:
            assert not (web_build / "stimuli" / f"{sid}-silent.mp4").exists()


def test_the_same_stimuli_build_the_same_bytes(web_build, web_stimuli, tmp_path):  # noqa: F811
    again = tmp_path / "again"
    summary = web.build_web(web_stimuli, again, study_cfg=StudyConfig(), progress=False)
    assert _files(again) == _files(web_build)
    for name in _files(web_build):
        assert (again / name).read_bytes() == (web_build / name).read_bytes(), name
    assert summary["n_files"] == len(_files(web_build))
    assert summary["bytes"] == sum((again / n).stat().st_size for n in _files(again))
    assert summary["manifest_digest"] == manifest_digest(load_manifest(web_stimuli))


# --- refusals ----------------------------------------------------------------------------------
def test_an_existing_folder_is_replaced_only_with_overwrite(web_stimuli, tmp_path):  # noqa: F811
    out = tmp_path / "web"
    out.mkdir()
    (out / "stale.txt").write_text("from before")
    with pytest.raises(ParameterError, match=re.escape(
            f"web folder {out} already exists; pass --overwrite to replace it")):
        web.build_web(web_stimuli, out, study_cfg=StudyConfig(), progress=False)
    assert _files(out) == ["stale.txt"]
    web.build_web(web_stimuli, out, study_cfg=StudyConfig(), overwrite=True, progress=False)
    assert "stale.txt" not in _files(out) and (out / "study.json").is_file()
    assert [p.name for p in tmp_path.iterdir()] == ["web"]  # no partial folder left


def test_a_damaged_stimulus_is_refused(web_stimuli, tmp_path):  # noqa: F811
    stim = tmp_path / "stimuli"
    shutil.copytree(web_stimuli, stim)
    with open(stim / MANIFEST, newline="") as f:
        rows = list(csv.DictReader(f))
    line, row = next((i, r) for i, r in enumerate(rows, start=2) if r["kind"] == "video")
    with open(stim / row["video"], "ab") as f:
        f.write(b"\0")
    out = tmp_path / "web"
    with pytest.raises(ParameterError, match=re.escape(
            f"{stim / MANIFEST}, line {line}: {stim / row['video']} does not match its checksum "
            "in the manifest (the file changed; update sha256_video or restore the file)")):
        web.build_web(stim, out, study_cfg=StudyConfig(), progress=False)
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["stimuli"]


def test_missing_node_modules_names_the_setup(web_stimuli, tmp_path, monkeypatch):  # noqa: F811
    absent = tmp_path / "node_modules"
    monkeypatch.setattr(web, "NODE_MODULES", absent)
    with pytest.raises(ParameterError, match=re.escape(
            f"{absent} not found: the web page's jsPsych files are installed by "
            "`bash tools/setup.sh web`")):
        web.build_web(web_stimuli, tmp_path / "web", study_cfg=StudyConfig(), progress=False)
    assert not (tmp_path / "web").exists()


# --- whole sessions, simulated -------------------------------------------------------------------
def make_plan(pid: str, sequence: str, *, start: int = 0, practice: bool = True) -> dict:
    """A POST api/session reply (web_contract.md) for the design's trials from ``start``; a
    part's instruction opens its first trial in the plan."""
    trials, seen = [], set()
    for t in session_trials(pid, sequence, 7)[start:]:
        part = f"{t.block}-{t.period}"
        trials.append({**t.as_dict(), "opens_part": None if part in seen else part})
        seen.add(part)
    return {"participant_id": pid, "token": f"token-{pid}", "sequence": sequence, "session": 1,
            "start": start, "practice": practice, "complete": False, "trials": trials,
            "answers": None, "completion": None}


def make_answers(pid: str, sequence: str) -> dict:
    keys = StudyConfig().keys
    rng = np.random.default_rng([ord(c) for c in pid + sequence])
    return {str(t.trial_index): {"key": keys[int(rng.integers(4))],
                            "rt_s": round(float(rng.uniform(0.3, 2.0)), 3)}
            for t in session_trials(pid, sequence, 7)}


def simulate(folder: Path, tmp_path: Path, **job) -> dict:
    path = tmp_path / "job.json"
    path.write_text(json.dumps(job))
    done = subprocess.run(["node", str(SIMULATE), str(folder), str(path)], capture_output=True,
                          text=True)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


@pytest.mark.parametrize("pid, sequence, start, practice", [
    ("P01", "SR", 0, True), ("P02", "RS", 0, True), ("P03", "SR", 0, False),
    ("P04", "RS", 10, False)])
def test_a_simulated_session_posts_each_judgment_in_order(web_build, tmp_path, pid,  # noqa: F811
                                                          sequence, start, practice):
    plan, answers = make_plan(pid, sequence, start=start, practice=practice), \
        make_answers(pid, sequence)
    out = simulate(web_build, tmp_path, plan=plan, answers=answers)
    posted = out["posted"]
    assert [(b["trial_index"], b["stimulus_id"]) for b in posted] == \
        [(t["trial_index"], t["stimulus_id"]) for t in plan["trials"]]
    assert posted[0]["trial_index"] == start
    for b in posted:
        assert (b["participant_id"], b["token"]) == (pid, f"token-{pid}")
        assert b["response_key"] == answers[str(b["trial_index"])]["key"]
        assert b["rt_ms"] == round(1000 * answers[str(b["trial_index"])]["rt_s"])
        br = b["browser"]
        assert br["stimulus_onset_ms"] <= br["stimulus_end_ms"] <= br["response_onset_ms"] \
            <= br["response_ms"]
        assert br["browser"].startswith("chrome ") and br["refresh_hz"] == 60
        assert br["fullscreen"] is False  # jsdom never enters full screen
    tf = [d.get("tf") for d in out["data"]]
    # consent, checks and practice ran, and only the trials posted
    assert tf[:3] == ["preload", "consent", "browser"] and tf.count("key-check") == 4
    assert tf.count("audio-check") == 1 and tf.count("post") == len(plan["trials"])
    assert ("practice-response" in tf) == practice
    assert tf.count("part") == sum(t["opens_part"] is not None for t in plan["trials"])
    end = [d for d in out["data"] if d.get("tf") == "end"][0]
    assert "C0DE" in end["stimulus"]  # the 27th reply's completion code
    assert out["redirects"] == ["https://example.org/done?cc=C0DE"]


def test_declining_consent_ends_without_a_post(web_build, tmp_path):  # noqa: F811
    out = simulate(web_build, tmp_path, plan=make_plan("P05", "SR"),
                   answers=make_answers("P05", "SR"), decline=True)
    assert out["posted"] == [] and out["redirects"] == []
    assert [d.get("tf") for d in out["data"]] == ["preload", "consent", "declined"]
    assert "You chose not to take part." in out["display"]


def test_a_refused_post_stops_the_session_with_its_line(web_build, tmp_path):  # noqa: F811
    plan = make_plan("P06", "RS")
    out = simulate(web_build, tmp_path, plan=plan, answers=make_answers("P06", "RS"), fail_at=3)
    assert [b["trial_index"] for b in out["posted"]] == [0, 1, 2, 3]
    assert "trial_index 3 refused (a test)" in out["display"]
    assert out["redirects"] == []
