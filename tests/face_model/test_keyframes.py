"""Keyframes and the MUP ↔ keyframe-weight conversion ( §IV-B, Eqs. 3–4; §VII-B): keyframe
selection by semantic correspondence, exact round trips inside the keyframe span, the measured
Eq. 4 round-trip error, weight-track files and their validation, persistence and error messages."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from data_synth.face import expression_fields, make_speaker
from face_model.keyframes import (KEYFRAMES, KeyframeModel, read_keyframe_tracks,
                                  write_keyframe_tracks)
from face_model.motion_units import MotionUnits, fit_corpus_units
from face_model.phones import BILABIALS, PHONES, viseme
from groundwork.errors import NotFittedError, ParameterError
from talkingface.config import Config

D = 158


@pytest.fixture(scope="module")
def fitted(small_corpus):
    units, defs = fit_corpus_units(small_corpus)
    return KeyframeModel().fit(small_corpus, units, deformations=defs), units, defs


def _mups_of(corpus, units, defs, expression):
    return np.concatenate([units.transform(defs[u.utt_id], expression)
                           for u in corpus.by_expression(expression)])


def _strength(units, d, expression):
    """Expression strength as the module defines it: the Eq. 1 residual on m_k0's direction."""
    r = d - units.mean_ - ((d - units.mean_) @ units.components_.T) @ units.components_
    m = units.expression_mean_[expression]
    return r @ (m / np.linalg.norm(m))


# -- selection ---------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["i", "a", "o", "f", "u", "m"])
def test_viseme_keyframes_are_neutral_frames_at_the_centre_of_their_visemes_phones(
        fitted, small_corpus, name):
    model, _, _ = fitted
    assert model.selection_[name]
    for utt_id, k in model.selection_[name]:
        utt = small_corpus[utt_id]
        assert utt.expression == "neutral"
        phone = PHONES[utt.phone_per_frame()[k]]
        assert viseme(phone) == name
        seg = next(s for s in utt.phones if s.start_s <= k / utt.fps < s.end_s)
        assert abs(k / utt.fps - 0.5 * (seg.start_s + seg.end_s)) <= 0.5 / utt.fps + 1e-9


def test_visemes_use_their_most_strongly_articulated_phones_first(small_corpus, fitted):
    _, units, defs = fitted
    model = KeyframeModel(min_samples=1).fit(small_corpus, units, deformations=defs)
    used = {n: {PHONES[small_corpus[u].phone_per_frame()[k]] for u, k in model.selection_[n]}
            for n in ("a", "u", "m", "f")}
    assert used["a"] == {"aa"}  # lip dominance 0.80, above ae/ay/aw (0.75) and ax (0.45)
    assert used["u"] <= {"uw", "w"}
    assert used["m"] <= set(BILABIALS) and used["f"] <= {"f", "v"}


@pytest.mark.parametrize("name", ["smile", "sad"])
def test_expression_keyframes_are_closed_mouth_frames_at_the_hold(fitted, small_corpus, name):
    model, units, defs = fitted
    sel = model.selection_[name]
    assert len(sel) >= model.min_samples
    for utt_id, k in sel:
        utt = small_corpus[utt_id]
        assert utt.expression == name
        t = _strength(units, defs[utt_id], name)
        assert t[k] >= model.hold_fraction * t.max()
        # the small corpus has enough silence + bilabial frames at the hold: the mouth is closed
        assert PHONES[utt.phone_per_frame()[k]] in {"sil"} | BILABIALS


def test_expression_keyframes_recover_the_generators_expression_fields(fitted, small_corpus):
    """The smile (sad) keyframe points along the generator's smile (sad) displacement field,
    and is closer to its own field than to the other expression's."""
    model, _, _ = fitted
    spk = make_speaker(0, Config().synth, small_corpus.info["seed"])
    fields = {k: v.ravel() for k, v in expression_fields(spk.neutral).items()}
    cos = lambda a, b: a @ b / np.linalg.norm(a) / np.linalg.norm(b)  # noqa: E731
    smile, sad = model.shapes_[KEYFRAMES.index("smile")], model.shapes_[KEYFRAMES.index("sad")]
    # measured with the default seed: 0.92 (smile), 0.85 (sad); default corpus 0.94, 0.93
    assert cos(smile, fields["smile"]) > 0.85
    assert cos(sad, fields["sad"]) > 0.75
    assert cos(smile, fields["smile"]) > cos(smile, fields["sad"]) + 0.5
    assert cos(sad, fields["sad"]) > cos(sad, fields["smile"]) + 0.5


def test_keyframes_are_medians_of_their_frames_and_K_is_well_conditioned(fitted):
    model, _, defs = fitted
    for i, name in enumerate(KEYFRAMES):
        frames = np.stack([defs[u][k] for u, k in model.selection_[name]])
        np.testing.assert_array_equal(model.shapes_[i], np.median(frames, axis=0))
    assert model.K.shape == (D, 8)
    assert model.condition_ < 1e3


# -- Eq. 4: exact properties -------------------------------------------------------------------
@given(b=arrays(np.float64, (5, 8), elements=st.floats(-3, 3)))
def test_weights_to_shapes_to_weights_is_the_identity(b, fitted):
    model, _, _ = fitted
    np.testing.assert_allclose(model.shapes_to_keyframes(model.keyframes_to_shapes(b)), b,
                               rtol=0, atol=1e-9)


def test_keyframe_weights_are_blend_weights(fitted):
    model, _, _ = fitted
    np.testing.assert_allclose(model.keyframes_to_shapes(np.eye(8)), model.shapes_, atol=1e-12)
    assert np.array_equal(model.keyframes_to_shapes(np.zeros((1, 8))), np.zeros((1, D)))


def test_the_keyframe_projection_is_idempotent(fitted, rng):
    model, _, defs = fitted
    d = np.concatenate([defs[k] for k in sorted(defs)[:3]] + [rng.normal(0, 3, (20, D))])
    once = model.keyframes_to_shapes(model.shapes_to_keyframes(d))
    twice = model.keyframes_to_shapes(model.shapes_to_keyframes(once))
    np.testing.assert_allclose(twice, once, rtol=0, atol=1e-9)
    # … and the projection residual is orthogonal to every keyframe (least squares)
    np.testing.assert_allclose((d - once) @ model.K, 0, atol=1e-8)


@pytest.mark.parametrize("expression", ["neutral", "smile", "sad"])
def test_weights_to_mups_follows_eq4_as_printed(fitted, rng, expression):
    """c_0 = M_0ᵀ(Kb − m_00) and c_k = α_k M_kᵀ(Kb − M_0 c_0 − m_00 − m_k0) — the same as
    projecting the shape Kb onto the MUs."""
    model, units, _ = fitted
    b = rng.normal(0, 1, (10, 8))
    np.testing.assert_allclose(model.keyframes_to_mups(b, expression),
                               units.transform(model.keyframes_to_shapes(b), expression),
                               rtol=0, atol=1e-10)


def test_neutral_round_trip_is_exact_when_the_keyframes_span_the_utterance_mus(fitted, rng):
    """Eq. 2 neutral shapes lie in span{m_00, M_0} (8 dimensions): 8 keyframes spanning it carry
    every neutral MUP exactly. Expressions need 10 dimensions, so there the loss is real."""
    _, units, _ = fitted
    shapes = units.mean_ + rng.normal(0, 5, (8, 7)) @ units.components_
    model = KeyframeModel.from_shapes(shapes, units)
    mups = np.hstack([rng.normal(0, 5, (30, 7)), np.zeros((30, 2))])
    back = model.keyframes_to_mups(model.mups_to_keyframes(mups, "neutral"), "neutral")
    np.testing.assert_allclose(back, mups, rtol=0, atol=1e-9)
    assert model.round_trip_error(mups, "neutral").pixel_max < 1e-9
    smile = np.hstack([mups[:, :7], rng.normal(0, 5, (30, 2))])
    assert model.round_trip_error(smile, "smile").pixel_rmse > 1e-3


# -- Eq. 4: the measured round-trip error on the small corpus ----------------------------------
# Measured with the default seed (pixels are per-marker distances between the Eq. 2 shapes):
#   neutral: RMS 0.146 px, max 0.59 px, MUPs 11.9 %, shape 8.2 %
#   smile:   RMS 0.177 px, max 0.78 px, MUPs  7.0 %, shape 6.5 %
#   sad:     RMS 0.169 px, max 0.75 px, MUPs 14.0 %, shape 9.1 %
# (default corpus: RMS 0.136 / 0.148 / 0.151 px, MUPs 10.6 / 5.4 / 11.9 %).
@pytest.mark.parametrize("expression", ["neutral", "smile", "sad"])
def test_mups_to_keyframes_to_mups_error_is_small_on_the_corpus(fitted, small_corpus,
                                                                 expression):
    model, units, defs = fitted
    mups = _mups_of(small_corpus, units, defs, expression)
    err = model.round_trip_error(mups, expression)
    assert err.n_frames == len(mups)
    assert err.pixel_rmse < 0.3, err
    assert err.pixel_max < 1.5, err
    assert err.mup_relative < 0.2, err
    assert err.shape_relative < 0.15, err
    assert err.pixel_rmse > 0.0  # 8 keyframes cannot carry 9 MUPs: the loss is reported, not hidden


# -- tracks ------------------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".json", ".csv"])
def test_tracks_round_trip_exactly(tmp_path, rng, suffix):
    w = rng.normal(0, 1, (47, 8)) * 10.0 ** rng.integers(-8, 3, (47, 8))
    path = write_keyframe_tracks(tmp_path / f"utt{suffix}", w, 30, expression="smile",
                                 source="test")
    tracks = read_keyframe_tracks(path)
    assert np.array_equal(tracks.weights, w)
    assert tracks.fps == 30 and tracks.weights.shape == (47, len(KEYFRAMES))
    np.testing.assert_allclose(tracks.times, np.arange(47) / 30)
    if suffix == ".json":
        assert (tracks.expression, tracks.source) == ("smile", "test")
        doc = json.loads(path.read_text())
        assert doc["format"] == "talkingface.keyframe_tracks" and doc["version"] == 1
        assert doc["frames"][1]["time_s"] == pytest.approx(1 / 30)


def test_csv_columns_may_come_in_any_order(tmp_path, rng):
    w = rng.normal(0, 1, (4, 8))
    order = list(reversed(range(8)))
    lines = ["time_s," + ",".join(KEYFRAMES[j] for j in order)]
    lines += [f"{k / 30!r}," + ",".join(repr(float(w[k, j])) for j in order) for k in range(4)]
    (tmp_path / "rev.csv").write_text("\n".join(lines) + "\n")
    assert np.array_equal(read_keyframe_tracks(tmp_path / "rev.csv").weights, w)


def _corrupt(path, old, new):
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


@pytest.mark.parametrize("suffix, old, new, problem", [
    (".json", '"talkingface.keyframe_tracks"', '"something.else"', "not keyframe tracks"),
    (".json", '"version": 1', '"version": 2', "not keyframe tracks"),
    (".json", "0.25", "NaN", "non-finite weight at frame 0, keyframe 'smile'"),
    (".json", '"o"', '"oh"', r"unknown keyframe names \['oh'\]"),
    (".json", '"u"', '"o"', "once each"),
    (".csv", "0.25", "nan", "non-finite weight at frame 0"),
    (".csv", ",o,", ",oh,", r"unknown keyframe names \['oh'\]"),
    (".csv", "\n0.03333333333333333,", "\n0.05,", "frame 1 is at 0.05 s"),
    (".csv", "time_s,", "t,", "header must start with 'time_s'"),
])
def test_corrupted_tracks_raise_naming_the_file_and_problem(tmp_path, suffix, old, new, problem):
    w = np.full((3, 8), 0.5)
    w[0, 0] = 0.25
    path = write_keyframe_tracks(tmp_path / f"bad_tracks{suffix}", w, 30, expression="sad",
                                 source="t")
    _corrupt(path, old, new)
    with pytest.raises(ParameterError, match=re.escape(str(path)) + ".*" + problem):
        read_keyframe_tracks(path)


def test_non_monotonic_json_times_and_short_rows_are_refused(tmp_path):
    path = write_keyframe_tracks(tmp_path / "t.json", np.zeros((3, 8)), 30, expression="neutral",
                                 source="t")
    doc = json.loads(path.read_text())
    doc["frames"][1]["time_s"], doc["frames"][2]["time_s"] = 2 / 30, 1 / 30
    path.write_text(json.dumps(doc))
    with pytest.raises(ParameterError, match=r"t\.json.*steps of 1/fps.*frame 1"):
        read_keyframe_tracks(path)
    doc = json.loads(path.read_text())
    doc["frames"][1]["time_s"], doc["frames"][2]["time_s"] = 1 / 30, 2 / 30
    doc["frames"][2]["weights"] = [0.0] * 7
    path.write_text(json.dumps(doc))
    with pytest.raises(ParameterError, match=r"t\.json: frame 2 has 7 weights, expected 8"):
        read_keyframe_tracks(path)
    path.write_text("{not json")
    with pytest.raises(ParameterError, match=r"t\.json: malformed"):
        read_keyframe_tracks(path)


def test_writing_bad_tracks_is_refused(tmp_path):
    with pytest.raises(ParameterError, match=r"shape \(n_frames, 8\), got \(3, 9\)"):
        write_keyframe_tracks(tmp_path / "a.json", np.zeros((3, 9)), expression="sad", source="")
    with pytest.raises(ParameterError, match="NaN"):
        write_keyframe_tracks(tmp_path / "a.json", np.full((3, 8), np.nan), expression="sad",
                              source="")
    with pytest.raises(ParameterError, match=r"\.json or \.csv, not '\.txt'"):
        write_keyframe_tracks(tmp_path / "a.txt", np.zeros((3, 8)), expression="sad", source="")
    with pytest.raises(ParameterError, match="fps must be a positive number"):
        write_keyframe_tracks(tmp_path / "a.csv", np.zeros((3, 8)), 0, expression="sad",
                              source="")


# -- persistence and errors --------------------------------------------------------------------
def test_save_load_rebuilds_the_same_conversion(fitted, small_corpus, tmp_path):
    model, units, defs = fitted
    path = model.save(tmp_path / "keyframes.npz")
    loaded = KeyframeModel.load(path)
    assert loaded.selection_ == model.selection_
    assert np.array_equal(loaded.shapes_, model.shapes_)
    assert (loaded.min_samples, loaded.hold_fraction) == (model.min_samples, model.hold_fraction)
    mups = _mups_of(small_corpus, units, defs, "smile")
    b = model.mups_to_keyframes(mups, "smile")
    assert np.array_equal(loaded.mups_to_keyframes(mups, "smile"), b)
    assert np.array_equal(loaded.keyframes_to_mups(b, "smile"), model.keyframes_to_mups(b, "smile"))
    units.save(tmp_path / "units.npz")
    with pytest.raises(ParameterError, match="units.npz: not a keyframe model"):
        KeyframeModel.load(tmp_path / "units.npz")
    with pytest.raises(ParameterError, match="not found"):
        KeyframeModel.load(tmp_path / "missing.npz")


def test_the_model_file_stores_its_motion_units_as_the_units_file_does(fitted, tmp_path):
    """The Motion Units inside keyframes.npz are their :meth:`MotionUnits.to_arrays` record:
    the same arrays (names prefixed ``mu_``) and metadata as motion_units.npz."""
    model, units, _ = fitted
    path = model.save(tmp_path / "keyframes.npz")
    arrays, meta = units.to_arrays()
    with np.load(path, allow_pickle=False) as z:
        stored = json.loads(str(z["metadata"]))
        assert (stored["kind"], stored["version"]) == ("keyframes", 3) and "format" not in stored
        assert stored["units"] == meta
        assert set(z.files) == {"metadata", "shapes", *(f"mu_{n}" for n in arrays)}
        for name, value in arrays.items():
            assert np.array_equal(z[f"mu_{name}"], value)
    loaded = KeyframeModel.load(path).units_
    again, again_meta = loaded.to_arrays()
    assert again_meta == meta and all(np.array_equal(again[n], arrays[n]) for n in arrays)
    assert loaded.metadata_ == {**units.metadata_, "layout_version": meta["layout_version"]}
    # an older version, and a file whose Motion Units lost an array, are refused by name
    record = {k: v for k, v in stored.items() if k not in ("kind", "version", "arrays", "sha256")}
    old = tmp_path / "old.npz"
    np.savez(old, metadata=np.array(json.dumps({**record, "format": "talkingface.keyframes/1"})),
             shapes=model.shapes_)
    with pytest.raises(ParameterError, match=r"old\.npz: not a keyframe model of this version "
                                             r"\(format 'talkingface\.keyframes/1', expected "
                                             r"'talkingface\.keyframes/2' or kind 'keyframes' "
                                             r"version 3\)$"):
        KeyframeModel.load(old)
    broken = tmp_path / "broken.npz"
    np.savez(broken, metadata=np.array(json.dumps({**record,
                                                   "format": "talkingface.keyframes/2"})),
             shapes=model.shapes_, **{f"mu_{n}": v for n, v in arrays.items() if n != "smile__mean"})
    with pytest.raises(ParameterError, match=r"broken\.npz \(its Motion Units\): Motion Units "
                                             r"arrays smile__mean are missing"):
        KeyframeModel.load(broken)


def _save_version_2(model: KeyframeModel, path):
    """``model`` as the version-2 code saved it: np.savez, ``format`` in the metadata, no kind
    and no checksum."""
    unit_arrays, unit_meta = model.units_.to_arrays()
    meta = {"format": "talkingface.keyframes/2", "keyframes": list(KEYFRAMES),
            "min_samples": int(model.min_samples), "hold_fraction": float(model.hold_fraction),
            "selection": {k: [[a, int(f)] for a, f in v] for k, v in model.selection_.items()},
            "units": unit_meta}
    with open(path, "wb") as f:
        np.savez(f, metadata=np.array(json.dumps(meta, sort_keys=True)), shapes=model.shapes_,
                 **{f"mu_{n}": x for n, x in unit_arrays.items()})
    return path


def test_a_version_2_file_loads_as_the_same_model(fitted, small_corpus, tmp_path):
    model, units, defs = fitted
    old = KeyframeModel.load(_save_version_2(model, tmp_path / "old.npz"))
    assert old.selection_ == model.selection_
    assert (old.min_samples, old.hold_fraction) == (model.min_samples, model.hold_fraction)
    assert old.shapes_.tobytes() == model.shapes_.tobytes()
    assert old.pinv_.tobytes() == model.pinv_.tobytes()
    assert old.units_.metadata_ == {**units.metadata_, "layout_version": "hwh79-1"}
    for e in ("neutral", "smile", "sad"):
        mups = _mups_of(small_corpus, units, defs, e)
        b = model.mups_to_keyframes(mups, e)
        assert old.mups_to_keyframes(mups, e).tobytes() == b.tobytes()
        assert old.keyframes_to_mups(b, e).tobytes() == model.keyframes_to_mups(b, e).tobytes()
    # saved again, it is a version-3 file of the same arrays
    with np.load(old.save(tmp_path / "new.npz")) as z, np.load(tmp_path / "old.npz") as y:
        assert json.loads(str(z["metadata"]))["version"] == 3
        assert set(z.files) == set(y.files)
        assert all(z[n].tobytes() == y[n].tobytes() for n in z.files if n != "metadata")


def test_a_damaged_keyframe_model_is_one_line_naming_it(fitted, tmp_path):
    model, _, _ = fitted
    path = model.save(tmp_path / "keyframes.npz")
    members = dict(np.load(path, allow_pickle=False))
    members["shapes"] = members["shapes"][::-1].copy()  # consistent zip, other numbers
    bad = tmp_path / "bad.npz"
    with open(bad, "wb") as f:
        np.savez(f, **members)
    with pytest.raises(ParameterError, match=r"bad\.npz: checksum mismatch: the file is not the "
                                             r"one saved"):
        KeyframeModel.load(bad)
    evil = tmp_path / "evil.npz"
    payload = np.empty(1, dtype=object)
    with open(evil, "wb") as f:
        np.savez(f, allow_pickle=True, **{**members, "shapes": payload})
    with pytest.raises(ParameterError, match=r"evil\.npz: array 'shapes' holds pickled Python "
                                             r"objects"):
        KeyframeModel.load(evil)


def test_invalid_inputs_raise_helpful_errors(fitted):
    model, _, _ = fitted
    with pytest.raises(ParameterError, match=r"MUPs \(A_0 \+ A_k columns\) must have "
                       r"shape \(n_frames, 9\), got \(4, 7\)"):
        model.mups_to_keyframes(np.zeros((4, 7)), "neutral")
    with pytest.raises(ParameterError, match="expression 'angry' is unknown; allowed: neutral, "):
        model.mups_to_keyframes(np.zeros((4, 9)), "angry")
    with pytest.raises(ParameterError, match="expression 'happy'"):
        model.keyframes_to_mups(np.zeros((4, 8)), "happy")
    with pytest.raises(ParameterError, match=r"weights must have shape \(n_frames, 8\)"):
        model.keyframes_to_mups(np.zeros((4, 9)))
    with pytest.raises(ParameterError, match="NaN"):
        model.mups_to_keyframes(np.full((2, 9), np.nan))
    with pytest.raises(ParameterError, match=r"deformations must have shape \(n_frames, 158\)"):
        model.shapes_to_keyframes(np.zeros((2, 79, 2)))
    with pytest.raises(NotFittedError, match="fit"):
        KeyframeModel().mups_to_keyframes(np.zeros((1, 9)))
    with pytest.raises(ParameterError, match="linearly dependent"):
        KeyframeModel.from_shapes(np.ones((8, D)), model.units_)


def test_fit_refuses_units_without_expressions_and_bad_settings(small_corpus, fitted):
    _, units, defs = fitted
    neutral_only = MotionUnits().fit({"neutral": np.concatenate(
        [defs[u.utt_id] for u in small_corpus.by_expression("neutral")])})
    with pytest.raises(ParameterError, match="no smile or sad MUs"):
        KeyframeModel().fit(small_corpus, neutral_only, deformations=defs)
    with pytest.raises(ParameterError, match="hold_fraction must be in"):
        KeyframeModel(hold_fraction=1.5).fit(small_corpus, units, deformations=defs)
    short = dict(defs)
    first = small_corpus.utterances[0].utt_id
    short[first] = short[first][:-1]
    with pytest.raises(ParameterError, match=f"deformations for {first} must have shape"):
        KeyframeModel().fit(small_corpus, units, deformations=short)
