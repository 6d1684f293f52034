"""The coarticulation model fitted on a mouth: the face map equals the generator's, step 1 recovers
drawn parameters, step 2 recovers a known model's targets and rates, the model file round-trips
with its checksum, and ``synth.articulation`` selects it and draws reproducibly."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from data_synth.articulation import (Articulation, articulation_model, articulation_path,
                                     coarticulate, file_sha256, read_articulation,
                                     write_articulation)
from data_synth.articulation_fit import (LOWER, UPPER, FaceMap, Sentence, box_least_squares,
                                         fit_coarticulation, to_articulation)
from data_synth.face import Speaker, articulate
from face_model.corpus import PhoneSegment
from face_model.layout import default_layout
from face_model.phones import ARTIC_PARAMS, PHONE_INDEX, PHONES
from groundwork.errors import ParameterError
from groundwork.settings import SettingError
from talkingface.config import Config

SYNTH = Config().synth
JAW = ARTIC_PARAMS.index("jaw")


def _sentence(rng, phones, n_phones: int) -> list:
    segs, t = [PhoneSegment(0.0, 0.3, "sil")], 0.3
    for _ in range(n_phones):
        d = float(rng.uniform(0.05, 0.15))
        segs.append(PhoneSegment(t, t + d, str(rng.choice(phones))))
        t += d
    segs.append(PhoneSegment(t, t + 0.3, "sil"))
    return segs


def test_face_map_draws_what_the_generator_draws(rng):
    neutral = default_layout().neutral + rng.normal(0, 1.0, (79, 2))
    speaker = Speaker(0, neutral, np.ones(7), 1.0, "en-us+m3", 165, 45)
    artic = rng.uniform(0, 1.2, (40, 7))
    artic[::3, ARTIC_PARAMS.index("closure")] = 1.0
    want = articulate(speaker, artic, np.zeros(40), expression="neutral",
                      envelope=np.zeros(40), cfg=SYNTH)
    scale = np.linalg.norm(neutral[76] - neutral[78]) / 172.0
    got = FaceMap.around(neutral, SYNTH, scale=scale).markers(artic)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


def test_box_least_squares_equals_scipy(rng):
    n, p = 30, 7
    x = rng.normal(size=(n, 20, p))
    y = rng.normal(size=(n, 20)) * 2
    gram = np.einsum("nkp,nkq->npq", x, x) + 1e-6 * np.eye(p)
    rhs = np.einsum("nkp,nk->np", x, y)
    got = box_least_squares(gram, rhs, LOWER, UPPER)
    for i in range(n):
        want = lsq_linear(x[i], y[i], bounds=(LOWER, UPPER), method="bvls").x
        np.testing.assert_allclose(got[i], want, atol=1e-4)


def test_step_one_recovers_drawn_parameters(rng):
    """Coarticulated parameters drawn through the map come back: the markers to 0.1 px for 90 %
    of frames, every parameter's median error under 0.02 (aperture and jaw have no effect on the
    lips while they are closed, so only the median is bounded)."""
    face = FaceMap.around(default_layout().neutral, SYNTH)
    segs = _sentence(rng, PHONES[:-1], 120)
    artic = coarticulate(segs, np.arange(int(segs[-1].end_s * 30)) / 30)
    got, rms = to_articulation(face, face.markers(artic))
    assert np.percentile(rms, 90) < 0.1
    assert np.median(np.abs(got - artic), axis=0).max() < 0.02
    assert got.min() >= 0 and (got <= UPPER).all()


def test_step_one_refuses_bad_markers():
    face = FaceMap.around(default_layout().neutral, SYNTH)
    with pytest.raises(ParameterError, match=r"aligned markers must be finite \(n, 79, 2\)"):
        to_articulation(face, np.zeros((3, 78, 2)))


@pytest.fixture(scope="module")
def known_fit():
    """Trajectories drawn by a known model over 30 sentences of 12 phone classes; fitted from
    the hand table with a negligible prior."""
    rng = np.random.default_rng(7)
    used = ["sil", "aa", "iy", "uw", "m", "f", "s", "t", "ow", "ae", "p", "w"]
    targets = Articulation.table().targets.copy()
    dominance = Articulation.table().dominance.copy()
    for ph in used:
        i = PHONE_INDEX[ph]
        targets[i] = rng.uniform(0, 1, 7)
        dominance[i, :] = np.exp(rng.uniform(-1.5, 0))
        dominance[i, JAW] = np.exp(rng.uniform(-1.5, 0))
    true = Articulation(targets, dominance, 12.0, 30.0, 1.2)
    sentences = []
    for _ in range(30):
        segs = _sentence(rng, used[1:], 14)
        t = np.arange(int(segs[-1].end_s * 30)) / 30
        sentences.append(Sentence(tuple(segs), t, coarticulate(segs, t, true), np.ones(len(t))))
    fitted, fit = fit_coarticulation(sentences, Articulation.table(), steps=150,
                                     prior_frames=1e-3)
    return true, fitted, fit, used


def test_fit_recovers_a_known_models_rates_and_targets(known_fit):
    true, fitted, fit, used = known_fit
    assert fitted.theta_anticipation == pytest.approx(12.0, rel=0.05)
    assert fitted.theta_carryover == pytest.approx(30.0, rel=0.05)
    assert fitted.power == pytest.approx(1.2, rel=0.05)
    rows = [PHONE_INDEX[p] for p in used if p != "sil"]
    err = np.abs(fitted.targets[rows] - true.targets[rows])
    # closure is forced inside /p m/: their own closure target is seen only through neighbours
    assert np.median(err) < 0.01 and np.percentile(err, 95) < 0.1
    assert fit["loss_end"] < 0.01 * fit["loss_start"]


def test_a_fit_leaves_the_processs_thread_count_as_it_was():
    """The fit runs on its own fixed threads and gives the process's share back (a test worker
    or a grid's worker keeps processes x threads within the cores)."""
    import torch

    rng = np.random.default_rng(3)
    segs = _sentence(rng, ["aa", "m", "iy"], 6)
    t = np.arange(int(segs[-1].end_s * 30)) / 30
    table = Articulation.table()
    sentence = Sentence(tuple(segs), t, coarticulate(segs, t, table), np.ones(len(t)))
    before = torch.get_num_threads()
    other = 3 if before != 3 else 1
    torch.set_num_threads(other)
    try:
        fit_coarticulation([sentence], table, steps=2)
        assert torch.get_num_threads() == other
    finally:
        torch.set_num_threads(before)


def test_phones_never_heard_keep_the_prior_exactly(known_fit):
    _, fitted, _, used = known_fit
    table = Articulation.table()
    unseen = [PHONE_INDEX[p] for p in PHONES if p not in used]
    np.testing.assert_array_equal(fitted.targets[unseen], table.targets[unseen])
    np.testing.assert_allclose(fitted.dominance[unseen], table.dominance[unseen], rtol=1e-12)


def test_the_model_file_round_trips_with_its_checksum(known_fit, tmp_path):
    _, fitted, _, _ = known_fit
    path = write_articulation(tmp_path / "m.npz", fitted, {"source": "drawn", "command": "test"})
    back = read_articulation(path)
    np.testing.assert_array_equal(back.targets, fitted.targets)
    np.testing.assert_array_equal(back.dominance, fitted.dominance)
    assert (back.theta_anticipation, back.theta_carryover, back.power) == \
        (fitted.theta_anticipation, fitted.theta_carryover, fitted.power)
    assert back.record["source"] == "drawn"
    data = bytearray(path.read_bytes())
    i = data.index(np.float64(fitted.targets[0, 0]).tobytes())
    data[i] ^= 0xFF
    bad = tmp_path / "bad.npz"
    bad.write_bytes(bytes(data))
    with pytest.raises(ParameterError, match="bad.npz"):
        read_articulation(bad)


def test_the_setting_selects_a_file_and_refuses_others(known_fit, tmp_path):
    _, fitted, _, _ = known_fit
    path = write_articulation(tmp_path / "m.npz", fitted, {"source": "drawn"})
    model = articulation_model(dataclasses.replace(SYNTH, articulation=str(path)))
    np.testing.assert_array_equal(model.targets, fitted.targets)
    assert model.theta_carryover == fitted.theta_carryover
    table = articulation_model(SYNTH)
    assert table.name == "table" and table.theta_anticipation == SYNTH.theta_anticipation
    with pytest.raises(SettingError, match=r"articulation is .*nope\.npz.*allowed: table, a "
                                           r"shipped name"):
        dataclasses.replace(SYNTH, articulation=str(tmp_path / "nope.npz"))
    (tmp_path / "text.npz").write_text("not a model")
    with pytest.raises(SettingError, match="text.npz"):
        dataclasses.replace(SYNTH, articulation=str(tmp_path / "text.npz"))


def test_a_corpus_drawn_with_the_fitted_articulation_is_reproducible_by_seed(tmp_path):
    from data_synth.generate import synthesize_corpus
    from face_model.corpus import load_corpus
    from tests.conftest import small_synth_config

    fitted = small_synth_config(n_sentences=2, expressions=("neutral",), articulation="grid-s1")
    one = synthesize_corpus(tmp_path / "a", fitted, 2002, progress=False)
    two = synthesize_corpus(tmp_path / "b", fitted, 2002, progress=False)
    table = synthesize_corpus(tmp_path / "t", dataclasses.replace(fitted, articulation="table"),
                              2002, progress=False)
    for name in sorted(p.name for p in (one / "markers").iterdir()):
        a, b, t = (np.load(root / "markers" / name) for root in (one, two, table))
        np.testing.assert_array_equal(a, b)
        assert np.abs(a - t).max() > 0.5  # the mouth moves otherwise
        np.testing.assert_array_equal(a[:, 76:], t[:, 76:])  # the same head and glasses
    info = json.loads((one / "corpus.json").read_text())
    assert info["articulation"]["sha256"] == file_sha256(articulation_path("grid-s1"))
    assert "articulation" not in json.loads((table / "corpus.json").read_text())["settings"]
    assert len(load_corpus(one).utterances) == 2
