"""Measure the landmark rigidity and derive the 79-marker ↔ MediaPipe-landmark correspondence.

    python tools/marker_correspondence.py LANDMARK_DIR [--every 3] [--check]

``LANDMARK_DIR`` holds the worker's ``.npz`` files (``face_model/landmark_worker.py``; e.g. the
``landmarks/`` folder ``talkingface corpus from-video --keep-landmarks`` leaves). Prints:

1. **Rigidity**: every frame (every ``--every``-th) is aligned by a least-squares similarity to
   the mean shape on the 150 most rigid landmarks, the mean and the set are re-estimated, five
   times; a landmark's rigidity is the RMS of its residual (pixels). The alignment markers
   (glasses, 76–78) are the most rigid mirror pair at the sides of the upper face (each more
   than a quarter of the face's width from the midline, above the nose tip; the pair's larger
   residual is minimised) and the most rigid landmark on the midline above the nose tip.
2. **The correspondence of the other markers** (:data:`face_model.landmarks.MARKER_LANDMARKS`):
   lips by their contours (fixed lists); forehead and cheek markers by placing the canonical
   layout on the mean face with the similarity that takes the layout's eye-line centre
   (320, 206) and mouth centre (320, 310) to the mean face's (eye corners 33 133 362 263; mouth
   corners 61 291), then the barycentric weights of the Delaunay triangle of non-lip, non-eye
   landmarks that holds the marker (outside the hull: the nearest point of the hull's edge).

``--check`` exits 1 when the table derived differs from the one in ``face_model/landmarks.py``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import Delaunay

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from face_model import landmarks as lm  # noqa: E402
from face_model.layout import GLASSES, REGIONS, default_layout  # noqa: E402

EYE_LANDMARKS = (33, 7, 163, 144, 145, 153, 154, 155, 133, 173, 157, 158, 159, 160, 161, 246,
                 263, 249, 390, 373, 374, 380, 381, 382, 362, 398, 384, 385, 386, 387, 388, 466,
                 *range(468, 478))
MIDLINE = (168, 1, 0, 17, 152, 10)


def _similarity(src, dst):
    """Least-squares similarity taking src (n, 2) onto dst (n, 2): (A, t)."""
    ms, md = src.mean(0), dst.mean(0)
    s, d = src - ms, dst - md
    a, b = (s * d).sum(), (s[:, 0] * d[:, 1] - s[:, 1] * d[:, 0]).sum()
    A = np.array([[a, -b], [b, a]]) / (s ** 2).sum()
    return A, md - A @ ms


def rigidity(frames: np.ndarray, n_rigid: int = 150, rounds: int = 5):
    """``(mean_shape (478, 2), rms_residual (478,))`` of landmark frames (n, 478, 2)."""
    mean, use = frames[0], np.arange(frames.shape[1])
    for _ in range(rounds):
        aligned = np.empty_like(frames)
        for i, x in enumerate(frames):
            A, t = _similarity(x[use], mean[use])
            aligned[i] = x @ A.T + t
        mean = aligned.mean(0)
        res = np.sqrt(((aligned - mean) ** 2).sum(-1).mean(0))
        use = np.argsort(res)[:n_rigid]
    return mean, res


def alignment_landmarks(mean, res) -> tuple[int, int, int]:
    cx = mean[list(MIDLINE), 0].mean()
    width = mean[454, 0] - mean[234, 0]
    upper = mean[:, 1] < mean[1, 1]
    pairs = []
    for i in np.where((mean[:, 0] < cx - 0.25 * width) & upper)[0]:
        ref = np.array([2 * cx - mean[i, 0], mean[i, 1]])
        j = int(np.argmin(((mean - ref) ** 2).sum(1)))
        if np.hypot(*(mean[j] - ref)) < 0.02 * width:
            pairs.append((float(max(res[i], res[j])), int(i), j))
    _, left, right = min(pairs)
    mid = np.where((np.abs(mean[:, 0] - cx) < 0.04 * width) & upper)[0]
    centre = int(mid[np.argmin(res[mid])])
    return left, centre, right


def _edge_point(p, pts, hull_edges):
    best = None
    for a, b in hull_edges:
        d = pts[b] - pts[a]
        f = float(np.clip(np.dot(p - pts[a], d) / np.dot(d, d), 0, 1))
        dist = np.hypot(*(pts[a] + f * d - p))
        if best is None or dist < best[0]:
            best = (dist, a, b, f)
    _, a, b, f = best
    return (a, b), (1 - f, f)


def correspondence(mean: np.ndarray, glasses: tuple[int, int, int]) -> dict:
    """Marker index → (landmark indices, weights)."""
    layout = default_layout().neutral.astype(np.float64)
    table = {}
    for contour, markers, ends in lm.LIP_SPANS:
        for k in markers:
            x0, x1 = layout[ends[0], 0], layout[ends[1], 0]
            pos = (layout[k, 0] - x0) / (x1 - x0) * (len(contour) - 1)
            i = min(int(np.floor(pos)), len(contour) - 2)
            f = round(float(pos - i), 4)
            table[k] = ((contour[i], contour[i + 1]), (round(1 - f, 4), f))
    for k, g in zip(GLASSES, glasses):
        table[k] = ((g,), (1.0,))
    src = np.array([[320.0, 206.0], [320.0, 310.0]])
    dst = np.array([mean[[33, 133, 362, 263]].mean(0), mean[[61, 291]].mean(0)])
    A, t = _similarity(src, dst)
    placed = layout @ A.T + t
    excluded = set(EYE_LANDMARKS) | {i for c, _, _ in lm.LIP_SPANS for i in c}
    keep = np.array([i for i in range(len(mean)) if i not in excluded])
    tri = Delaunay(mean[keep])
    hull_edges = [(int(keep[a]), int(keep[b])) for a, b in tri.convex_hull]
    for k in [*REGIONS["forehead"], *REGIONS["cheeks"]]:
        p = placed[k]
        s = int(tri.find_simplex(p))
        if s >= 0:
            T = tri.transform[s]
            w = T[:2] @ (p - T[2])
            w = np.append(w, 1 - w.sum())
            idx = tuple(int(keep[v]) for v in tri.simplices[s])
        else:
            idx, w = _edge_point(p, mean, hull_edges)
        w = np.round(np.asarray(w, float), 4)
        table[k] = (tuple(idx), tuple(float(x) for x in w))
    return dict(sorted(table.items()))


def load_frames(folder: Path, every: int) -> np.ndarray:
    frames = []
    for f in sorted(folder.glob("*.npz")):
        with np.load(f) as d:
            frames.append(d["landmarks"][d["found"]][::every, :, :2])
    if not frames:
        sys.exit(f"{folder}: no landmark files (*.npz)")
    return np.concatenate(frames).astype(np.float64)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", type=Path)
    p.add_argument("--every", type=int, default=3)
    p.add_argument("--check", action="store_true")
    args = p.parse_args(argv)
    frames = load_frames(args.folder, args.every)
    mean, res = rigidity(frames)
    glasses = alignment_landmarks(mean, res)
    order = np.argsort(res)
    print(f"{len(frames)} frames; most rigid: "
          + ", ".join(f"{i} ({res[i]:.2f} px)" for i in order[:10]))
    print("alignment landmarks (glasses L, bridge, R): "
          + ", ".join(f"{g} ({res[g]:.2f} px)" for g in glasses)
          + f"; median over all landmarks {np.median(res):.2f} px")
    table = correspondence(mean, glasses)
    if args.check:
        same = table == {k: (tuple(v[0]), tuple(v[1])) for k, v in lm.MARKER_LANDMARKS.items()}
        print("the table in face_model/landmarks.py: " + ("same" if same else "DIFFERS"))
        return 0 if same else 1
    print("MARKER_LANDMARKS = {")
    for k, (idx, w) in table.items():
        print(f"    {k}: ({idx}, {w}),")
    print("}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
