"""The side-by-side video of a real clip (issue 39, :mod:`talkingface.stages.side_by_side`): three
panels of one height, every frame of the clip at its rate, the clip's audio; tracked markers on
panel 1, the prediction mapped back into the same image by the inverse of the clip's own
alignment on panel 2, the model's face rendered on panel 3; the report's strip picks /p b m/
and open-vowel frames by its rule; ``evaluate-face --side-by-side`` refuses a corpus folder and
a folder that holds files, before any work and changing nothing.

The clip is GRID s1 ``bbbf8p`` (tests/data/grid/video) with its markers from the built-in corpus
(face_model/real_faces/grid-s1, tracked on the same video); the model is the gated MLP trained in
a second on 16 other sentences of that corpus.
"""
from __future__ import annotations

import dataclasses
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import talkingface.cli.faces as faces
import talkingface.stages.side_by_side as sbs
from face_model.alignment import align_markers
from face_model.corpus import Corpus, load_corpus
from face_model.layout import mouth_opening
from face_model.motion_units import fit_corpus_units
from face_model.render import FaceRenderer
from groundwork.errors import ParameterError
from groundwork.movie import check_mp4
from mapping import build_dataset, make_mapper, split_masks
from mapping.animator import FaceAnimator
from mapping.checkpoint import AudioMapping, rest_mups
from talkingface.cli.main import main
from talkingface.config import Config
from talkingface.stages.face_scoring import (RealClip, clips_from_corpus, model_neutrals,
                                             predicted_markers)
from talkingface.stages.real_speaker import BUILTIN

GRID = Path(__file__).resolve().parents[1] / "data" / "grid"
CLIP = "bbbf8p"
VIDEO = GRID / "video" / f"{CLIP}.mpg"


def _small_corpus(root: Path, n_train: int = 16) -> tuple[Path, list]:
    """A corpus folder with :data:`CLIP` and the first ``n_train`` sentences of the built-in
    corpus that are not among tests/data/grid's videos (their files copied), and those ids."""
    rows = (BUILTIN / "manifest.csv").read_text().splitlines()
    held = {p.stem for p in (GRID / "video").glob("*.mpg")}
    train = [r for r in rows[1:] if r.split(",")[0] not in held][:n_train]
    keep = [r for r in rows[1:] if r.split(",")[0] == CLIP] + train
    root.mkdir()
    (root / "manifest.csv").write_text("\n".join([rows[0], *keep]) + "\n")
    shutil.copy(BUILTIN / "corpus.json", root)
    for r in keep:
        for rel in r.split(",")[-4:]:
            (root / rel).parent.mkdir(exist_ok=True)
            shutil.copy(BUILTIN / rel, root / rel)
    return root, [r.split(",")[0] for r in train]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """``(clip, animator, neutral)``: the clip, a model trained on 16 other sentences of the
    speaker, and the speaker's neutral face (the median of the clip's aligned first frame, as
    :func:`model_neutrals` gives it for a speaker the model was not trained on)."""
    root, train_ids = _small_corpus(tmp_path_factory.mktemp("grid") / "corpus")
    corpus = load_corpus(root)
    train = Corpus(corpus.root, corpus.info,
                   [u for u in corpus.utterances if u.utt_id in train_ids])
    cfg = Config()
    units, _ = fit_corpus_units(train)
    data = build_dataset(train, units)
    mapper = make_mapper("gated_mlp", cfg.mapping, n_utterance=units.n_utterance,
                         random_state=cfg.seed).fit(
        data, split_masks(data, "random_frames", seed=cfg.seed))
    animator = FaceAnimator(AudioMapping(mapper, sample_rate=train.utterances[0].sample_rate,
                                         n_utterance=units.n_utterance,
                                         rest_mups=rest_mups(units)), units)
    clip = clips_from_corpus(root, [CLIP])[0]
    neutrals, _ = model_neutrals(animator, [clip], {CLIP: align_markers(clip.markers)})
    return clip, animator, neutrals[clip.speaker]


@pytest.fixture(scope="module")
def movie(setup, tmp_path_factory):
    clip, animator, neutral = setup
    path = tmp_path_factory.mktemp("sbs") / f"{CLIP}.mp4"
    return sbs.write_side_by_side(path, VIDEO, clip, animator, neutral, progress=False)


def _ffmpeg(*args) -> subprocess.CompletedProcess:
    import imageio_ffmpeg

    return subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", *args],
                          capture_output=True, check=False)


def _frames(path) -> list:
    import cv2

    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        out.append(frame)
    cap.release()
    return out


# -- the video -------------------------------------------------------------------------------
def test_three_panels_every_frame_at_the_clips_rate_and_its_audio(setup, movie):
    clip, _, _ = setup
    check_mp4(movie)
    layout = sbs.layout_for(sbs.video_size(VIDEO))
    assert layout.panel_widths == (360, 360, 266) and layout.height == 288  # GRID: 360 x 288
    frames = _frames(movie)
    assert len(frames) == clip.n_frames == 89
    assert frames[0].shape == (layout.height + layout.caption, sum(layout.panel_widths), 3)
    info = _ffmpeg("-i", str(movie)).stderr.decode()
    assert re.search(r"Video: h264.*, 986x306.*, 30 fps", info), info
    assert re.search(r"Audio: aac", info), info
    pcm = _ffmpeg("-v", "error", "-i", str(movie), "-vn", "-f", "s16le", "-ac", "1", "-ar",
                  str(clip.sample_rate), "-").stdout
    samples = len(pcm) // 2
    # the clip's length to within one video frame (AAC's own framing)
    assert abs(samples - len(clip.audio)) <= clip.sample_rate / clip.fps
    assert len(clip.audio) == round(clip.n_frames / clip.fps * clip.sample_rate)


def test_panel_1_shows_the_tracked_markers_panel_2_the_prediction_panel_3_the_face(setup):
    clip, animator, neutral = setup
    pred = sbs.predict(animator, clip, neutral)
    layout, frames = sbs.side_by_side_frames(VIDEO, clip, animator, neutral, prediction=pred)
    frames = list(frames)
    w, h = layout.video_width, layout.height
    renderer = FaceRenderer(size=(layout.face_width, h))
    for k in (0, 40, 88):
        real, predicted, face = (frames[k][:h, :w], frames[k][:h, w:2 * w], frames[k][:h, 2 * w:])
        assert np.any(real != predicted)
        assert np.array_equal(face, renderer.render(pred.face[k]))
        for panel, markers, colour in ((real, clip.markers[k], sbs._REAL),
                                       (predicted, pred.image[k], sbs._PRED)):
            x, y = np.round(markers).astype(int).T
            hit = np.all(panel[y, x] == colour, axis=1)
            assert hit.mean() > 0.95, (k, hit.mean())  # a dot on every marker
    assert np.array_equal(frames[40], list(sbs.side_by_side_frames(
        VIDEO, clip, animator, neutral)[1])[40])  # deterministic


def test_the_prediction_is_the_scorers_and_lies_on_the_real_face(setup):
    clip, animator, neutral = setup
    pred = sbs.predict(animator, clip, neutral)
    assert np.array_equal(pred.aligned, predicted_markers(animator, clip, neutral))
    # panel 2's markers, mapped by the clip's own alignment (fitted on its tracked glasses),
    # are the aligned prediction
    A, t = sbs._fit(clip.markers, "similarity")
    np.testing.assert_allclose(np.einsum("nij,nmj->nmi", A, pred.image) + t[:, None],
                               pred.aligned, rtol=0, atol=1e-9)
    np.testing.assert_allclose(pred.face - np.asarray(animator.neutral)[None],
                               pred.aligned - neutral[None], atol=1e-9)


@pytest.mark.parametrize("model", ["similarity", "affine"])
def test_unaligning_the_aligned_markers_recovers_the_tracked_markers(setup, model):
    clip, _, _ = setup
    back = sbs.unalign_markers(align_markers(clip.markers, model=model), clip.markers,
                               model=model)
    np.testing.assert_allclose(back, clip.markers, rtol=0, atol=1e-9)
    with pytest.raises(ParameterError, match=r"alignment model 'rigid'; allowed: similarity"):
        sbs.unalign_markers(clip.markers, clip.markers, model="rigid")


# -- the strip -------------------------------------------------------------------------------
def _known(clip: RealClip) -> RealClip:
    """The clip with phones whose strip is known: /m/ then /b p/ (one run), and three vowels
    whose middle frames are 15, 40 and 70."""
    phones = ((0.0, 0.30, "sil"), (0.30, 0.43, "m"), (0.43, 0.60, "ah"),
              (0.60, 0.73, "b"), (0.73, 0.80, "p"), (1.25, 1.42, "aa"), (2.25, 2.42, "iy"),
              (2.42, 2.9667, "sil"))
    return dataclasses.replace(clip, phones=phones, valid=np.ones(clip.n_frames, bool))


def test_the_strip_rule_picks_the_first_closures_and_the_widest_vowels(setup):
    clip, _, _ = setup
    known = _known(clip)
    opening = mouth_opening(align_markers(clip.markers))
    middles = {"ah": 15, "aa": 40, "iy": 70}  # round(centre s * 30)
    widest = sorted(middles, key=lambda ph: -opening[middles[ph]])[:2]
    picks = sbs.strip_rule(known)
    # /m/ centre 0.365 s -> frame 11; the run /b p/ 0.60-0.80 s -> centre 0.70 s -> frame 21
    assert [(p.frame, p.reason) for p in picks] == sorted(
        [(11, "p b m"), (21, "p b m")] + [(middles[ph], f"open vowel {ph}") for ph in widest])
    # a vowel whose middle frame has no detected face is never chosen
    valid = np.ones(clip.n_frames, bool)
    valid[middles[widest[0]]] = False
    again = sbs.strip_rule(dataclasses.replace(known, valid=valid))
    assert f"open vowel {widest[0]}" not in [p.reason for p in again]
    assert sbs.strip_rule(dataclasses.replace(clip, phones=None)) == []


def test_the_strip_of_the_real_clip_shows_a_closure(setup):
    clip, animator, neutral = setup
    stills = sbs.strip_frames(VIDEO, clip, animator, neutral)
    closures = [s for s in stills if s.reason == "p b m"]
    assert len(closures) == 2 and len(stills) == 4
    for s in closures:  # its time is inside a /p b m/ phone of the clip
        t = s.frame / clip.fps
        assert any(a - 0.5 / clip.fps <= t <= b + 0.5 / clip.fps
                   for a, b, ph in clip.phones if ph in {"p", "b", "m"}), (s.frame, clip.phones)
    shapes = {s.image.shape for s in stills}
    assert len(shapes) == 1 and next(iter(shapes))[1] % 2 == 0
    half = stills[0].image.shape[1] // 2
    assert np.any(stills[0].image[:, :half] != stills[0].image[:, half:])


# -- the command line ------------------------------------------------------------------------
from tests.talkingface.test_face_outputs import _error_line, _tree  # noqa: E402


def _videos(root: Path) -> Path:
    video = root / "s1" / "video"
    video.mkdir(parents=True)
    shutil.copy(VIDEO, video)
    return video


def test_side_by_side_with_a_corpus_folder_is_one_clear_line(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["evaluate-face", "--model", "m.tfmap", str(BUILTIN), "--side-by-side",
                 "sbs"]) == 2
    assert _error_line(capsys) == (f"error: --side-by-side sbs: {BUILTIN} is a corpus folder "
                                   "(markers, no video); give the folder of videos it was made "
                                   "from")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ParameterError, match=r"^--side-by-side sbs: .* is a corpus folder"):
        faces.check_side_by_side(Path("sbs"), BUILTIN, corpus=True, overwrite=True)


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_a_folder_that_holds_files_is_refused_and_kept(tmp_path, monkeypatch, capsys,
                                                       overwrite):
    monkeypatch.chdir(tmp_path)
    video = _videos(tmp_path)
    (tmp_path / "sbs").mkdir()
    (tmp_path / "sbs" / f"{CLIP}.mp4").write_bytes(b"an earlier video")
    (tmp_path / "sbs" / "notes.txt").write_text("keep me\n")
    before = _tree(tmp_path)
    assert main(["evaluate-face", "--model", "m.tfmap", str(video), "--side-by-side", "sbs",
                 *overwrite]) == 2
    line = _error_line(capsys)
    assert line.startswith("error: --side-by-side sbs ")
    assert ("already holds files; pass --overwrite" in line if not overwrite
            else "holds files that are not videos (.mp4)" in line)
    assert _tree(tmp_path) == before
    (tmp_path / "sbs.mp4").write_bytes(b"x")
    assert main(["evaluate-face", "--model", "m.tfmap", str(video), "--side-by-side",
                 "sbs.mp4"]) == 2
    assert "--side-by-side sbs.mp4 is a file; give a folder" in _error_line(capsys)


def test_evaluate_face_writes_one_video_per_clip_and_replaces_it_only_when_asked(
        setup, tmp_path, monkeypatch, capsys):
    clip, animator, _ = setup
    monkeypatch.chdir(tmp_path)
    video = _videos(tmp_path)
    monkeypatch.setattr(faces, "load_animator",
                        lambda model, runs_dir: (animator, tmp_path / "run" / "m.tfmap"))
    monkeypatch.setattr(faces, "clips_from_videos", lambda src, **_: ([clip], [], []))
    argv = ["evaluate-face", str(video), "--out", "res", "--side-by-side", "sbs"]
    assert main(argv) == 0
    assert "side by side: sbs/ (1 videos" in capsys.readouterr().out
    first = _tree(tmp_path / "sbs")
    assert list(first) == [f"{CLIP}.mp4"]
    check_mp4(tmp_path / "sbs" / f"{CLIP}.mp4")
    assert main(["evaluate-face", str(video), "--out", "res_b", "--side-by-side", "sbs"]) == 2
    assert "--side-by-side sbs already holds files; pass --overwrite" in _error_line(capsys)
    assert main([*argv, "--overwrite"]) == 0
    assert _tree(tmp_path / "sbs") == first  # the same video, byte for byte
    capsys.readouterr()
    assert main(["evaluate-face", str(video), "--out", "res2", "--side-by-side", "res2/v"]) == 2
    assert "--side-by-side res2/v is in the results folder res2" in _error_line(capsys)


# -- the real_speaker stage's videos and the report's stills ---------------------------------
def test_another_models_face_is_rendered_as_that_model_animates_it(setup):
    clip, animator, neutral = setup
    own = sbs.predict(animator, clip, neutral)
    other = sbs.predict(animator, clip, neutral, face_animator=animator)
    assert np.array_equal(own.aligned, other.aligned) and np.array_equal(own.image, other.image)
    np.testing.assert_allclose(other.face, own.face, atol=1e-9)  # the two paths agree


def test_the_stage_writes_the_videos_of_held_out_clips_and_the_reports_stills(setup, tmp_path):
    from analysis.real_face_report import video_strip_figure
    from talkingface.stages.real_speaker import (BUILTIN_VIDEOS, SIDE_BY_SIDE_CAPTIONS,
                                                 _side_by_side, video_files)

    clip, animator, neutral = setup
    videos = video_files(BUILTIN_VIDEOS)
    assert set(videos) == {"bbbf8p", "bgbh7a"} and (BUILTIN_VIDEOS / "NOTICE.md").is_file()
    other = dataclasses.replace(clip, clip="zz-no-video")
    side = _side_by_side(tmp_path, [other, clip], videos, animator, animator, neutral)
    assert side == {"videos": [f"side_by_side_{CLIP}.mp4"], "clips": [CLIP],
                    "without_video": 1}
    check_mp4(tmp_path / side["videos"][0])
    with np.load(tmp_path / "video_strip.npz") as z:
        frames, reasons, images = list(z["frames"]), list(z["reasons"]), z["images"]
    rule = sbs.strip_rule(clip)
    assert frames == [s.frame for s in rule] and reasons == [s.reason for s in rule]
    assert images.dtype == np.uint8 and images.shape[0] == len(rule) and images.shape[3] == 3
    png = video_strip_figure(tmp_path / "video_strip.npz", tmp_path / "strip.png")
    assert png.stat().st_size > 10_000 and len(SIDE_BY_SIDE_CAPTIONS) == 3
