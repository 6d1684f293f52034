"""Motion Units (paper §IV-A, Eqs. 1–2): round trips, orthonormality, recovery of known models,
persistence, deterministic signs and error messages."""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.linalg import subspace_angles

from data_synth.face import expression_fields, make_speaker
from face_model.motion_units import MotionUnits, fit_corpus_units
from groundwork import modelfile
from groundwork.errors import NotFittedError, ParameterError
from talkingface.config import Config

D = 158


def _orthonormal(rng, k: int, against: np.ndarray | None = None) -> np.ndarray:
    """``k`` random orthonormal rows of length 158, orthogonal to the rows of ``against``."""
    m = rng.standard_normal((D, k))
    if against is not None:
        m -= against.T @ (against @ m)
    q, _ = np.linalg.qr(m)
    return q.T


def _low_rank(rng, n: int, basis: np.ndarray, sd: np.ndarray, mean: np.ndarray) -> np.ndarray:
    return mean + (rng.standard_normal((n, len(basis))) * sd) @ basis


@pytest.fixture
def model_data(rng):
    """Neutral data of rank 7 plus full-rank noise; smile and sad add their own directions."""
    mean = rng.normal(0, 3, D)
    basis = _orthonormal(rng, 7)
    sd = np.array([9.0, 7.0, 5.0, 4.0, 3.0, 2.0, 1.5])
    noise = lambda n: 0.05 * rng.standard_normal((n, D))  # noqa: E731
    data = {"neutral": _low_rank(rng, 600, basis, sd, mean) + noise(600)}
    for name in ("smile", "sad"):
        direction = rng.standard_normal((2, D))
        intensity = rng.uniform(0.5, 1.0, (400, 1)) * [4.0, 1.0] + rng.standard_normal((400, 2))
        data[name] = _low_rank(rng, 400, basis, sd, mean) + intensity @ direction + noise(400)
    return data


@pytest.fixture
def fitted(model_data):
    return MotionUnits(7, 2).fit(model_data, metadata={"source": "test"})


def _within_span(mu: MotionUnits, rng, n: int, expression: str = "neutral") -> np.ndarray:
    d = mu.mean_ + rng.standard_normal((n, mu.n_utterance)) * 5 @ mu.components_
    if expression != "neutral":
        d = d + mu.expression_mean_[expression] \
            + rng.standard_normal((n, mu.n_expression)) * 3 @ mu.expression_components_[expression]
    return d


@pytest.mark.parametrize("expression", ["neutral", "smile", "sad"])
def test_round_trip_is_exact_inside_the_mu_span(fitted, rng, expression):
    d = _within_span(fitted, rng, 50, expression)
    mups = fitted.transform(d, expression)
    assert mups.shape == (50, 9)
    np.testing.assert_allclose(fitted.inverse_transform(mups, expression), d, rtol=0, atol=1e-10)
    # ... and MUPs → deformations → MUPs is the identity too.
    np.testing.assert_allclose(fitted.transform(fitted.inverse_transform(mups, expression),
                                                expression), mups, rtol=0, atol=1e-10)


def test_neutral_mups_have_a_zero_expression_part(fitted, model_data):
    mups = fitted.transform(model_data["smile"][:20], "neutral")
    assert np.array_equal(mups[:, 7:], np.zeros((20, 2)))


@given(coef=arrays(np.float64, (3, 9), elements=st.floats(-50, 50)),
       expression=st.sampled_from(["neutral", "smile", "sad"]))
def test_round_trip_property(coef, expression):
    rng = np.random.default_rng(5)
    mean = rng.normal(0, 3, D)
    basis = _orthonormal(rng, 9)
    data = {"neutral": _low_rank(rng, 60, basis[:7], np.arange(7, 0, -1.0), mean)}
    data["smile"] = data["neutral"][:40] + rng.standard_normal((40, 2)) @ basis[7:] * 3
    data["sad"] = data["neutral"][20:] + (rng.standard_normal((40, 2)) * [1.0, -2.0]) @ basis[7:]
    mu = MotionUnits(7, 2).fit(data)
    if expression == "neutral":
        coef = coef.copy()
        coef[:, 7:] = 0.0
    d = mu.inverse_transform(coef, expression)
    np.testing.assert_allclose(mu.transform(d, expression), coef, rtol=0, atol=1e-9)


def test_reconstruction_error_of_the_training_data_is_the_unexplained_variance(fitted,
                                                                                model_data):
    d0 = model_data["neutral"]
    err = d0 - fitted.inverse_transform(fitted.transform(d0))
    np.testing.assert_allclose((err**2).sum() / (len(d0) - 1), fitted.variance_[7:].sum(),
                               rtol=1e-9)
    for k in ("smile", "sad"):
        dk = model_data[k]
        err = dk - fitted.inverse_transform(fitted.transform(dk, k), k)
        np.testing.assert_allclose((err**2).sum() / (len(dk) - 1),
                                   fitted.expression_variance_[k][2:].sum(), rtol=1e-9)
    # The variance shares agree with it.
    total = fitted.variance_.sum()
    np.testing.assert_allclose(fitted.variance_explained()["neutral"],
                               1 - fitted.variance_[7:].sum() / total, rtol=1e-12)


def test_utterance_mus_are_orthonormal(fitted):
    c = fitted.components_
    assert c.shape == (7, D)
    np.testing.assert_allclose(c @ c.T, np.eye(7), rtol=0, atol=1e-12)


def test_expression_mus_are_orthonormal_and_orthogonal_to_the_utterance_mus(fitted):
    assert fitted.expressions_ == ("smile", "sad")
    for k in fitted.expressions_:
        ck = fitted.expression_components_[k]
        assert ck.shape == (2, D)
        np.testing.assert_allclose(ck @ ck.T, np.eye(2), rtol=0, atol=1e-12)
        np.testing.assert_allclose(ck @ fitted.components_.T, 0.0, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fitted.components_ @ fitted.expression_mean_[k], 0.0,
                                   atol=1e-10)


@pytest.mark.parametrize("rank,n_utterance", [(5, 5), (3, 7)])
def test_recovers_a_known_low_rank_subspace(rng, rank, n_utterance):
    basis = _orthonormal(rng, rank)
    mean = rng.normal(0, 10, D)
    d = _low_rank(rng, 300, basis, np.linspace(8.0, 2.0, rank), mean)
    mu = MotionUnits(n_utterance, 2).fit({"neutral": d})
    np.testing.assert_allclose(mu.mean_, d.mean(0), atol=1e-12)
    np.testing.assert_allclose(subspace_angles(mu.components_[:rank].T, basis.T), 0.0, atol=1e-6)
    ratio = mu.explained_variance_ratio()
    np.testing.assert_allclose(ratio[rank - 1:], 1.0, atol=1e-12)
    assert ratio[rank - 2] < 0.999
    np.testing.assert_allclose(mu.variance_explained()["neutral"], 1.0, atol=1e-12)
    np.testing.assert_allclose(mu.variance_[rank:], 0.0, atol=1e-12)
    # The eigenvalues are the variances of the data along the true axes.
    np.testing.assert_allclose(mu.variance_[:rank].sum(),
                               ((d - d.mean(0)) @ basis.T).var(0, ddof=1).sum(), rtol=1e-10)


def test_expression_mu_recovers_a_known_expression_direction(rng):
    basis = _orthonormal(rng, 7)
    direction = _orthonormal(rng, 1, against=basis)[0]
    mean = rng.normal(0, 3, D)
    sd = np.linspace(6.0, 1.0, 7)
    intensity = rng.uniform(0.2, 1.0, (300, 1)) * 5.0
    data = {"neutral": _low_rank(rng, 400, basis, sd, mean),
            "smile": _low_rank(rng, 300, basis, sd, mean) + intensity * direction}
    mu = MotionUnits(7, 1).fit(data)
    m1 = mu.expression_components_["smile"][0]
    np.testing.assert_allclose(abs(m1 @ direction), 1.0, atol=1e-10)
    np.testing.assert_allclose(mu.expression_mean_["smile"], intensity.mean() * direction,
                               atol=1e-9)
    np.testing.assert_allclose(mu.variance_explained()["smile"], 1.0, atol=1e-12)
    # The MUP of a frame is its intensity about the mean (up to the axis's sign).
    ck = mu.transform(data["smile"], "smile")[:, 7]
    np.testing.assert_allclose(np.abs(np.corrcoef(ck, intensity[:, 0])[0, 1]), 1.0, atol=1e-10)


def test_expression_mu_is_the_residual_of_a_direction_partly_inside_the_utterance_space(rng):
    basis = _orthonormal(rng, 7)
    outside = _orthonormal(rng, 1, against=basis)[0]
    direction = 0.6 * outside + 0.8 * basis[2]  # unit length, mostly in the utterance space
    sd = np.linspace(6.0, 1.0, 7)
    data = {"neutral": _low_rank(rng, 400, basis, sd, np.zeros(D)),
            "sad": _low_rank(rng, 300, basis, sd, np.zeros(D))
            + rng.uniform(1.0, 4.0, (300, 1)) * direction}
    mu = MotionUnits(7, 1).fit(data)
    np.testing.assert_allclose(abs(mu.expression_components_["sad"][0] @ outside), 1.0,
                               atol=1e-10)


def test_two_expression_mus_recover_a_two_dimensional_expression_space(rng):
    basis = _orthonormal(rng, 7)
    expr = _orthonormal(rng, 2, against=basis)
    sd = np.linspace(6.0, 1.0, 7)
    data = {"neutral": _low_rank(rng, 400, basis, sd, np.zeros(D)),
            "smile": _low_rank(rng, 300, basis, sd, np.zeros(D))
            + (rng.standard_normal((300, 2)) * [3.0, 1.0]) @ expr}
    mu = MotionUnits(7, 2).fit(data)
    np.testing.assert_allclose(subspace_angles(mu.expression_components_["smile"].T, expr.T),
                               0.0, atol=1e-6)


def test_save_and_load_give_identical_transforms(fitted, model_data, tmp_path):
    path = fitted.save(tmp_path / "units.npz")
    loaded = MotionUnits.load(path)
    assert (loaded.n_utterance, loaded.n_expression) == (7, 2)
    assert loaded.expressions_ == fitted.expressions_
    assert loaded.metadata_["source"] == "test"
    assert loaded.metadata_["layout_version"] == "hwh79-1"
    for k in ("neutral", "smile", "sad"):
        d = model_data[k][:30]
        mups = fitted.transform(d, k)
        assert np.array_equal(loaded.transform(d, k), mups)
        assert np.array_equal(loaded.inverse_transform(mups, k), fitted.inverse_transform(mups, k))
        assert np.array_equal(loaded.explained_variance_ratio(k),
                              fitted.explained_variance_ratio(k))
    # Saving the loaded model again gives the same arrays.
    again = MotionUnits.load(loaded.save(tmp_path / "again.npz"))
    assert np.array_equal(again.components_, fitted.components_)


def test_load_refuses_a_missing_or_foreign_file(tmp_path):
    with pytest.raises(ParameterError, match=r"Motion Units file .*nothere\.npz not found"):
        MotionUnits.load(tmp_path / "nothere.npz")
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, metadata=np.array('{"format": "something/else"}'), mean=np.zeros(D))
    with pytest.raises(ParameterError, match=r"foreign\.npz: not a Motion Units file \(format "
                                             r"'something/else'"):
        MotionUnits.load(foreign)


def test_the_file_holds_the_to_arrays_record(fitted, model_data, tmp_path):
    """motion_units.npz is exactly :meth:`to_arrays`: these names, this metadata (format 1)."""
    arrays, meta = fitted.to_arrays()
    assert set(arrays) == {"mean", "components", "variance"} | {
        f"{k}__{a}" for k in ("smile", "sad") for a in ("mean", "components", "variance")}
    assert meta == {"format": "talkingface.motion_units/1", "layout_version": "hwh79-1",
                    "n_utterance": 7, "n_expression": 2, "expressions": ["smile", "sad"],
                    "source": "test"}
    assert arrays["components"].shape == (7, D) and arrays["sad__components"].shape == (2, D)
    with np.load(fitted.save(tmp_path / "units.npz"), allow_pickle=False) as z:
        assert set(z.files) == {"metadata", *arrays}
        stored = json.loads(str(z["metadata"]))
        assert (stored.pop("kind"), stored.pop("version")) == ("motion_units", 2)
        assert stored.pop("arrays") == modelfile.manifest(arrays)
        assert stored.pop("sha256") == modelfile.checksum(
            arrays, {**meta, "kind": "motion_units", "version": 2,
                     "arrays": modelfile.manifest(arrays)})
        assert stored == meta
        for name, value in arrays.items():
            assert z[name].dtype == value.dtype and np.array_equal(z[name], value)
    back = MotionUnits.from_arrays(arrays, json.loads(json.dumps(meta)))
    assert back.metadata_ == {"source": "test", "layout_version": "hwh79-1"}
    for k in ("neutral", "smile", "sad"):
        assert np.array_equal(back.transform(model_data[k][:30], k),
                              fitted.transform(model_data[k][:30], k))
    again, again_meta = back.to_arrays()
    assert again_meta == meta and all(np.array_equal(again[n], arrays[n]) for n in arrays)


def _save_version_1(units: MotionUnits, path):
    """``units`` as the version-1 code saved them: np.savez of the arrays and the record, no
    kind, no checksum."""
    arrays, meta = units.to_arrays()
    with open(path, "wb") as f:
        np.savez(f, metadata=np.array(json.dumps(meta, sort_keys=True)), **arrays)
    return path


def test_a_version_1_file_loads_as_the_same_model(fitted, model_data, tmp_path):
    old = MotionUnits.load(_save_version_1(fitted, tmp_path / "old.npz"))
    new = MotionUnits.load(fitted.save(tmp_path / "new.npz"))
    for loaded in (old, new):
        assert loaded.metadata_ == {"source": "test", "layout_version": "hwh79-1"}
        assert loaded.expressions_ == fitted.expressions_
        for name in ("mean_", "components_", "variance_"):
            assert getattr(loaded, name).tobytes() == getattr(fitted, name).tobytes()
        for k in ("neutral", "smile", "sad"):
            d = model_data[k][:30]
            assert loaded.transform(d, k).tobytes() == fitted.transform(d, k).tobytes()
    # re-saved, the old model is the new file, member for member (the zip's dates aside)
    with np.load(old.save(tmp_path / "again.npz")) as a, np.load(tmp_path / "new.npz") as b:
        assert a.files == b.files and all(a[n].tobytes() == b[n].tobytes() for n in a.files)


def test_a_damaged_or_foreign_model_file_is_one_line_naming_it(fitted, tmp_path):
    path = fitted.save(tmp_path / "units.npz")
    members = dict(np.load(path, allow_pickle=False))
    members["mean"] = members["mean"] + 1e-12  # a consistent archive, other numbers
    bad = tmp_path / "bad.npz"
    with open(bad, "wb") as f:
        np.savez(f, **members)
    with pytest.raises(ParameterError, match=r"bad\.npz: checksum mismatch"):
        MotionUnits.load(bad)
    cut = tmp_path / "cut.npz"
    cut.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(ParameterError, match=r"cut\.npz: the model file is truncated or damaged"):
        MotionUnits.load(cut)
    other = modelfile.write_model(tmp_path / "other.npz", {"x": np.zeros(2)}, {},
                                  kind="keyframes", version=3)
    with pytest.raises(ParameterError, match=r"other\.npz: not a Motion Units file \(its kind "
                                             r"is 'keyframes', expected 'motion_units'\)$"):
        MotionUnits.load(other)
    newer = modelfile.write_model(tmp_path / "newer.npz", *fitted.to_arrays(),
                                  kind="motion_units", version=3)
    with pytest.raises(ParameterError, match=r"newer\.npz was saved by a newer version of "
                                             r"talkingface \(motion_units version 3; this "
                                             r"version reads 2\); update talkingface$"):
        MotionUnits.load(newer)


def test_from_arrays_refuses_a_foreign_record_or_missing_arrays(fitted):
    arrays, meta = fitted.to_arrays()
    with pytest.raises(ParameterError, match=r"record: not a Motion Units file \(format 'x', "
                                             r"expected 'talkingface\.motion_units/1'\)"):
        MotionUnits.from_arrays(arrays, {**meta, "format": "x"}, source="record")
    del arrays["sad__components"], arrays["variance"]
    with pytest.raises(ParameterError, match="Motion Units: Motion Units arrays variance, "
                                             "sad__components are missing"):
        MotionUnits.from_arrays(arrays, meta)
    with pytest.raises(NotFittedError):
        MotionUnits().to_arrays()


def test_signs_are_deterministic(model_data):
    a = MotionUnits(7, 2).fit(model_data)
    b = MotionUnits(7, 2).fit({k: v.copy() for k, v in model_data.items()})
    assert np.array_equal(a.components_, b.components_)
    for k in ("smile", "sad"):
        assert np.array_equal(a.expression_components_[k], b.expression_components_[k])
    # The convention: the largest-magnitude loading of every axis is positive, so reordering the
    # frames (which changes the SVD's arithmetic) gives the same axes.
    for c in [a.components_, *a.expression_components_.values()]:
        assert np.all(c[np.arange(len(c)), np.abs(c).argmax(1)] > 0)
    rev = MotionUnits(7, 2).fit({k: v[::-1] for k, v in model_data.items()})
    np.testing.assert_allclose(rev.components_, a.components_, atol=1e-8)
    for k in ("smile", "sad"):
        np.testing.assert_allclose(rev.expression_components_[k], a.expression_components_[k],
                                   atol=1e-6)


def test_not_fitted_errors():
    mu = MotionUnits()
    d = np.zeros((3, D))
    for call in (lambda: mu.transform(d), lambda: mu.inverse_transform(np.zeros((3, 9))),
                 lambda: mu.explained_variance_ratio(), lambda: mu.save("x.npz")):
        with pytest.raises(NotFittedError, match="MotionUnits is not fitted yet"):
            call()
    assert not hasattr(mu, "components_")


def test_wrong_shapes_and_unknown_expression_are_refused(fitted):
    with pytest.raises(ParameterError, match=r"deformations must have shape \(n_frames, 158\), "
                                             r"got \(4, 157\)"):
        fitted.transform(np.zeros((4, 157)))
    with pytest.raises(ParameterError, match=r"deformations must have shape \(n_frames, 158\), "
                                             r"got \(158,\)"):
        fitted.transform(np.zeros(D))
    with pytest.raises(ParameterError, match=r"MUPs must have shape \(n_frames, 9\), got \(4, 7\)"):
        fitted.inverse_transform(np.zeros((4, 7)))
    with pytest.raises(ParameterError, match="expression 'angry' has no MUs; allowed: neutral, "
                                             "smile, sad"):
        fitted.transform(np.zeros((4, D)), "angry")
    with pytest.raises(ParameterError, match="expression 'angry' has no MUs"):
        fitted.inverse_transform(np.zeros((4, 9)), "angry")
    with pytest.raises(ParameterError, match="expression 'angry' has no MUs"):
        fitted.explained_variance_ratio("angry")
    bad = np.zeros((4, D))
    bad[2, 5] = np.inf
    with pytest.raises(ParameterError, match="deformations hold NaN or inf"):
        fitted.transform(bad)


def test_fit_refuses_bad_input(model_data, rng):
    with pytest.raises(ParameterError, match=r"needs neutral deformations \(key 'neutral'\); "
                                             r"got keys \['sad', 'smile'\]"):
        MotionUnits().fit({"smile": model_data["smile"], "sad": model_data["sad"]})
    with pytest.raises(ParameterError, match=r"n_utterance must be an integer in 1\.\.158, got 0"):
        MotionUnits(0, 2).fit(model_data)
    with pytest.raises(ParameterError, match=r"n_expression must be an integer in 1\.\.158, "
                                             r"got 2\.5"):
        MotionUnits(7, 2.5).fit(model_data)
    with pytest.raises(ParameterError, match="7 neutral frames cannot give 7 MUs"):
        MotionUnits(7, 2).fit({"neutral": model_data["neutral"][:7]})
    with pytest.raises(ParameterError, match="2 smile frames cannot give 2 MUs"):
        MotionUnits(7, 2).fit({"neutral": model_data["neutral"], "smile": model_data["smile"][:2]})
    with pytest.raises(ParameterError, match=r"smile deformations must have shape "
                                             r"\(n_frames, 158\), got \(50, 79, 2\)"):
        MotionUnits().fit({"neutral": model_data["neutral"],
                           "smile": rng.standard_normal((50, 79, 2))})
    nan = model_data["neutral"].copy()
    nan[3, 3] = np.nan
    with pytest.raises(ParameterError, match="neutral deformations hold NaN or inf"):
        MotionUnits().fit({"neutral": nan})


def test_corpus_units_recover_the_generators_expression_fields(small_corpus):
    """On a synthetic corpus, the first expression MU is the generator's smile (sad) field, seen
    beyond the utterance MUs."""
    units, defs = fit_corpus_units(small_corpus, metadata={"run": "t"})
    assert units.metadata_ == {"alignment": "similarity", "run": "t"}
    assert set(defs) == {u.utt_id for u in small_corpus.utterances}
    assert units.variance_explained()["neutral"] > 0.9
    spk = make_speaker(0, Config().synth, small_corpus.info["seed"])
    fields = expression_fields(spk.neutral)
    for k in ("smile", "sad"):
        v = fields[k].ravel()
        v = v - units.components_.T @ (units.components_ @ v)
        v /= np.linalg.norm(v)
        assert abs(units.expression_components_[k][0] @ v) > 0.99
