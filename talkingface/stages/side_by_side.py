"""A real clip beside the model's lips (issue 39): one MP4 per clip, three panels of one height,
the clip's audio muxed, and a few still frames for the report.

1. **real + tracked**: the video frame, with the clip's tracked markers (its 79 markers, image
   pixels) drawn on it; grey markers on a frame whose face was not detected (interpolated).
2. **predicted from audio**: the same frame, grey and faded, with the markers the model predicts
   from the clip's audio drawn in the same image coordinates: the speaker's neutral face plus the
   model's deformation (Eq. 2), as :func:`talkingface.stages.face_scoring.predicted_markers`
   computes it in the aligned frame, mapped back into the image by the inverse of the clip's own
   per-frame alignment (:func:`unalign_markers`: the map :func:`face_model.alignment.
   align_markers` fits on the tracked glasses markers of that frame, inverted).
3. **animated face**: the model's own face, as ``talkingface animate`` draws it: the model's
   neutral face (``animator.neutral``) plus the same deformation, rendered by
   :class:`face_model.render.FaceRenderer` at the panels' height.

Output frame k is at k / ``clip.fps`` s (the markers' times); the video frame shown is the
source frame nearest that time by the decoder's presentation times (OpenCV's, as the landmark
worker reads them; ties go to the earlier frame). Captions sit in a band under the panels, so the
frame is the panels' summed width and their height plus the band (:class:`Layout`).

The report's strip (:func:`strip_rule`) shows real | predicted at: the middle frame of the first
two /p b m/ segments (runs of adjacent /p b m/, as :func:`analysis.face_eval.closure_segments`
merges them), then the middle frame of the two vowel segments (:data:`analysis.speech_scores.
VOWELS`) whose real inner-lip opening (:func:`face_model.layout.mouth_opening` of the aligned
tracked markers) is widest at that middle frame, among frames with a detected face. The choice
reads the real face and the phones only, never the prediction.

Everything is deterministic: the same clip, video and model give the same frames.

``clip`` is a :class:`talkingface.stages.face_scoring.RealClip`.
"""
from __future__ import annotations

import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.face_eval import closure_segments, phone_segments
from analysis.speech_scores import VOWELS
from face_model.alignment import affine_params, align_markers, similarity_params
from face_model.layout import (GLASSES, LEFT_INNER_CORNER, LEFT_OUTER_CORNER, LOWER_INNER,
                               LOWER_OUTER, RIGHT_INNER_CORNER, RIGHT_OUTER_CORNER, UPPER_INNER,
                               UPPER_OUTER, default_layout, mouth_opening)
from face_model.render import FaceRenderer
from groundwork.audio import write_wav
from groundwork.errors import ParameterError
from groundwork.movie import write_mp4
from talkingface.stages.face_scoring import predicted_markers

CAPTIONS = ("real + tracked", "predicted from audio", "animated face")
CAPTION_BAND = 18  # pixels under the panels
MAX_HEIGHT = 480  # panels of a taller video are scaled down to this height, pixels
STRIP_MARGIN = 0.15  # the strip's box around the markers, a fraction of their extent
FACE_ASPECT = 368 / 400  # FaceRenderer's default size: width / height of the head's crop
_REAL, _PRED, _MISSING = (40, 220, 90), (255, 60, 200), (150, 150, 150)  # RGB
_BACKGROUND, _TEXT = (24, 24, 28), (235, 235, 235)
_SHIFT = 4  # sub-pixel bits for cv2 drawing


@dataclass(frozen=True)
class Layout:
    """The frame's geometry, pixels: panels 1 and 2 are ``video_width`` wide, panel 3
    ``face_width``; all three ``height`` high, over a caption band ``caption`` high. ``scale``:
    panel pixels per video pixel."""

    video_width: int
    face_width: int
    height: int
    caption: int
    scale: float

    @property
    def panel_widths(self) -> tuple[int, int, int]:
        return self.video_width, self.video_width, self.face_width

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` of a whole frame."""
        return sum(self.panel_widths), self.height + self.caption


def layout_for(video_size, *, max_height: int = MAX_HEIGHT) -> Layout:
    """The :class:`Layout` for a video of ``video_size`` ``(width, height)`` pixels: its own
    height (at most ``max_height``), every side even (H.264 in yuv420p needs it)."""
    w, h = int(video_size[0]), int(video_size[1])
    if w < 16 or h < 16:
        raise ParameterError(f"video size {w}x{h}; allowed: at least 16x16 pixels")
    scale = min(1.0, max_height / h)
    even = lambda n: int(n) + int(n) % 2  # noqa: E731
    height = even(round(h * scale))
    return Layout(even(round(w * scale)), even(round(height * FACE_ASPECT)), height,
                  CAPTION_BAND, scale)


# -- markers --------------------------------------------------------------------------------
def _fit(markers: np.ndarray, model: str) -> tuple[np.ndarray, np.ndarray]:
    """The per-frame maps ``align_markers`` fits on ``markers``' glasses: ``aligned = A m + t``."""
    src = np.asarray(markers, np.float64)[:, list(GLASSES)]
    dst = np.broadcast_to(default_layout().neutral[list(GLASSES)], src.shape)
    if model == "similarity":
        return similarity_params(src, dst)
    if model == "affine":
        return affine_params(src, dst)
    raise ParameterError(f"alignment model {model!r}; allowed: similarity, affine")


def unalign_markers(aligned: np.ndarray, markers: np.ndarray, *,
                    model: str = "similarity") -> np.ndarray:
    """Map aligned points back into the image: the inverse of the per-frame maps that
    :func:`face_model.alignment.align_markers` fits on the glasses of ``markers``.

    Parameters
    ----------
    aligned : ndarray, shape (n_frames, 79, 2)
        Points in the aligned frame, pixels (e.g. a prediction on the speaker's neutral face).
    markers : ndarray, shape (n_frames, 79, 2)
        The clip's tracked markers, image pixels: they define each frame's map.
    model : {"similarity", "affine"}
        The alignment (the model's: ``units.metadata_["alignment"]``).

    Returns
    -------
    ndarray, shape (n_frames, 79, 2)
        Image pixels, float64; ``unalign_markers(align_markers(m), m)`` is ``m`` (to rounding).
    """
    A, t = _fit(markers, model)
    pts = np.asarray(aligned, np.float64) - t[:, None, :]
    return np.einsum("nij,nmj->nmi", np.linalg.inv(A), pts)


def alignment_of(animator) -> str:
    """The alignment the animator's Motion Units were fitted in (default similarity)."""
    return animator.units.metadata_.get("alignment", "similarity")


@dataclass(frozen=True)
class Prediction:
    """A model's lips for one clip, each (n_frames, 79, 2) pixels: ``aligned`` (the speaker's
    neutral face plus the deformation), ``image`` (mapped into the video's pixels) and ``face``
    (the model's own neutral face plus the deformation, for the renderer)."""

    aligned: np.ndarray
    image: np.ndarray
    face: np.ndarray


def predict(animator, clip, neutral: np.ndarray, *, input_rate: int | None = None,
            face_animator=None) -> Prediction:
    """The model's markers for ``clip`` (a :class:`~talkingface.stages.face_scoring.RealClip`)
    on ``neutral`` (79, 2), exactly the clip's frames
    (:func:`talkingface.stages.face_scoring.predicted_markers`), and their image and
    rendered-face versions.
    ``input_rate``: the rate (Hz) the model hears the audio at (None: the clip's own).
    ``face_animator``: another model whose own face (its neutral face plus its deformation
    of the same audio) is the rendered one (None: ``animator``'s)."""
    neutral = np.asarray(neutral, np.float64)
    aligned = predicted_markers(animator, clip, neutral, input_rate)
    image = unalign_markers(aligned, clip.markers, model=alignment_of(animator))
    if face_animator is None:
        face = np.asarray(animator.neutral, np.float64)[None] + (aligned - neutral[None])
    else:
        face = predicted_markers(face_animator, clip,
                                 np.asarray(face_animator.neutral, np.float64), input_rate)
    return Prediction(aligned, image, face)


# -- drawing --------------------------------------------------------------------------------
_OUTER = [LEFT_OUTER_CORNER, *UPPER_OUTER, RIGHT_OUTER_CORNER, *LOWER_OUTER]
_INNER = [LEFT_INNER_CORNER, *UPPER_INNER, RIGHT_INNER_CORNER, *LOWER_INNER]


def _pts(p: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(p) * (1 << _SHIFT)).astype(np.int32).reshape(-1, 1, 2)


def draw_markers(img: np.ndarray, markers: np.ndarray, colour, *, scale: float = 1.0) -> None:
    """Draw 79 markers (image pixels × ``scale``) on ``img`` (h, w, 3) in place: a dot each,
    and the outer and inner lip contours closed."""
    import cv2

    m = np.asarray(markers, np.float64) * scale
    aa = cv2.LINE_AA
    for ring in (_OUTER, _INNER):
        cv2.polylines(img, [_pts(m[ring])], True, colour, 1, aa, _SHIFT)
    r = max(1, round(1.5 * (1 << _SHIFT)))
    for p in _pts(m):
        cv2.circle(img, tuple(int(v) for v in p[0]), r, colour, -1, aa, _SHIFT)


def _faded(frame: np.ndarray) -> np.ndarray:
    grey = frame.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    return np.repeat((96 + 0.45 * grey)[..., None], 3, axis=2).astype(np.uint8)


def _caption(width: int, height: int, text: str) -> np.ndarray:
    import cv2

    band = np.empty((height, width, 3), np.uint8)
    band[:] = _BACKGROUND
    cv2.putText(band, text, (6, height - 5), cv2.FONT_HERSHEY_SIMPLEX, 0.4, _TEXT, 1,
                cv2.LINE_AA)
    return band


def _panel(frame: np.ndarray, layout: Layout) -> np.ndarray:
    """A video frame (h, w, 3) at the layout's panel size."""
    import cv2

    size = (layout.video_width, layout.height)
    if frame.shape[1::-1] == size:
        return frame.copy()
    return cv2.resize(frame, size, interpolation=cv2.INTER_AREA)


def real_panel(frame: np.ndarray, markers: np.ndarray, layout: Layout,
               valid: bool = True) -> np.ndarray:
    """Panel 1: the frame with the tracked markers (grey when no face was detected)."""
    img = _panel(frame, layout)
    draw_markers(img, markers, _REAL if valid else _MISSING, scale=layout.scale)
    return img


def predicted_panel(frame: np.ndarray, markers: np.ndarray, layout: Layout) -> np.ndarray:
    """Panel 2: the frame grey and faded, with the predicted markers (image pixels)."""
    img = _faded(_panel(frame, layout))
    draw_markers(img, markers, _PRED, scale=layout.scale)
    return img


# -- video ----------------------------------------------------------------------------------
def video_size(video) -> tuple[int, int]:
    """``(width, height)`` of a video's frames, pixels."""
    import cv2

    cap = cv2.VideoCapture(str(video))
    try:
        ok, frame = cap.read()
    finally:
        cap.release()
    if not ok:
        raise ParameterError(f"{video}: no video frame could be decoded")
    return frame.shape[1], frame.shape[0]


def video_frames(video, times_s) -> Iterator[np.ndarray]:
    """RGB frames (h, w, 3) uint8 of ``video`` nearest each of the increasing ``times_s`` (s),
    by the decoder's presentation times (the landmark worker's reading; ties: the earlier
    frame; after the last frame, the last frame)."""
    import cv2

    cap = cv2.VideoCapture(str(video))
    try:
        def read():
            ok, frame = cap.read()
            return (cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0, frame) if ok else None

        cur = read()
        if cur is None:
            raise ParameterError(f"{video}: no video frame could be decoded")
        nxt = read()
        for t in times_s:
            while nxt is not None and abs(nxt[0] - t) < abs(cur[0] - t):
                cur, nxt = nxt, read()
            yield cv2.cvtColor(cur[1], cv2.COLOR_BGR2RGB)
    finally:
        cap.release()


def side_by_side_frames(video, clip, animator, neutral: np.ndarray, *,
                        prediction: Prediction | None = None, input_rate: int | None = None,
                        max_height: int = MAX_HEIGHT, face_animator=None,
                        captions: tuple = CAPTIONS):
    """``(layout, frames)``: the :class:`Layout` and an iterator of the clip's
    ``clip.n_frames`` RGB frames (height, width, 3) uint8, three panels and their captions
    (module docstring).

    Parameters
    ----------
    video : path
        The clip's video (the one its markers were tracked on).
    clip : RealClip
        :class:`talkingface.stages.face_scoring.RealClip`: markers in the video's pixels.
    animator : mapping.animator.FaceAnimator
        The model.
    neutral : ndarray, shape (79, 2)
        The speaker's neutral face in the aligned frame, pixels
        (:func:`talkingface.stages.face_scoring.model_neutrals`).
    prediction : Prediction, optional
        :func:`predict`'s result, when already made.
    input_rate : int, optional
        The rate (Hz) the model hears the audio at.
    max_height : int
        The panels' greatest height, pixels.
    face_animator : FaceAnimator, optional
        The model whose face panel 3 renders (:func:`predict`; None: ``animator``).
    captions : tuple of 3 str
        The panels' captions.
    """
    pred = prediction or predict(animator, clip, neutral, input_rate=input_rate,
                                 face_animator=face_animator)
    layout = layout_for(video_size(video), max_height=max_height)
    renderer = FaceRenderer(size=(layout.face_width, layout.height))
    band = np.concatenate([_caption(w, layout.caption, text)
                           for w, text in zip(layout.panel_widths, captions)], axis=1)
    valid = np.ones(clip.n_frames, bool) if clip.valid is None else np.asarray(clip.valid)
    times = np.arange(clip.n_frames) / clip.fps

    def frames():
        for k, frame in enumerate(video_frames(video, times)):
            panels = [real_panel(frame, clip.markers[k], layout, bool(valid[k])),
                      predicted_panel(frame, pred.image[k], layout),
                      renderer.render(pred.face[k])]
            yield np.concatenate([np.concatenate(panels, axis=1), band], axis=0)

    return layout, frames()


def write_side_by_side(path, video, clip, animator, neutral: np.ndarray, *,
                       input_rate: int | None = None, progress: bool = True,
                       max_height: int = MAX_HEIGHT, prediction: Prediction | None = None,
                       face_animator=None, captions: tuple = CAPTIONS) -> Path:
    """Write the clip's three-panel MP4 (H.264, ``clip.fps``, ``clip.n_frames`` frames) with
    the clip's own audio muxed as AAC (:func:`groundwork.movie.write_mp4`: written under a
    temporary name, renamed into place only when whole). Arguments as for
    :func:`side_by_side_frames`; ``progress``: the render's bar.

    Returns
    -------
    Path
        ``path``.
    """
    layout, frames = side_by_side_frames(video, clip, animator, neutral, input_rate=input_rate,
                                         max_height=max_height, prediction=prediction,
                                         face_animator=face_animator, captions=captions)
    with tempfile.TemporaryDirectory(prefix="talkingface-sbs-") as tmp:
        wav = Path(tmp) / "audio.wav"
        write_wav(wav, np.asarray(clip.audio), clip.sample_rate)
        return write_mp4(path, frames, clip.n_frames, layout.size, fps=clip.fps,
                         audio_path=wav, progress=progress, macro_block_size=2)


# -- the report's strip ---------------------------------------------------------------------
@dataclass(frozen=True)
class StripFrame:
    """One still of the strip: the frame index (at ``frame / fps`` s), why it was chosen
    (``"p b m"`` or ``"open vowel <phone>"``) and, from :func:`strip_frames`, the image
    real | predicted (height, 2 · width, 3) uint8 (the panels, or their :func:`face_box`)."""

    frame: int
    reason: str
    image: np.ndarray | None = None


def _middle(start_s: float, end_s: float, fps: float, n: int) -> int:
    return int(min(n - 1, max(0, round((start_s + end_s) / 2 * fps))))


def strip_rule(clip, *, alignment: str = "similarity", n_closures: int = 2,
               n_open: int = 2) -> list[StripFrame]:
    """The strip's frames for ``clip`` in time order (module docstring): the middle frame
    (the frame nearest the centre) of the first ``n_closures`` /p b m/ segments, and of the
    ``n_open`` vowel segments whose real inner-lip opening is widest at that frame, among
    frames with a detected face and not already chosen (ties: the earlier segment). A clip
    without phones gives none; one with fewer segments, fewer frames."""
    if not clip.phones:
        return []
    n, fps = clip.n_frames, clip.fps
    closures, _ = closure_segments(clip.phones)  # centres of the runs of /p b m/, s
    chosen = {_middle(c, c, fps, n): "p b m" for c in closures[:n_closures]}
    opening = mouth_opening(align_markers(clip.markers, model=alignment))
    valid = np.ones(n, bool) if clip.valid is None else np.asarray(clip.valid)
    vowels = []
    for s, e, ph in phone_segments(clip.phones):
        k = _middle(s, e, fps, n)
        if ph in VOWELS and valid[k]:
            vowels.append((-float(opening[k]), s, k, ph))  # widest first, then earliest
    vowels.sort()
    picked = 0
    for _, _, k, ph in vowels:
        if picked < n_open and k not in chosen:
            chosen[k], picked = f"open vowel {ph}", picked + 1
    return [StripFrame(k, why) for k, why in sorted(chosen.items())]


def face_box(points: np.ndarray, layout: Layout, *, margin: float = STRIP_MARGIN
              ) -> tuple[int, int, int, int]:
    """``(x0, y0, x1, y1)`` panel pixels around ``points`` (..., 2) video pixels: their
    bounding box widened by ``margin`` of its size on every side, inside the panel."""
    p = np.asarray(points, np.float64).reshape(-1, 2) * layout.scale
    lo, hi = p.min(0), p.max(0)
    pad = margin * (hi - lo)
    x0, y0 = np.maximum(0, np.floor(lo - pad)).astype(int)
    x1, y1 = np.minimum([layout.video_width, layout.height], np.ceil(hi + pad)).astype(int)
    return int(x0), int(y0), int(x1), int(y1)


def strip_frames(video, clip, animator, neutral: np.ndarray, *, frames=None,
                 prediction: Prediction | None = None, input_rate: int | None = None,
                 max_height: int = MAX_HEIGHT, crop: bool = True) -> list[StripFrame]:
    """The strip's stills, real | predicted (panels 1 and 2 side by side, no captions), at
    ``frames`` (a list of :class:`StripFrame`; default :func:`strip_rule`). With ``crop``
    every still of the clip shows the same box: around all the clip's tracked and predicted
    markers (:func:`face_box`). Other arguments as for :func:`side_by_side_frames`."""
    pred = prediction or predict(animator, clip, neutral, input_rate=input_rate)
    picks = strip_rule(clip, alignment=alignment_of(animator)) if frames is None else frames
    if not picks:
        return []
    layout = layout_for(video_size(video), max_height=max_height)
    x0, y0, x1, y1 = (face_box(np.concatenate([clip.markers, pred.image]), layout) if crop
                      else (0, 0, layout.video_width, layout.height))
    valid = np.ones(clip.n_frames, bool) if clip.valid is None else np.asarray(clip.valid)
    order = sorted(range(len(picks)), key=lambda i: picks[i].frame)
    images = {}
    for i, frame in zip(order, video_frames(video, [picks[i].frame / clip.fps for i in order])):
        k = picks[i].frame
        panels = (real_panel(frame, clip.markers[k], layout, bool(valid[k])),
                  predicted_panel(frame, pred.image[k], layout))
        images[i] = np.concatenate([p[y0:y1, x0:x1] for p in panels], axis=1)
    return [StripFrame(p.frame, p.reason, images[i]) for i, p in enumerate(picks)]
