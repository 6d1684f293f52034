"""Alignment by the three glasses markers (paper §IV-A): head motion removed, deformations."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from data_synth.face import make_speaker
from data_synth.nuisance import apply_head_motion, head_motion
from face_model.alignment import (
    affine_params,
    align_markers,
    corpus_deformations,
    flatten,
    similarity_params,
    speaker_neutrals,
    unflatten,
)
from face_model.layout import GLASSES, default_layout
from groundwork.errors import ParameterError
from talkingface.config import Config

G = list(GLASSES)


def _deformed_faces(rng, n_frames: int, sd_px: float = 4.0) -> np.ndarray:
    """Neutral face plus random per-frame deformation of the skin; glasses at the reference."""
    faces = np.repeat(default_layout().neutral[None], n_frames, axis=0).copy()
    faces[:, :76] += sd_px * rng.standard_normal((n_frames, 76, 2))
    return faces


def _similarity(rng, n_frames: int):
    ang = rng.uniform(-0.4, 0.4, n_frames)
    s = rng.uniform(0.7, 1.3, n_frames)
    A = s[:, None, None] * np.stack([np.stack([np.cos(ang), -np.sin(ang)], -1),
                                     np.stack([np.sin(ang), np.cos(ang)], -1)], -2)
    t = rng.uniform(-80, 80, (n_frames, 2))
    return A, t


def _apply(A, t, points):
    return np.einsum("nij,nmj->nmi", A, points) + t[:, None, :]


def test_similarity_alignment_removes_random_head_motion_exactly(rng):
    faces = _deformed_faces(rng, 40)
    A, t = _similarity(rng, 40)
    moved = _apply(A, t, faces)
    assert np.abs(moved - faces).max() > 10.0  # the motion is large
    aligned = align_markers(moved, model="similarity")
    np.testing.assert_allclose(aligned, faces, rtol=0, atol=1e-9)


def test_similarity_alignment_removes_the_generators_head_motion(rng):
    """The generator's own nuisance (data_synth.nuisance) is undone without noise."""
    synth = Config().synth
    spk = make_speaker(0, synth, seed=11)
    face = np.repeat(spk.neutral[None], 90, axis=0)
    face = face + 2.0 * rng.standard_normal(face.shape) * (np.arange(79) < 76)[None, :, None]
    motion = head_motion(rng, 90, 30, rotation_deg=5.0, scale=0.05, translation_px=20.0)
    moved = apply_head_motion(face, motion)
    np.testing.assert_allclose(align_markers(moved), align_markers(face), rtol=0, atol=1e-9)


@given(angle=st.floats(-3.0, 3.0), scale=st.floats(0.2, 5.0),
       tx=st.floats(-500, 500), ty=st.floats(-500, 500))
def test_similarity_alignment_is_exact_for_any_similarity(angle, scale, tx, ty):
    faces = _deformed_faces(np.random.default_rng(3), 2)
    A = scale * np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    moved = _apply(np.stack([A, A]), np.array([[tx, ty], [tx, ty]]), faces)
    np.testing.assert_allclose(align_markers(moved), faces, rtol=0, atol=1e-8)


def test_similarity_params_is_the_least_squares_solution(rng):
    """With noisy glasses, the closed form equals a generic linear least-squares fit."""
    src = rng.uniform(0, 300, (5, 3, 2))
    dst = rng.uniform(0, 300, (5, 3, 2))
    A, t = similarity_params(src, dst)
    for k in range(5):
        # dst = [a -b; b a] src + t  is linear in (a, b, tx, ty).
        rows_x = np.c_[src[k, :, 0], -src[k, :, 1], np.ones(3), np.zeros(3)]
        rows_y = np.c_[src[k, :, 1], src[k, :, 0], np.zeros(3), np.ones(3)]
        sol, *_ = np.linalg.lstsq(np.r_[rows_x, rows_y], np.r_[dst[k, :, 0], dst[k, :, 1]],
                                  rcond=None)
        a, b, tx, ty = sol
        np.testing.assert_allclose(A[k], [[a, -b], [b, a]], atol=1e-10)
        np.testing.assert_allclose(t[k], [tx, ty], atol=1e-8)


def test_affine_alignment_maps_the_glasses_exactly_onto_the_reference(rng):
    faces = _deformed_faces(rng, 30)
    # Arbitrary (non-similarity) glasses: the three points move independently, by up to 5 px
    # (more would make the 16 px high glasses triangle nearly degenerate).
    faces[:, G] += rng.uniform(-5, 5, (30, 3, 2))
    aligned = align_markers(faces, model="affine")
    ref = np.broadcast_to(default_layout().neutral[G], (30, 3, 2))
    np.testing.assert_allclose(aligned[:, G], ref, rtol=0, atol=1e-9)
    custom = np.array([[100.0, 200.0], [180.0, 170.0], [260.0, 210.0]])
    aligned = align_markers(faces, model="affine", reference=custom)
    np.testing.assert_allclose(aligned[:, G], np.broadcast_to(custom, (30, 3, 2)),
                               rtol=0, atol=1e-9)


def test_affine_alignment_undoes_any_affine_head_motion(rng):
    faces = _deformed_faces(rng, 20)
    A = np.eye(2) + rng.uniform(-0.3, 0.3, (20, 2, 2))  # rotation, anisotropic scale and shear
    t = rng.uniform(-50, 50, (20, 2))
    aligned = align_markers(_apply(A, t, faces), model="affine")
    np.testing.assert_allclose(aligned, faces, rtol=0, atol=1e-8)
    A2, t2 = affine_params(faces[:, G], _apply(A, t, faces)[:, G])
    np.testing.assert_allclose(A2, A, atol=1e-10)
    np.testing.assert_allclose(t2, t, atol=1e-8)


def test_similarity_alignment_maps_similar_glasses_onto_a_custom_reference(rng):
    ref = default_layout().neutral[G] * 1.1 + np.array([12.0, -7.0])
    faces = _deformed_faces(rng, 10)
    A, t = _similarity(rng, 10)
    aligned = align_markers(_apply(A, t, faces), reference=ref)
    np.testing.assert_allclose(aligned[:, G], np.broadcast_to(ref, (10, 3, 2)), atol=1e-9)


def test_flatten_interleaves_x_and_y_and_round_trips(rng):
    pts = rng.standard_normal((4, 79, 2))
    flat = flatten(pts)
    assert flat.shape == (4, 158)
    assert np.array_equal(flat[:, 0::2], pts[..., 0]) and np.array_equal(flat[:, 1::2], pts[..., 1])
    assert np.array_equal(unflatten(flat), pts)


@pytest.mark.parametrize("shape", [(5, 78, 2), (5, 79, 3), (79, 2)])
def test_align_refuses_wrong_marker_shapes(shape):
    with pytest.raises(ParameterError, match=rf"markers must have shape \(n_frames, 79, 2\), "
                                             rf"got {__import__('re').escape(str(shape))}"):
        align_markers(np.zeros(shape))


def test_align_refuses_nan_unknown_model_and_bad_reference(rng):
    faces = _deformed_faces(rng, 3)
    bad = faces.copy()
    bad[1, 50, 0] = np.nan
    with pytest.raises(ParameterError, match="markers hold NaN or inf"):
        align_markers(bad)
    with pytest.raises(ParameterError, match="alignment model 'projective'; allowed: similarity, "
                                             "affine"):
        align_markers(faces, model="projective")
    with pytest.raises(ParameterError, match=r"reference glasses must have shape \(3, 2\), "
                                             r"got \(2, 2\)"):
        align_markers(faces, reference=np.zeros((2, 2)))


def test_speaker_neutral_is_the_median_aligned_first_frame(small_corpus):
    neutrals = speaker_neutrals(small_corpus)
    assert set(neutrals) == {"s00"}
    defs = corpus_deformations(small_corpus, neutrals=neutrals)
    assert set(defs) == {u.utt_id for u in small_corpus.utterances}
    firsts = np.stack([defs[u.utt_id][0] for u in small_corpus.by_expression("neutral")])
    np.testing.assert_allclose(np.median(firsts, axis=0), 0.0, atol=1e-9)
    for u in small_corpus.utterances:
        assert defs[u.utt_id].shape == (u.n_frames, 158)
        # Head motion removed: the glasses hardly deform (marker noise only, 0.15 px).
        glasses = unflatten(defs[u.utt_id])[:, G]
        assert np.abs(glasses).max() < 1.5


def test_speaker_without_neutral_utterance_is_refused():
    face = default_layout().neutral[None].copy()
    corpus = SimpleNamespace(utterances=[
        SimpleNamespace(speaker="s00", expression="neutral", markers=face, utt_id="a"),
        SimpleNamespace(speaker="s01", expression="smile", markers=face, utt_id="b"),
    ])
    with pytest.raises(ParameterError, match=r"speakers \['s01'\] have no neutral utterance"):
        speaker_neutrals(corpus)
