"""Linear algebra that does not depend on the processor or the BLAS thread count
(groundwork.numerics): the gesvd fallback when gesdd fails, one- and two-thread fits equal, and
the AMD EPYC failure (OpenBLAS Haswell kernels, two threads) reproduced in a subprocess."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from face_model.alignment import corpus_deformations
from face_model.keyframes import KeyframeModel
from face_model.motion_units import MotionUnits, fit_corpus_units
from groundwork import numerics
from talkingface.config import Config

REPO_ROOT = Path(__file__).resolve().parents[2]


def _deformations(corpus):
    defs = corpus_deformations(corpus)
    by: dict = {}
    for u in corpus.utterances:
        by.setdefault(u.expression, []).append(defs[u.utt_id])
    return {k: np.concatenate(v) for k, v in by.items()}


def _arrays(mu: MotionUnits) -> dict:
    out = {"mean": mu.mean_, "components": mu.components_, "variance": mu.variance_}
    for k in mu.expressions_:
        out[f"{k}.mean"] = mu.expression_mean_[k]
        out[f"{k}.components"] = mu.expression_components_[k]
        out[f"{k}.variance"] = mu.expression_variance_[k]
    return out


def _assert_same_units(a: MotionUnits, b: MotionUnits, atol: float) -> None:
    aa, bb = _arrays(a), _arrays(b)
    assert aa.keys() == bb.keys()
    for k in aa:  # signs included: no abs() anywhere
        np.testing.assert_allclose(aa[k], bb[k], rtol=0, atol=atol * max(1.0, np.abs(aa[k]).max()),
                                   err_msg=k)


def test_motion_units_fit_when_gesdd_fails(small_corpus, monkeypatch):
    defs = _deformations(small_corpus)
    normal = MotionUnits().fit(defs)
    calls = []

    def failing_gesdd(*args, **kwargs):
        calls.append(1)
        raise np.linalg.LinAlgError("SVD did not converge")

    monkeypatch.setattr(np.linalg, "svd", failing_gesdd)
    fallback = MotionUnits().fit(defs)
    assert len(calls) == 1 + len(normal.expressions_)  # every PCA went through the fallback
    _assert_same_units(normal, fallback, 1e-12)


def test_motion_units_equal_with_one_and_two_blas_threads(small_corpus):
    defs = _deformations(small_corpus)
    with threadpool_limits(limits=1, user_api="blas"):
        one = MotionUnits().fit(defs)
    with threadpool_limits(limits=2, user_api="blas"):
        assert all(i["num_threads"] == 2 for i in threadpool_info() if i["user_api"] == "blas")
        two = MotionUnits().fit(defs)
    _assert_same_units(one, two, 1e-12)


def test_fits_run_on_one_blas_thread_and_restore_the_caller_setting():
    seen = []

    @numerics.single_threaded
    def probe():
        seen.extend(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")

    with threadpool_limits(limits=2, user_api="blas"):
        probe()
        after = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    assert seen and set(seen) == {1}
    assert set(after) == {2}


def test_pinv_and_lstsq_match_numpy_and_survive_a_failing_driver(rng, monkeypatch):
    a = rng.standard_normal((158, 8))
    b = rng.standard_normal((158, 3))
    np.testing.assert_array_equal(numerics.pinv(a), np.linalg.pinv(a))
    np.testing.assert_array_equal(numerics.lstsq(a, b), np.linalg.lstsq(a, b, rcond=None)[0])
    want_pinv, want_x = np.linalg.pinv(a), np.linalg.lstsq(a, b, rcond=None)[0]

    def fail(*args, **kwargs):
        raise np.linalg.LinAlgError("did not converge")

    monkeypatch.setattr(np.linalg, "svd", fail)
    monkeypatch.setattr(np.linalg, "lstsq", fail)
    np.testing.assert_allclose(numerics.pinv(a), want_pinv, rtol=0, atol=1e-12)
    np.testing.assert_allclose(numerics.lstsq(a, b), want_x, rtol=0, atol=1e-12)


def test_keyframe_model_fits_when_gesdd_fails(small_corpus, monkeypatch):
    units, defs = fit_corpus_units(small_corpus)
    normal = KeyframeModel().fit(small_corpus, units, deformations=defs)

    def fail(*args, **kwargs):
        raise np.linalg.LinAlgError("SVD did not converge")

    monkeypatch.setattr(np.linalg, "svd", fail)
    fallback = KeyframeModel().fit(small_corpus, units, deformations=defs)
    np.testing.assert_allclose(fallback.pinv_, normal.pinv_, rtol=0, atol=1e-12)
    assert fallback.condition_ == pytest.approx(normal.condition_, rel=1e-12)


_CHILD = """
import json, sys
import numpy as np
from face_model.corpus import load_corpus
from face_model.motion_units import fit_corpus_units
units, _ = fit_corpus_units(load_corpus(sys.argv[1]))
print(json.dumps({"components": units.components_.tolist(),
                  "smile": units.expression_components_["smile"].tolist(),
                  "sad": units.expression_components_["sad"].tolist()}))
"""


def test_three_sentence_corpus_fits_with_haswell_kernels_on_two_threads(tmp_path, synth_config):
    """The reported failure: OpenBLAS's Haswell kernels (what it picks on an AVX2 AMD EPYC)
    with two threads, and the 3-sentence corpus whose smile residual made gesdd fail."""
    from data_synth.generate import synthesize_corpus
    from face_model.corpus import load_corpus

    corpus_dir = synthesize_corpus(tmp_path / "c", synth_config(n_sentences=3), Config().seed,
                                   progress=False)
    env = {**os.environ, "OPENBLAS_CORETYPE": "Haswell", "OPENBLAS_NUM_THREADS": "2",
           "PYTHONPATH": str(REPO_ROOT)}
    out = subprocess.run([sys.executable, "-c", _CHILD, str(corpus_dir)], env=env,
                         capture_output=True, text=True, cwd=REPO_ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    child = json.loads(out.stdout)
    here, _ = fit_corpus_units(load_corpus(corpus_dir))
    np.testing.assert_allclose(child["components"], here.components_, rtol=0, atol=1e-12)
    np.testing.assert_allclose(child["smile"], here.expression_components_["smile"], rtol=0,
                               atol=1e-12)
    np.testing.assert_allclose(child["sad"], here.expression_components_["sad"], rtol=0,
                               atol=1e-12)
