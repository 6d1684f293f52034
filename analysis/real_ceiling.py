"""Steps of the gap between our Table II on a real speaker and the paper's (issue 39): the
measurements that need no trained mapping, each chosen on training sentences only.

* **Eq. 6 against what** (:func:`truth_r`): the paper's ground truth is the Motion Units'
  reconstruction of the tracked MUPs, each coordinate divided by its largest absolute
  displacement (:mod:`analysis.metrics`); beside it, the same R against the aligned markers
  themselves, so that a reader sees what the definition alone moves.
* **The measurement floor**: how much of the truth is the landmarks' frame-to-frame jitter
  (:func:`smoothing_floor`: R of the truth against a centred moving average of itself, the best
  any predictor of the smooth motion can reach if the rest is noise) and how much the Motion
  Units keep (:func:`reconstruction_r`: R of the aligned markers against their reconstruction).
* **Audio–video offset** (:func:`offset_scores`, :func:`best_offset`): recordings differ in how
  their audio and video are aligned. For each lag, a ridge regression from the audio features'
  context to the MUPs is fitted on half of the training sentences and scored (Eq. 6, on the
  displacements the MUPs reconstruct, normalised as the paper's: ``project``) on the other
  half, both ways; the best lag is the one with the highest mean R.
* **Learning curve** (:func:`nested_subsets`): training subsets of growing size, each holding
  the smaller ones, drawn with a seed.

Arrays: features (n_frames, n_features) per sentence, MUPs (n_frames, n_mups), displacements
(n_frames, 158) pixels, x/y interleaved per marker.
"""
from __future__ import annotations

import numpy as np

from analysis.metrics import normalization_scale, pearson_r
from groundwork.errors import ParameterError

RIDGE_ALPHA = 1.0  # the offset search's ridge penalty (on standardised features)
OFFSET_CONTEXT = 3  # frames of audio context either side in the offset search's regression


def _check_pairs(features: list, targets: list) -> None:
    if len(features) != len(targets) or len(features) < 2:
        raise ParameterError(f"need as many target sequences as feature sequences, at least 2 "
                             f"sentences; got {len(features)} and {len(targets)}")
    for i, (x, y) in enumerate(zip(features, targets)):
        if np.ndim(x) != 2 or np.ndim(y) != 2 or len(x) != len(y):
            raise ParameterError(f"sentence {i}: features {np.shape(x)} and targets "
                                 f"{np.shape(y)} must be 2-D with one number of frames")


def shifted(features: np.ndarray, targets: np.ndarray, lag: int) -> tuple:
    """The frames of one sentence paired at ``lag``: the audio of frame t with the face of frame
    t + lag (a positive lag: the face moves ``lag`` frames after the sound that drives it)."""
    n = len(features)
    if abs(lag) >= n:
        return features[:0], targets[:0]
    if lag >= 0:
        return features[:n - lag], targets[lag:]
    return features[-lag:], targets[:n + lag]


def _context(x: np.ndarray, k: int) -> np.ndarray:
    """Each frame with ``k`` frames either side (edges repeated), (n, (2k + 1) · d)."""
    padded = np.concatenate([np.repeat(x[:1], k, 0), x, np.repeat(x[-1:], k, 0)])
    return np.concatenate([padded[i:i + len(x)] for i in range(2 * k + 1)], axis=1)


def _ridge(x: np.ndarray, y: np.ndarray, alpha: float):
    """Ridge regression on standardised ``x``: a function from new x to predictions."""
    mu, sd = x.mean(0), x.std(0)
    sd = np.where(sd > 0, sd, 1.0)
    z = (x - mu) / sd
    ym = y.mean(0)
    w = np.linalg.solve(z.T @ z + alpha * np.eye(z.shape[1]), z.T @ (y - ym))
    return lambda xn: ((xn - mu) / sd) @ w + ym


def _identity(y: np.ndarray) -> np.ndarray:
    return y


def offset_scores(features: list, targets: list, lags, *, context: int = OFFSET_CONTEXT,
                  alpha: float = RIDGE_ALPHA, project=None, truths=None) -> dict:
    """``{lag: R}``: for each lag, a ridge regression from the features' context to the targets
    (:func:`shifted` at that lag) fitted on every other sentence and scored by Eq. 6 on the
    rest, then the other way round; R is the mean of the two halves. Give it training
    sentences only: the lag it picks is a setting of the pipeline.

    ``project``: ``(n, n_targets) -> (n, n_dims)``, applied to the truth and the estimate
    before Eq. 6 — for MUPs, their displacements by Eq. 2 divided by the database's largest
    absolute displacement per coordinate, the paper's R (None: R on the targets as given).
    ``truths``: per sentence what the projected estimate is scored against instead of the
    projected targets (n_frames, n_dims), e.g. the aligned markers themselves."""
    project = project or _identity
    _check_pairs(features, targets)
    if truths is not None:
        _check_pairs(features, truths)
    halves = (list(range(0, len(features), 2)), list(range(1, len(features), 2)))
    ctx = [_context(np.asarray(x, np.float64), context) for x in features]
    out = {}
    for lag in lags:
        pairs = [shifted(x, np.asarray(y, np.float64), int(lag)) for x, y in zip(ctx, targets)]
        against = None if truths is None else [
            shifted(x, np.asarray(t, np.float64), int(lag))[1] for x, t in zip(ctx, truths)]
        scores = []
        for fit, score in (halves, halves[::-1]):
            xf = np.concatenate([pairs[i][0] for i in fit])
            yf = np.concatenate([pairs[i][1] for i in fit])
            xs = np.concatenate([pairs[i][0] for i in score])
            ys = np.concatenate([pairs[i][1] for i in score])
            if len(xf) < 2 or len(xs) < 2:
                raise ParameterError(f"lag {lag}: too few frames left to fit and score "
                                     f"({len(xf)} and {len(xs)}); use smaller lags")
            truth = project(ys) if against is None else np.concatenate(
                [against[i] for i in score])
            scores.append(pearson_r(truth, project(_ridge(xf, yf, alpha)(xs))))
        out[int(lag)] = float(np.mean(scores))
    return out


def best_offset(scores: dict) -> int:
    """The lag of the highest R in ``scores`` (:func:`offset_scores`); of equal ones, the
    smallest in size, then the negative."""
    if not scores:
        raise ParameterError("no lag was scored")
    return max(scores, key=lambda lag: (scores[lag], -abs(lag), -lag))


def smoothing_floor(truths: list, window: int = 3) -> float:
    """Eq. 6 of the truth (per sentence, (n_frames, n_dims), pooled) against its centred moving
    average over ``window`` frames (odd; edges averaged over the frames there are): near 1 when
    the truth moves smoothly, lower the more of it is frame-to-frame jitter that no audio can
    predict."""
    if window < 1 or window % 2 == 0:
        raise ParameterError(f"window {window!r}: allowed: an odd whole number, 1 or more")
    if not truths:
        raise ParameterError("no sentences to measure")
    smooth = []
    for t in truths:
        t = np.asarray(t, np.float64)
        c = np.cumsum(np.concatenate([np.zeros((1, t.shape[1])), t]), axis=0)
        idx = np.arange(len(t))
        lo = np.clip(idx - window // 2, 0, len(t))
        hi = np.clip(idx + window // 2 + 1, 0, len(t))
        smooth.append((c[hi] - c[lo]) / (hi - lo)[:, None])
    return pearson_r(np.concatenate(truths), np.concatenate(smooth))


def truth_r(markers: np.ndarray, reconstruction: np.ndarray, estimate: np.ndarray) -> dict:
    """Eq. 6 of an estimate (displacements) against the paper's truth, the Motion Units'
    reconstruction, and against the aligned markers themselves; each coordinate divided by
    the largest absolute displacement of the truth it is scored against (over the frames
    given: pass a whole database's to match Table II)."""
    markers, reconstruction, estimate = (np.asarray(a, np.float64)
                                         for a in (markers, reconstruction, estimate))
    if not markers.shape == reconstruction.shape == estimate.shape:
        raise ParameterError(f"markers {markers.shape}, reconstruction {reconstruction.shape} "
                             f"and estimate {estimate.shape} must have one shape")
    out = {}
    for name, truth in (("paper", reconstruction), ("markers", markers)):
        scale = normalization_scale(truth)
        out[name] = pearson_r(truth / scale, estimate / scale)
    return out


def reconstruction_r(markers: np.ndarray, reconstruction: np.ndarray) -> float:
    """Eq. 6 of the aligned markers' displacements against their Motion Units' reconstruction
    (each coordinate divided by the markers' largest absolute displacement): what the units
    keep of the face's motion, the ceiling of any mapping scored against the markers."""
    markers = np.asarray(markers, np.float64)
    scale = normalization_scale(markers)
    return pearson_r(markers / scale, np.asarray(reconstruction, np.float64) / scale)


def nested_subsets(ids: list, sizes, seed: int) -> dict:
    """``{size: ids}``: training subsets of each size (a size over ``len(ids)`` gives all; 0
    means all), each the first ``size`` of one seeded permutation, so every subset holds the
    smaller ones; ids keep their order within a subset."""
    ids = list(ids)
    if len(set(ids)) != len(ids):
        raise ParameterError("sentence ids must be distinct")
    bad = [s for s in sizes if not isinstance(s, (int, np.integer)) or s < 0]
    if bad:
        raise ParameterError(f"subset sizes {bad}: allowed: whole numbers, 0 (all) or more")
    order = np.random.default_rng(seed).permutation(len(ids))
    out = {}
    for size in sizes:
        n = len(ids) if size == 0 else min(int(size), len(ids))
        chosen = set(order[:n].tolist())
        out[int(size)] = [u for i, u in enumerate(ids) if i in chosen]
    return out


def phone_onehot(phones: np.ndarray, n_classes: int) -> np.ndarray:
    """Per frame, the one-hot code of its phone-class index (``phones``: (n_frames,) indices in
    0..n_classes - 1): the oracle's input, the true phones instead of the audio."""
    phones = np.asarray(phones)
    if phones.ndim != 1 or (len(phones) and (phones.min() < 0 or phones.max() >= n_classes)):
        raise ParameterError(f"phone indices must be 1-D in 0..{n_classes - 1}")
    out = np.zeros((len(phones), n_classes))
    out[np.arange(len(phones)), phones] = 1.0
    return out


def region_loadings(components: np.ndarray, regions: dict) -> list[dict]:
    """Per Motion Unit (rows of ``components``, (n_units, 158), unit length), the share of its
    squared loading on each region's markers (``regions``: name -> marker indices) and on the
    x coordinates: where on the face a unit moves, and whether sideways or up and down."""
    components = np.asarray(components, np.float64)
    out = []
    for c in components:
        total = float((c ** 2).sum()) or 1.0
        row = {name: float((c[np.array([2 * m + k for m in markers for k in (0, 1)])] ** 2)
                           .sum() / total) for name, markers in regions.items()}
        row["x"] = float((c[0::2] ** 2).sum() / total)
        out.append(row)
    return out


def learning_curve(features: list, targets: list, sizes, *, seed: int,
                   context: int = OFFSET_CONTEXT, alpha: float = RIDGE_ALPHA,
                   project=None) -> dict:
    """``{n: R}``: the ridge probe of :func:`offset_scores` (lag 0) fitted on ``n`` sentences
    of one half of the sentences (every other one; :func:`nested_subsets` of that half, seeded)
    and scored by Eq. 6 on the whole other half, then the other way round (mean R). ``sizes``
    above a half's size are cut to it (0: all of it); the keys are the sizes used, so a curve
    says how much more data would buy. ``project``: as :func:`offset_scores`."""
    project = project or _identity
    _check_pairs(features, targets)
    halves = (list(range(0, len(features), 2)), list(range(1, len(features), 2)))
    ctx = [_context(np.asarray(x, np.float64), context) for x in features]
    used = sorted({min(len(h), int(s) if s else len(h)) for s in sizes for h in halves[:1]})
    out = {}
    for n in used:
        scores = []
        for fit, score in (halves, halves[::-1]):
            chosen = nested_subsets(fit, [n], seed)[n]
            xf = np.concatenate([ctx[i] for i in chosen])
            yf = np.concatenate([np.asarray(targets[i], np.float64) for i in chosen])
            xs = np.concatenate([ctx[i] for i in score])
            ys = np.concatenate([np.asarray(targets[i], np.float64) for i in score])
            scores.append(pearson_r(project(ys), project(_ridge(xf, yf, alpha)(xs))))
        out[n] = float(np.mean(scores))
    return out


def curve_projection(curve: dict, n: int) -> dict:
    """What a learning curve ``{sentences: R}`` (:func:`learning_curve`) projects for ``n``
    sentences: the rise of R per doubling of the data, the least-squares slope of R on
    log2(sentences), continued from the largest size measured to ``n``. A straight line in
    log data is the optimistic reading of a curve that flattens (it never bends down).

    Raises
    ------
    ParameterError
        Fewer than two sizes, or ``n`` not above the largest.
    """
    sizes = sorted(int(k) for k in curve)
    if len(sizes) < 2:
        raise ParameterError(f"a projection needs R at two or more sizes, got {sizes}")
    if n <= sizes[-1]:
        raise ParameterError(f"project to more sentences than measured ({sizes[-1]}), got {n}")
    x = np.log2(sizes)
    y = np.array([float(curve[k] if k in curve else curve[str(k)]) for k in sizes])
    slope = float(np.polyfit(x, y, 1)[0])
    return {"per_doubling": slope, "sentences": int(n),
            "r": float(y[-1] + slope * (np.log2(n) - x[-1]))}

