"""MU-constrained tracking (paper §V, Eq. 5, Appendix A): exact recovery of known MUPs and head
motion by the linear solution, agreement with the direct nonlinear fit, the tracker beating raw
Lucas–Kanade on rendered video, and error messages."""
from __future__ import annotations

import numpy as np
import pytest

from face_model.alignment import speaker_neutrals
from face_model.layout import LEFT_OUTER_CORNER, RIGHT_OUTER_CORNER, default_layout
from face_model.marker_video import VideoDifficulty, render_marker_video, tracking_error_curve
from face_model.motion_units import MotionUnits, fit_corpus_units
from face_model.mu_fit import (
    apply_beta,
    beta_to_similarity,
    fit_linear,
    fit_nonlinear,
    min_markers,
    model_basis,
    similarity_beta,
)
from face_model.tracker import MUTracker, init_from_mouth_corners, track_points_lk
from groundwork.errors import ParameterError


@pytest.fixture(scope="module")
def model(small_corpus):
    """MUs fitted on the small corpus, the speaker's neutral, and per-utterance deformations."""
    units, defs = fit_corpus_units(small_corpus)
    return units, speaker_neutrals(small_corpus)["s00"], defs


def _close(got, want, rel=1e-6):
    """Every column within ``rel`` of that column's largest magnitude (or of 1, if smaller)."""
    tol = rel * np.maximum(np.abs(want).max(axis=0), 1.0)
    worst = (np.abs(got - want) / tol).max()
    assert worst <= 1.0, f"off by {worst:.3g} × the tolerance"


def _synthetic(rng, units, neutral, expression, defs, corpus, n=30):
    """Frames built exactly from known MUPs (the corpus's own, for realistic values) and a known
    similarity: (c (n, A_0 + A_k), β (n, 6), markers (n, 79, 2))."""
    d = np.concatenate([defs[u.utt_id] for u in corpus.by_expression(expression)])
    c = units.transform(d, expression)[rng.choice(len(d), n, replace=False)]
    base, basis = model_basis(units, expression, neutral=neutral)
    shape = base + np.einsum("nm,mkd->nkd", c[:, :len(basis)], basis)
    beta = similarity_beta(rng.uniform(-0.2, 0.2, n), rng.uniform(0.7, 1.4, n),
                           rng.uniform(-100, 100, n), rng.uniform(-100, 100, n))
    return c, beta, apply_beta(beta, shape)


# -- (a) exact recovery by the linear Appendix-A solution ---------------------------------------
@pytest.mark.parametrize("expression", ["neutral", "smile", "sad"])
def test_linear_solution_recovers_known_mups_and_motion(model, small_corpus, rng, expression):
    units, neutral, defs = model
    c, beta, z = _synthetic(rng, units, neutral, expression, defs, small_corpus)
    fit = fit_linear(z, units, expression, neutral=neutral)
    _close(fit.mups, c)
    _close(fit.beta, beta)
    np.testing.assert_allclose(fit.markers, z, rtol=0, atol=1e-6)
    if expression == "neutral":
        assert np.all(fit.mups[:, units.n_utterance:] == 0)
    np.testing.assert_allclose(beta_to_similarity(fit.beta)[:, 1],  # the head's scale
                               np.hypot(beta[:, 0], beta[:, 2]), rtol=1e-9)


def test_recovery_ignores_markers_of_zero_weight(model, small_corpus, rng):
    units, neutral, defs = model
    c, beta, z = _synthetic(rng, units, neutral, "smile", defs, small_corpus, n=5)
    w = np.ones(z.shape[:2])
    w[:, 46:76:2] = 0.0  # half the lip markers lost ...
    z = z.copy()
    z[:, 46:76:2] += 40.0  # ... and wildly wrong
    fit = fit_linear(z, units, "smile", neutral=neutral, weights=w)
    _close(fit.mups, c)
    _close(fit.beta, beta)


def test_nonlinear_solution_recovers_known_mups_and_motion(model, small_corpus, rng):
    units, neutral, defs = model
    c, beta, z = _synthetic(rng, units, neutral, "sad", defs, small_corpus, n=5)
    fit = fit_nonlinear(z, units, "sad", neutral=neutral)
    _close(fit.mups, c)
    _close(fit.beta, beta)


def test_fit_reproduces_motion_units_transform(model, small_corpus):
    """Markers that are an aligned face (β = identity) give exactly MotionUnits.transform."""
    units, neutral, defs = model
    u = small_corpus.by_expression("smile")[0]
    d = defs[u.utt_id]
    mups = units.transform(d, "smile")
    z = neutral + units.inverse_transform(mups, "smile").reshape(-1, 79, 2)
    fit = fit_linear(z, units, "smile", neutral=neutral)
    np.testing.assert_allclose(fit.mups, mups, atol=1e-8)
    np.testing.assert_allclose(fit.beta, np.tile([1.0, 0, 0, 1, 0, 0], (len(z), 1)), atol=1e-9)


# -- (b) the linear solution agrees with the direct nonlinear fit --------------------------------
@pytest.mark.parametrize("noise_px", [0.1, 0.5])
def test_linear_agrees_with_nonlinear_on_noisy_markers(model, small_corpus, rng, noise_px):
    units, neutral, defs = model
    _, _, z = _synthetic(rng, units, neutral, "smile", defs, small_corpus, n=20)
    zn = z + rng.normal(0.0, noise_px, z.shape)
    lin = fit_linear(zn, units, "smile", neutral=neutral)
    nl = fit_nonlinear(zn, units, "smile", neutral=neutral)
    cost_lin = ((lin.markers - zn) ** 2).sum((1, 2))
    cost_nl = ((nl.markers - zn) ** 2).sum((1, 2))
    assert np.all(cost_nl <= cost_lin * (1 + 1e-9))  # the direct fit is the optimum ...
    assert np.all(cost_lin <= 1.05 * cost_nl)  # ... and Eq. 12 comes within 5 % of it
    gap = np.linalg.norm(lin.markers - nl.markers, axis=-1)
    assert gap.mean() < 0.1 * noise_px
    err_lin = np.linalg.norm(lin.markers - z, axis=-1).mean()
    err_nl = np.linalg.norm(nl.markers - z, axis=-1).mean()
    assert err_lin < 1.1 * err_nl < 0.6 * noise_px  # both remove most of the noise
    np.testing.assert_allclose(beta_to_similarity(lin.beta)[:, :2],
                               beta_to_similarity(nl.beta)[:, :2], atol=0.02 * noise_px)


# -- initialisation --------------------------------------------------------------------------------
def test_mouth_corner_initialisation_is_the_similarity_through_the_corners(rng):
    neutral = default_layout().neutral
    beta = similarity_beta(0.3, 1.7, 25.0, -40.0)[None]
    moved = apply_beta(beta, neutral[None])[0]
    got = init_from_mouth_corners(neutral, moved[LEFT_OUTER_CORNER], moved[RIGHT_OUTER_CORNER])
    np.testing.assert_allclose(got, moved, atol=1e-9)


# -- (c) tracking rendered video -------------------------------------------------------------------
@pytest.fixture(scope="module")
def utterances(small_corpus):
    return [small_corpus["s00_neutral_000"], small_corpus["s00_smile_001"]]


def test_constrained_tracking_beats_raw_lucas_kanade_on_noisy_video(model, utterances):
    units, neutral, _ = model
    curve = tracking_error_curve(utterances, units, neutrals={"s00": neutral},
                                 noise_levels=(10.0, 30.0), seed=3)
    assert curve.n_frames == sum(u.n_frames for u in utterances)
    assert np.all(curve.constrained_px < curve.lk_px)
    assert curve.constrained_px[-1] < 0.5 * curve.lk_px[-1]  # by far at heavy noise
    assert np.all(curve.constrained_px < 0.5)  # pixels; the MU model alone leaves ~0.2
    assert [r["noise_sd"] for r in curve.rows()] == [10.0, 30.0]


def test_started_from_the_image_alone_the_tracker_is_as_good(model, utterances):
    """No ground truth at the start: the first-frame markers are found in the image (mouth
    corners, then the dots), and the constrained tracker still stays within half a pixel."""
    units, neutral, _ = model
    curve = tracking_error_curve(utterances, units, neutrals={"s00": neutral},
                                 noise_levels=(10.0, 30.0), seed=3, init="image")
    assert np.all(curve.constrained_px < curve.lk_px)
    assert np.all(curve.constrained_px < 0.5), curve.rows()


def test_tracker_outputs_and_recovery_after_occlusion(model, utterances):
    units, neutral, _ = model
    u = utterances[1]
    _, mapping = render_marker_video(u.markers, seed=5)
    truth = mapping.to_image(u.markers)
    cheek = truth[0, 22:46]
    right, top = cheek[:, 0].max(), cheek[:, 1].min()
    box = (right - 60, top, right + 10, top + 80)  # over the right cheek
    d = VideoDifficulty(noise_sd=8.0, occlusion=(0.8, 0.4, box))
    frames, mapping_occluded = render_marker_video(u.markers, seed=5, difficulty=d)
    assert mapping_occluded == mapping  # the placement depends on the markers only
    res = MUTracker().track(frames, units, "smile", neutral=neutral,
                            corners=(truth[0, LEFT_OUTER_CORNER], truth[0, RIGHT_OUTER_CORNER]))
    n = u.n_frames
    assert res.markers.shape == res.measured.shape == (n, 79, 2)
    assert res.mups.shape == (n, units.n_mups) and res.beta.shape == (n, 6)
    assert res.used.shape == (n, 79) and np.all(np.isfinite(res.residual_px))
    err = np.linalg.norm(res.markers - truth, axis=-1).mean(1)
    after = np.flatnonzero(d.occluded_frames(n))[-1] + 1
    assert err.max() < 1.5 and err[after:].mean() < 0.8  # no drift after the box leaves
    lk, _ = track_points_lk(frames, truth[0])
    assert np.linalg.norm(lk - truth, axis=-1)[after:].mean() > 2 * err[after:].mean()
    # The head motion and the MUPs follow those of the true markers.
    ref = fit_linear(truth, units, "smile", neutral=neutral)
    np.testing.assert_allclose(res.head_motion[:, 0], beta_to_similarity(ref.beta)[:, 0],
                               atol=0.01)  # radians
    assert np.corrcoef(res.mups[:, 0], ref.mups[:, 0])[0, 1] > 0.9


def test_paper_plain_scheme_and_nonlinear_solver_run(model, utterances):
    units, neutral, _ = model
    u = utterances[0]
    frames, mapping = render_marker_video(u.markers[:20], seed=2)
    truth = mapping.to_image(u.markers[:20])
    for tracker in (MUTracker(outlier_px=None, anchor_px=None), MUTracker(solver="nonlinear")):
        res = tracker.track(frames, units, "neutral", neutral=neutral, init_markers=truth[0])
        assert np.linalg.norm(res.markers - truth, axis=-1).mean() < 0.6
        assert np.all(res.mups[:, units.n_utterance:] == 0)


# -- (e) errors -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tiny_video(utterances):
    frames, mapping = render_marker_video(utterances[0].markers[:3], seed=1)
    return frames, mapping.to_image(utterances[0].markers[0])


@pytest.mark.parametrize("change, match", [
    (lambda f, p: {"frames": f[0]}, r"frames must have shape \(n_frames, height, width\)"),
    (lambda f, p: {"frames": f.astype(np.float32)}, "frames must be uint8 images"),
    (lambda f, p: {"frames": f[:1]}, "at least 2 frames, got 1"),
    (lambda f, p: {"expression": "angry"}, "expression 'angry' has no MUs; allowed: neutral, "),
    (lambda f, p: {"init_markers": np.where(np.arange(79)[:, None] == 3, np.nan, p)},
     "init_markers hold NaN"),
    (lambda f, p: {"init_markers": p[:10]}, r"init_markers must have shape \(79, 2\)"),
    (lambda f, p: {"init_markers": p + 500}, "fall outside the 320x320 frames"),
    (lambda f, p: {"corners": (p[46], p[55])}, "exactly one of init_markers"),
    (lambda f, p: {"init_markers": None}, "exactly one of init_markers"),
    (lambda f, p: {"neutral": np.zeros((78, 2))}, r"neutral must have shape \(79, 2\)"),
    (lambda f, p: {"neutral": None}, r"neutral \(79, 2\) is required"),
])
def test_track_rejects_bad_input(model, tiny_video, change, match):
    units, neutral, _ = model
    frames, p0 = tiny_video
    kw = {"frames": frames, "expression": "neutral", "neutral": neutral, "init_markers": p0}
    kw.update(change(frames, p0))
    with pytest.raises(ParameterError, match=match):
        MUTracker().track(kw.pop("frames"), units, kw.pop("expression"), **kw)


@pytest.mark.parametrize("params, match", [
    ({"solver": "newton"}, "solver 'newton'; allowed: linear, nonlinear"),
    ({"win_size": 2}, "win_size must be an integer >= 3, got 2"),
    ({"max_level": -1}, "max_level must be an integer >= 0"),
    ({"outlier_px": -1.0}, "outlier_px must be a number > 0 or None, got -1.0"),
    ({"anchor_px": float("nan")}, "anchor_px must be a number > 0 or None"),
])
def test_tracker_rejects_bad_parameters(model, tiny_video, params, match):
    units, neutral, _ = model
    frames, p0 = tiny_video
    tracker = MUTracker(**params)
    assert all(getattr(tracker, k) is v for k, v in params.items())  # stored verbatim
    with pytest.raises(ParameterError, match=match):
        tracker.track(frames, units, neutral=neutral, init_markers=p0)


def test_fits_reject_bad_input(model):
    units, neutral, _ = model
    z = np.tile(neutral, (2, 1, 1))
    with pytest.raises(ParameterError, match=r"zeta must have shape \(79, 2\) or"):
        fit_linear(z[:, :50], units, neutral=neutral)
    with pytest.raises(ParameterError, match="weights must be finite, >= 0"):
        fit_linear(z, units, neutral=neutral, weights=-np.ones((2, 79)))
    few = np.zeros((2, 79))
    few[:, :5] = 1.0
    need = min_markers(units, "smile")
    with pytest.raises(ParameterError, match=f"at least {need} markers of non-zero weight"):
        fit_linear(z, units, "smile", neutral=neutral, weights=few)
    with pytest.raises(ParameterError, match="units must be fitted MotionUnits"):
        fit_nonlinear(z, MotionUnits(), neutral=neutral)
    with pytest.raises(ParameterError, match="less than a pixel apart"):
        init_from_mouth_corners(neutral, [10.0, 10.0], [10.2, 10.0])
