"""Simulated participants (study.simulate): the expression classifier, the FLMP observers and the
simulated study written through the data contract."""
from __future__ import annotations

import csv
import dataclasses
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from face_model.alignment import align_markers
from face_model.corpus import Corpus
from groundwork.errors import ParameterError
from study.classifier import classifier_corpus, observer_classifier
from study.data import N_TRIALS, Allocation, data_path, sidecar_path
from study.design import (
    AUDIO,
    EXPRESSIONS,
    FACES,
    RESPONSES,
    Trial,
    required_stimuli,
    stimulus_id,
)
from study.simulate import (
    EMOTIONS,
    EXPRESSION_EMOTION,
    RESPONDER_MODEL,
    ExpressionClassifier,
    FLMPObserver,
    ObserverParams,
    simulate_study,
    visual_evidence,
)
from study.stimuli import Stimulus

HELD_OUT = 3  # sentence index kept out of the classifier's training


def _held_out(u) -> bool:
    return u.utt_id.endswith(f"_{HELD_OUT:03d}")


@pytest.fixture(scope="module")
def classifier(small_corpus):
    """Trained on sentences 0-2 (all three expressions) of the small corpus."""
    train = Corpus(small_corpus.root, small_corpus.info,
                   [u for u in small_corpus.utterances if not _held_out(u)])
    return ExpressionClassifier().fit(train, seed=11)


@pytest.fixture(scope="module")
def make_stimuli(small_corpus, classifier, tmp_path_factory):
    """``make_stimuli(shrink)``: a stimulus set built from the held-out sentence. The real face is
    the aligned corpus markers; the synthetic face is the same trajectory with its deformation
    from the classifier's neutral face scaled by ``shrink`` (1.0: identical to the real face).
    Videos are not needed (only markers are read): video/wav point at an existing corpus file."""
    root = tmp_path_factory.mktemp("stimuli")
    held = {u.expression: u for u in small_corpus.utterances if _held_out(u)}
    any_file = Path(small_corpus.root) / "manifest.csv"

    def make(shrink: float) -> dict:
        out = {}
        for e in EXPRESSIONS:
            real = align_markers(held[e].markers)
            synth = classifier.neutral_ + shrink * (real - classifier.neutral_)
            for face, m in (("real", real), ("synthetic", synth)):
                path = root / f"{face}-{e}-x{shrink}.npy"
                np.save(path, m.astype(np.float32), allow_pickle=False)
                for a in AUDIO:
                    sid = stimulus_id(face, e, a)
                    out[sid] = Stimulus(sid, "video", face, e, a, any_file, any_file, path,
                                        len(m), 30, len(m) / 30, {})
        for a in AUDIO:
            sid = stimulus_id("none", "none", a)
            out[sid] = Stimulus(sid, "audio", "none", "none", a, None, any_file, None, 30, 30,
                                1.0, {})
        assert sorted(out) == sorted(required_stimuli())
        return out

    return make


def _rows(summary) -> list[dict]:
    rows = []
    for path in summary["data"]:
        with open(path, newline="") as f:
            rows.extend(csv.DictReader(f))
    return rows


def test_classifier_recovers_held_out_expressions(small_corpus, classifier):
    for u in small_corpus.utterances:
        if not _held_out(u):
            continue
        for markers in (u.markers, align_markers(u.markers)):  # raw and already aligned
            p = classifier.predict_proba(markers)
            assert p.shape == (3,)
            assert np.all(p >= 0) and p.sum() == pytest.approx(1.0)
            assert EXPRESSIONS[int(np.argmax(p))] == u.expression, (u.utt_id, p)


def test_same_seed_same_files_other_seed_differs(make_stimuli, classifier, tmp_path):
    stimuli = make_stimuli(1.0)
    runs = {name: simulate_study(tmp_path / name, stimuli, classifier, n=4, seed=s,
                                 study_seed=99)
            for name, s in (("a", 5), ("b", 5), ("c", 6))}
    a, b, c = runs["a"], runs["b"], runs["c"]
    assert a["participants"] == ["SIM01", "SIM02", "SIM03", "SIM04"]
    assert a["sequences"] == {"SR": 2, "RS": 2}
    for pid in a["participants"]:
        assert data_path(tmp_path / "a", pid).read_bytes() == \
            data_path(tmp_path / "b", pid).read_bytes()
        assert sidecar_path(tmp_path / "a", pid).read_bytes() == \
            sidecar_path(tmp_path / "b", pid).read_bytes()
    rows_a, rows_c = _rows(a), _rows(c)
    assert len(rows_a) == 4 * N_TRIALS
    assert all(r["simulated"] == "true" and r["responder_model"] == RESPONDER_MODEL
               and r["response"] in RESPONSES and float(r["rt_s"]) > 0 and r["timestamp"] == ""
               for r in rows_a)
    # the design (trial order) depends on study_seed only; the answers on seed
    assert [r["stimulus_id"] for r in rows_a] == [r["stimulus_id"] for r in rows_c]
    assert [(r["response"], r["rt_s"]) for r in rows_a] != \
        [(r["response"], r["rt_s"]) for r in rows_c]
    # nothing is ever overwritten: a second run into the same folder is refused, files unchanged
    before = {p: p.read_bytes() for p in a["data"]}
    with pytest.raises(ParameterError, match="never overwritten"):
        simulate_study(tmp_path / "a", stimuli, classifier, n=4, seed=5, study_seed=99)
    assert {p: p.read_bytes() for p in a["data"]} == before


def test_identical_faces_give_matching_tallies(make_stimuli, classifier, tmp_path):
    stimuli = make_stimuli(1.0)
    visual = visual_evidence(classifier, stimuli)
    for e in EXPRESSIONS:
        for a in AUDIO:
            assert np.array_equal(visual[stimulus_id("synthetic", e, a)],
                                  visual[stimulus_id("real", e, a)])
    n = 40
    rows = _rows(simulate_study(tmp_path / "s", stimuli, classifier, n=n, seed=3, study_seed=4))
    tally = Counter((r["face"], r["block"], r["expression"], r["audio"], r["response"])
                    for r in rows if r["face"] != "none")
    cells = {(b, e, a) for (_, b, e, a, _) in tally}
    assert len(cells) == 3 + 9  # visual-only cells and bimodal cells
    for b, e, a in cells:
        for resp in RESPONSES:
            s, r = tally[("synthetic", b, e, a, resp)], tally[("real", b, e, a, resp)]
            # S - R sums n paired differences of Bernoulli answers with equal probabilities, so
            # its variance is at most 2 n p(1-p) (p the pooled rate). 4 sd (+1 for
            # discreteness) bounds each of the 48 comparisons at ~6e-5 under the
            # normal approximation (all together < 0.5 %).
            p = (s + r) / (2 * n)
            assert abs(s - r) <= 4 * np.sqrt(2 * n * p * (1 - p)) + 1, (b, e, a, resp, s, r)


def test_degraded_synthetic_face_is_recognised_less(make_stimuli, classifier, tmp_path):
    rows = _rows(simulate_study(tmp_path / "s", make_stimuli(0.2), classifier, n=20, seed=8,
                                study_seed=9))
    visual_rows = [r for r in rows if r["block"] == "visual" and r["expression"] != "neutral"]

    def accuracy(face):
        hits = [r["response"] == EXPRESSION_EMOTION[r["expression"]]
                for r in visual_rows if r["face"] == face]
        assert len(hits) == 2 * 20
        return np.mean(hits)

    assert accuracy("real") > 0.6
    assert accuracy("synthetic") < accuracy("real") - 0.3


def test_video_without_markers_is_refused(make_stimuli, classifier, tmp_path):
    stimuli = make_stimuli(1.0)
    sid = "synthetic-sad-good"
    stimuli[sid] = dataclasses.replace(stimuli[sid], markers=None)
    with pytest.raises(ParameterError, match=sid) as err:
        visual_evidence(classifier, stimuli)
    assert "simulated participants need" in str(err.value)
    with pytest.raises(ParameterError, match=sid):
        simulate_study(tmp_path / "s", stimuli, classifier, n=2, seed=1, study_seed=1)
    assert not (tmp_path / "s").exists()  # refused before anything was written


_probs = st.lists(st.floats(0.001, 1.0), min_size=3, max_size=3).map(np.array)


@given(v=_probs, gamma=st.floats(0.2, 5.0), rho=st.floats(0.0, 1.0),
       audio=st.sampled_from(AUDIO), seed=st.integers(0, 2**32))
def test_flmp_posterior_and_answers(v, gamma, rho, audio, seed):
    params = ObserverParams(visual_sensitivity=gamma, content_reliance=rho,
                            not_sure_threshold=0.5, not_sure_slope=0.03, lapse_rate=0.02,
                            rt_median_s=1.0, rt_uncertainty_slowing=0.4, rt_log_sd=0.3)
    obs = FLMPObserver(params, seed)
    visual = {"real-smile-normal": v, "real-smile-" + audio: v}
    vis = Trial("visual", 0, 0, "real", "smile", "none", "real-smile-normal")
    aud = Trial("audio", 0, 1, "none", "none", audio, f"audio-{audio}")
    bim = Trial("bimodal", 1, 2, "real", "smile", audio, "real-smile-" + audio)
    pv, pa, pb = (obs.posterior(t, visual) for t in (vis, aud, bim))
    for p in (pv, pa, pb):
        assert p.sum() == pytest.approx(1.0) and np.all(p >= 0)
    # FLMP: the bimodal posterior is the normalised product of the unimodal ones
    prod = pv * pa
    np.testing.assert_allclose(pb, prod / prod.sum(), rtol=1e-9, atol=1e-12)
    if rho == 0.0:  # words that carry nothing leave the face alone
        np.testing.assert_allclose(pb, pv, rtol=1e-9, atol=1e-12)
    target = EMOTIONS.index({"normal": "neutral", "good": "happy", "bad": "sad"}[audio])
    assert pa[target] == pa.max()
    response, rt = obs.respond(bim, visual)
    assert response in RESPONSES and rt > 0


# --- the observers' classifier of a stimulus set (study.classifier.observer_classifier) -------
def test_classifier_corpus_prefers_the_runs_corpus(small_corpus_dir, tmp_path):
    stim = tmp_path / "run" / "stimuli"
    stim.mkdir(parents=True)
    with pytest.raises(ParameterError, match=r"no corpus to train the observers' expression "
                                             r"classifier: neither .*run/corpus nor "
                                             r".*stimuli/source exists"):
        classifier_corpus(stim)
    (stim / "source").symlink_to(small_corpus_dir)  # the stimuli's own source sentences
    assert classifier_corpus(stim) == stim / "source"
    (tmp_path / "run" / "corpus").symlink_to(small_corpus_dir)  # the run's corpus comes first
    assert classifier_corpus(str(stim)) == tmp_path / "run" / "corpus"


def test_observer_classifier_is_the_default_classifier_on_that_corpus(small_corpus,
                                                                      small_corpus_dir,
                                                                      tmp_path):
    stim = tmp_path / "stimuli"
    stim.mkdir()
    (stim / "source").symlink_to(small_corpus_dir)
    clf = observer_classifier(stim, seed=5)
    ref = ExpressionClassifier().fit(small_corpus, seed=5)
    assert clf.describe() == ref.describe()
    m = small_corpus.utterances[0].markers
    np.testing.assert_array_equal(clf.predict_frames(m), ref.predict_frames(m))


# --- an interrupted simulation is resumed: the folder ends up as an uninterrupted run's --------
def _interrupt_after(monkeypatch, k: int, *, torn: bool):
    """Interrupt the simulation at the ``k``-th judgment it writes (a kill in the middle of
    writing that row when ``torn``: half of it reaches the file)."""
    from study.data import SessionFile

    append, calls = SessionFile.append, []

    def interrupted(self, row):
        calls.append(row)
        if len(calls) == k:
            if torn:
                append(self, row)
                data = self.path.read_bytes()
                cut = data.rfind(b"\n", 0, len(data) - 1) + 1
                self.path.write_bytes(data[:cut + (len(data) - cut) // 2])
            raise KeyboardInterrupt
        return append(self, row)

    monkeypatch.setattr(SessionFile, "append", interrupted)


def _slots(study):
    return [(r["slot"], r["sequence"], r["participant_id"], r["status"])
            for r in Allocation(study).rows()]


def _files(study):
    return {q.relative_to(study): q.read_bytes() for q in sorted(study.rglob("*"))
            if q.is_file() and not q.name.startswith(".") and not q.name.startswith("allocation")}


@pytest.mark.parametrize("where", ["mid-row", "between participants", "before the status"])
def test_an_interrupted_simulation_resumes_to_the_uninterrupted_files(
        make_stimuli, classifier, tmp_path, monkeypatch, where):
    stimuli = make_stimuli(1.0)
    kw = dict(n=4, seed=5, study_seed=99)
    whole = simulate_study(tmp_path / "whole", stimuli, classifier, **kw)
    study = tmp_path / "cut"
    with monkeypatch.context() as m:
        if where == "mid-row":  # SIM03's 11th judgment half written
            _interrupt_after(m, 2 * N_TRIALS + 11, torn=True)
        elif where == "between participants":  # SIM02 holds its slot, nothing written yet
            _interrupt_after(m, N_TRIALS + 1, torn=False)
        else:  # SIM02's files complete, its slot not yet marked complete
            set_status = Allocation.set_status
            m.setattr(Allocation, "set_status", lambda self, pid, status: (
                (_ for _ in ()).throw(KeyboardInterrupt) if pid == "SIM02"
                else set_status(self, pid, status)))
        with pytest.raises(KeyboardInterrupt):
            simulate_study(study, stimuli, classifier, **kw)
    before = _files(study)
    assert before != _files(tmp_path / "whole")
    res = simulate_study(study, stimuli, classifier, progress=True, **kw)
    assert _files(study) == _files(tmp_path / "whole")  # byte for byte
    assert _slots(study) == _slots(tmp_path / "whole")
    assert res["sequences"] == whole["sequences"] and res["participants"] == whole["participants"]
    kept = {"mid-row": ["SIM01", "SIM02"], "between participants": ["SIM01"],
            "before the status": ["SIM01"]}[where]
    assert res["kept"] == kept
    assert res["resumed"] == {"mid-row": ["SIM03"], "between participants": ["SIM02"],
                              "before the status": ["SIM02"]}[where]
    for q, data in before.items():  # nothing written before the interruption was rewritten
        if q.name != f"{q.parent.name}_task-emotion_beh.csv" or q.parent.name[4:] in kept:
            assert (study / q).read_bytes() == data


def test_a_simulation_is_resumed_only_with_its_own_settings(make_stimuli, classifier,
                                                            tmp_path, monkeypatch):
    stimuli = make_stimuli(1.0)
    study = tmp_path / "s"
    with monkeypatch.context() as m:
        _interrupt_after(m, N_TRIALS + 5, torn=False)
        with pytest.raises(KeyboardInterrupt):
            simulate_study(study, stimuli, classifier, n=3, seed=5, study_seed=99)
    files = {q: q.read_bytes() for q in study.rglob("*") if q.is_file()}
    with pytest.raises(ParameterError, match=r"sub-SIM01_task-emotion_beh\.csv is not what this "
                                             r"simulation writes"):
        simulate_study(study, stimuli, classifier, n=3, seed=6, study_seed=99)
    with pytest.raises(ParameterError, match=r"allocation list \(n=3, seed=99\), not the one "
                                             r"of this simulation \(n=4"):
        simulate_study(study, stimuli, classifier, n=4, seed=5, study_seed=99)
    assert {q: q.read_bytes() for q in study.rglob("*") if q.is_file()} == files
    res = simulate_study(study, stimuli, classifier, n=3, seed=5, study_seed=99)
    assert (res["kept"], res["resumed"]) == (["SIM01"], ["SIM02"])


def test_the_progress_bar_counts_participants(make_stimuli, classifier, tmp_path, capsys):
    simulate_study(tmp_path / "s", make_stimuli(1.0), classifier, n=3, seed=1, study_seed=2,
                   progress=True)
    err = capsys.readouterr().err
    assert "simulated participants" in err and "3/3" in err


def test_each_participant_is_drawn_alone_as_in_the_whole_population():
    """A study of a million participants starts at once: participant i is drawn when it is
    simulated (child i of the seed), with the same parameters as from the whole population."""
    from study.simulate import make_observer, make_observers

    whole = make_observers(8, 2002)
    for i in (0, 3, 7):
        alone = make_observer(i, 2002)
        assert alone.seed == whole[i].seed and alone.params == whole[i].params
    assert make_observer(999_999, 2002).seed != whole[0].seed
