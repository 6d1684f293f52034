"""Teaching the causal front end (issue 40): hama's targets are its spikes' class mass read
with its own timing rule, the Teacher job fits the hearing pass and its cache, the numpy
forward pass is torch's, training recovers a known mapping the same way twice, and bad
settings are refused by name."""
import pickle

import numpy as np
import pytest
import torch

from analysis.speech_set import load_speech_set
from face_model.phones import PHONE_INDEX
from groundwork.cache import ArrayCache
from groundwork.errors import ParameterError
from groundwork.settings import SettingError
from mapping import front_net, front_training, hama_front
from mapping.causal_front import CausalStream
from mapping.front_net import make_front, random_front
from mapping.front_training import (FrontExample, FrontSettings, Teacher, cached_targets,
                                    class_mass, teacher_rows, teacher_targets, torch_net,
                                    train_front)
from mapping.hama_front import assigned_spikes
from mapping.hearing import hear_all
from mapping.recogniser import HEARD_KIND, hearing_cache

SIL, P, AA, S = (PHONE_INDEX[p] for p in ("sil", "p", "aa", "s"))


# -- the numpy net is torch's ---------------------------------------------------------------------

@pytest.mark.parametrize("lookahead_ms", [0, 50, 100])
def test_the_numpy_forward_pass_is_torchs(lookahead_ms):
    arrays, metadata = random_front(3, n_mels=40, hidden=24, lookahead_ms=lookahead_ms)
    front = make_front(arrays, metadata)
    x = np.random.default_rng(0).standard_normal((57, 40)).astype(np.float32)
    state = front.new_state()  # in three pieces: the state carries the context
    got = np.concatenate([front.forward(x[:10], state), front.forward(x[10:11], state),
                          front.forward(x[11:], state)])
    with torch.no_grad():
        want = torch_net(arrays, metadata)(torch.from_numpy(x)[None])[0].numpy()
    assert got.shape == want.shape == (57, lookahead_ms // 10 + 1, 44)
    np.testing.assert_allclose(got, want, atol=1e-4)


# -- the teacher's targets ------------------------------------------------------------------------

CLASSES = np.array([P, AA, AA, -1, -1])  # tokens: p, a, ɑ, a word boundary, the blank
BLANK = 4


def handmade(n_out=40):
    """Log posteriors (n_out, 5): blanks, a spike of p at 10 (held at 11: no new spike), of
    ɑ at 16, a word boundary at 30 (no spike) and p at 38."""
    p = np.tile([0.025, 0.025, 0.025, 0.025, 0.9], (n_out, 1))
    p[10] = p[11] = [0.5, 0.1, 0.1, 0.1, 0.2]
    p[16] = [0.05, 0.3, 0.35, 0.1, 0.2]
    p[30] = [0.1, 0.1, 0.1, 0.5, 0.2]
    p[38] = [0.6, 0.1, 0.05, 0.05, 0.2]
    return np.log(p).astype(np.float32)


def rows(spec, n):
    out = np.zeros((n, 44), np.float32)
    out[:, SIL] = 1
    for first, last, mass in spec:
        out[first:last + 1] = 0
        for c, v in mass.items():
            out[first:last + 1, c] = v
    return out


def test_hand_made_spikes_give_exact_target_rows():
    lp = handmade()
    np.testing.assert_array_equal(
        assigned_spikes(lp, CLASSES, BLANK, reach=3, boundary=0.5),
        np.r_[[-1] * 7, [10] * 7, [16] * 6, [-1] * 15, [38] * 5])
    timing = hama_front.Timing(lag=0, reach=3, boundary=0.5, edge=True)
    # step s reads output frame s // 2; steps 80.. lie past the decode: silence
    want = rows([(14, 27, {P: 5 / 7, AA: 2 / 7}), (28, 39, {P: 1 / 14, AA: 13 / 14}),
                 (70, 79, {P: 0.6 / 0.75, AA: 0.15 / 0.75})], 84)
    np.testing.assert_allclose(teacher_rows(lp, 0, 84, CLASSES, BLANK, timing), want,
                               atol=1e-6)
    # with a lag of one frame, steps reading past the end read the last frame (the edge rule)
    lagged = hama_front.Timing(lag=1, reach=3, boundary=0.5, edge=True)
    want = rows([(12, 25, {P: 5 / 7, AA: 2 / 7}), (26, 37, {P: 1 / 14, AA: 13 / 14}),
                 (68, 79, {P: 0.6 / 0.75, AA: 0.15 / 0.75})], 84)
    np.testing.assert_allclose(teacher_rows(lp, 0, 84, CLASSES, BLANK, lagged), want,
                               atol=1e-6)
    # padding rows are dropped; no posteriors at all is silence
    np.testing.assert_allclose(teacher_rows(np.concatenate([lp[:5], lp]), 5, 84, CLASSES,
                                            BLANK, timing),
                               teacher_rows(lp, 0, 84, CLASSES, BLANK, timing), atol=1e-7)
    np.testing.assert_array_equal(teacher_rows(None, 3, 5, CLASSES, BLANK), rows([], 5))


def test_teacher_targets_read_hamas_whole_decode(monkeypatch):
    lp = handmade(50)
    seen = []

    def log_posteriors(x):
        seen.append(len(x))
        return lp

    monkeypatch.setattr(hama_front, "log_posteriors", log_posteriors)
    monkeypatch.setattr(hama_front, "model", lambda: (None, CLASSES, BLANK))
    y = np.zeros(16000, np.float32)  # one second: no padding
    got = teacher_targets(y)
    assert seen == [16000] and got.shape == (front_net.n_steps(16000), 44) == (101, 44)
    np.testing.assert_array_equal(got, teacher_rows(lp, 0, 101, CLASSES, BLANK))


@pytest.fixture(scope="module")
def a0009():
    item = load_speech_set(ids=["slt_a0009"])[0]
    assert item.sr == 16000
    return item.audio.astype(np.float32)


@pytest.mark.parametrize("seconds", [None, 0.6])  # whole (3.1 s), and short: padded to 1 s
def test_targets_of_a_real_recording_are_hamas_spike_mass(a0009, seconds):
    y = a0009 if seconds is None else a0009[int(0.1 * 16000):int((0.1 + seconds) * 16000)]
    lp, pad = hama_front.whole_posteriors(y)
    assert (pad > 0) == (seconds is not None)
    _, classes, blank = hama_front.model()
    got = teacher_targets(y)
    n = front_net.n_steps(len(y))
    assert got.shape == (n, 44)
    np.testing.assert_allclose(got.sum(axis=1), 1.0, atol=1e-5)
    # the spikes assigned are output_classes' own
    spike = assigned_spikes(lp, classes, blank)
    best = lp.argmax(axis=1)
    np.testing.assert_array_equal(np.where(spike >= 0, classes[best[spike]], SIL),
                                  hama_front.output_classes(lp))
    # each step's row is the class mass of the spike its output frame belongs to
    checked = 0
    timing, n_out = hama_front.Timing(), len(lp) - pad  # the committed lag and edge rule
    for s in range(n):
        g0 = s // 2
        g = g0 + timing.lag
        f = g if g < n_out else (n_out - 1 if timing.edge and g0 < n_out else None)
        if f is None or spike[pad + f] < 0:
            np.testing.assert_array_equal(got[s], np.eye(44)[SIL])
            continue
        p = np.exp(lp[spike[pad + f]].astype(np.float64))
        mass = np.zeros(44)
        np.add.at(mass, classes[classes >= 0], p[classes >= 0])
        np.testing.assert_allclose(got[s], mass / mass.sum(), atol=1e-6)
        checked += 1
    assert checked > n / 2  # most of the recording is speech
    np.testing.assert_allclose(class_mass(lp[:3], classes).sum(axis=1), 1.0)


def test_the_teacher_job_round_trips_through_the_cache(a0009, tmp_path):
    y = a0009[:16000]
    job = pickle.loads(pickle.dumps(Teacher(y)))  # a spawned worker gets it pickled
    assert job.key() == Teacher(y.copy()).key() != Teacher(y[:-1]).key()
    cache = ArrayCache(tmp_path)
    assert hear_all([job], cache, workers=1, progress=False).as_dict() == {"heard": 1,
                                                                             "reused": 0}
    assert hear_all([Teacher(y)], cache, progress=False).as_dict() == {"heard": 0, "reused": 1}
    entry = ArrayCache(tmp_path).get(HEARD_KIND, job.key())["targets"]
    assert entry.dtype == np.float16 and entry.shape == (front_net.n_steps(16000), 44)
    np.testing.assert_array_equal(entry, job.compute()["targets"])
    with hearing_cache(ArrayCache(tmp_path)) as c:
        t = cached_targets(y)
        assert c.hits == 1 and c.misses == 0
    np.testing.assert_allclose(t, teacher_targets(y), atol=2e-3)
    np.testing.assert_allclose(t.sum(axis=1), 1.0, atol=1e-6)


# -- training ------------------------------------------------------------------------------------

def toy(seed, n_utt=8, seconds=2.0):
    """Utterances of tone (class aa) and noise (class s) in turns of 0.2–0.5 s, with their
    one-hot targets per step and the class per step."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_utt):
        n = int(seconds * 16000)
        y, cls, i, tone = np.zeros(n, np.float32), np.zeros(n, np.int64), 0, bool(rng.random()
                                                                                  < 0.5)
        while i < n:
            m = int(rng.uniform(0.2, 0.5) * 16000)
            t = np.arange(min(m, n - i)) / 16000
            y[i:i + len(t)] = (0.3 * np.sin(2 * np.pi * rng.uniform(200, 400) * t) if tone else
                               0.1 * rng.standard_normal(len(t)))
            cls[i:i + len(t)] = AA if tone else S
            i, tone = i + len(t), not tone
        steps = cls[np.minimum(np.arange(front_net.n_steps(n)) * 160, n - 1)]
        out.append((y, steps))
    return out


SMALL = FrontSettings(hidden=16, lookahead_ms=30, epochs=12, batch=4, learning_rate=0.01,
                      segment_s=1.0, patience=0)


def examples(data):
    return [FrontExample(y, np.eye(44, dtype=np.float32)[steps], steps) for y, steps in data]


def test_training_recovers_a_known_mapping_the_same_way_twice():
    train = examples(toy(0))
    arrays, metadata = train_front(train, SMALL, seed=5, progress=False,
                                   info={"training_speakers": ["tone"]})
    again, _ = train_front(train, SMALL, seed=5, progress=False)
    for k in front_net.ARRAYS:
        np.testing.assert_array_equal(arrays[k], again[k])
    assert metadata["training_speakers"] == ["tone"] and metadata["lookahead_ms"] == 30
    assert metadata["teacher"] == hama_front.RECOGNISER_NAME
    front = make_front(arrays, metadata)
    right = total = 0
    for y, steps in toy(1, n_utt=3):  # new utterances
        s = CausalStream(16000, 30, 3, 0, model=front)
        s.push(y)
        labels = np.asarray(s.labels.tolist() + s.flush())
        truth = steps[np.arange(len(labels)) * 100 // 30]
        right, total = right + int(np.sum(labels == truth)), total + len(labels)
    assert right / total >= 0.9


def test_bad_examples_are_refused_by_index():
    y = np.zeros(1600, np.float32)
    with pytest.raises(ParameterError, match=r"^training example 0: 11 steps of audio, targets "
                                             r"\(10, 44\) and labels \(11,\); allowed: "
                                             r"\(11, 44\) and \(11,\)$"):
        train_front([FrontExample(y, np.ones((10, 44)))], SMALL, seed=0, progress=False)
    with pytest.raises(ParameterError, match="needs at least one training example"):
        train_front([], SMALL, seed=0, progress=False)


@pytest.mark.parametrize("kwargs, message", [
    ({"lookahead_ms": 150}, "lookahead_ms is 150; allowed: a multiple of 10 from 0 to 100 (ms)"),
    ({"lookahead_ms": 95}, "lookahead_ms is 95; allowed: a multiple of 10 from 0 to 100 (ms)"),
    ({"hidden": 0}, "hidden is 0; allowed: an integer >= 1"),
])
def test_bad_settings_are_refused_by_key(kwargs, message):
    with pytest.raises(SettingError) as err:
        FrontSettings(**kwargs)
    assert str(err.value) == message
    assert str(err.value.within("front_end")) == "front_end." + message  # as the config says
    assert isinstance(err.value, ParameterError)


def test_step_labels_follow_the_video_frames():
    got = front_training.step_labels(np.array([1, 2, 3]), 30, 12)
    np.testing.assert_array_equal(got, [1, 1, 1, 1, 2, 2, 2, 3, 3, 3, -1, -1])
