"""The causal front end's stream (issue 40): a frame depends on no audio past its look-ahead,
offline equals live for any chunking, each frame reads the head its docstring names, the
model file round-trips and names its weights, and bad input is refused by name."""
import numpy as np
import pytest

from face_model.phones import PHONE_INDEX
from groundwork.errors import ParameterError
from groundwork.modelfile import ModelFileError, write_model
from mapping import front_net
from tests.mapping.streams import feed
from mapping.causal_front import CausalStream, labels_at_delays, posteriors
from mapping.front_net import (front_name, load, make_front, random_front, read_front, resolve,
                               write_front)

SIL = PHONE_INDEX["sil"]
FPS = 30


@pytest.fixture(scope="module")
def front():
    """A seeded untrained net: 16 wide, heads of 0 … 100 ms."""
    return make_front(*random_front(7, n_mels=40, hidden=16, lookahead_ms=100))


def sound(sr, seconds=1.5, seed=0):
    """Speech-like test audio: a gliding tone in bursts over quiet noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * sr)) / sr
    bursts = (t % 0.4) < 0.22
    y = 0.3 * np.sin(2 * np.pi * (200 + 900 * t) * t) * bursts + 0.02 * rng.standard_normal(
        len(t))
    return y.astype(np.float32)


def run(stream, y, sizes=None):
    """Windows of ``y`` pushed in chunks of ``sizes`` (cycled; None: one push), flushed."""
    return feed(stream, y, [max(len(y), 1)] if sizes is None else sizes)


# -- causality ---------------------------------------------------------------------------------

@pytest.mark.parametrize("sr", [16000, 22050])
@pytest.mark.parametrize("back", [0, 3])
@pytest.mark.parametrize("delay", [0, 1, 3])
def test_a_frame_depends_on_no_audio_after_its_look_ahead(front, sr, delay, back):
    y = sound(sr)
    k = 20
    s = CausalStream(sr, FPS, delay, back, model=front)
    cut = s._boundary(k + delay + 1)  # the first sample of block k + delay + 1
    other = y.copy()
    other[cut:] = 0.5 * np.random.default_rng(1).standard_normal(len(y) - cut)
    a = run(CausalStream(sr, FPS, delay, back, model=front), y)
    b = run(CausalStream(sr, FPS, delay, back, model=front), other)
    np.testing.assert_array_equal(a[:k + 1], b[:k + 1])
    assert np.any(a[k + 1:] != b[k + 1:])  # the change is heard, just later


# -- offline = live ------------------------------------------------------------------------------

@pytest.mark.parametrize("sr", [16000, 22050])
@pytest.mark.parametrize("delay, back", [(0, 2), (3, 2), (5, 0)])
def test_windows_do_not_depend_on_the_chunking(front, sr, delay, back):
    y = sound(sr, 2.0)
    whole = run(CausalStream(sr, FPS, delay, back, model=front), y)
    assert whole.shape == (-(-len(y) * FPS // sr), back + 1 + delay)
    assert len(np.unique(whole[:, back])) > 1  # the phones vary: the comparison is not vacuous
    rng = np.random.default_rng(3)
    sizes = np.concatenate([[1, 0, 1, 2, 0], rng.integers(0, 2000, size=300)])
    s = CausalStream(sr, FPS, delay, back, model=front)
    np.testing.assert_array_equal(run(s, y, sizes), whole)
    np.testing.assert_array_equal(s.windows, whole)
    np.testing.assert_array_equal(s.labels, whole[:, back])


def test_sample_by_sample_equals_one_push(front):
    sr, y = 22050, sound(22050, 0.6)
    whole = run(CausalStream(sr, FPS, 3, 1, model=front), y)
    s = CausalStream(sr, FPS, 3, 1, model=front)
    phones = [p for x in y for p in s.push(x[None])] + s.flush()
    np.testing.assert_array_equal(phones, whole[:, 1])


@pytest.mark.parametrize("sr", [16000, 22050])
def test_labels_at_delays_are_the_streams_phones(front, sr):
    y = sound(sr, 1.3)
    delays = (0, 1, 2, 3, 4, 6)  # 4 and 6 frames reach past the 100-ms head: it is reused
    got = labels_at_delays(y, sr, FPS, delays, model=front)
    for d in delays:
        np.testing.assert_array_equal(got[d], run(CausalStream(sr, FPS, d, 0, model=front),
                                                  y)[:, 0])
    np.testing.assert_array_equal(got[4], got[6])


def test_each_frame_reads_the_head_of_its_look_ahead(front):
    sr, y = 16000, sound(16000, 1.2)
    p = posteriors(y, sr, FPS, model=front)
    assert p.shape == (front_net.n_steps(len(y)), 11, 44)
    np.testing.assert_allclose(p.sum(axis=2), 1.0, rtol=1e-5)
    for d, head in ((0, 0), (1, 3), (2, 6), (3, 10)):
        labels = run(CausalStream(sr, FPS, d, 0, model=front), y)[:, 0]
        k = np.arange(len(labels) - 4)  # frames decided before the end of the audio
        step = k * 100 // FPS + head
        np.testing.assert_array_equal(labels[k], p[step, head].argmax(axis=1))


@pytest.mark.parametrize("n", [0, 1, 534, 16000, 16001])
def test_the_stream_counts_its_frames_as_the_others(front, n):
    s = CausalStream(16000, FPS, 3, 2, model=front)
    w = run(s, np.zeros(n, np.float32))
    assert w.shape == (-(-n * FPS // 16000), 6)
    assert np.all(w[:1, :2] == SIL)  # frames before 0 are silence


def test_past_columns_keep_their_decided_phones(front):
    w = run(CausalStream(22050, FPS, 2, 3, model=front), sound(22050, 1.5))
    labels = w[:, 3]
    for c in range(3):  # column c holds frame k − 3 + c
        np.testing.assert_array_equal(w[3 - c:, c], labels[:len(w) - 3 + c])


# -- the model file ------------------------------------------------------------------------------

def test_the_model_file_round_trips_and_names_its_weights(tmp_path, front):
    arrays, metadata = random_front(7, n_mels=40, hidden=16, lookahead_ms=100)
    path = write_front(tmp_path / "front.npz", arrays, {**metadata, "training_speakers": ["x"]})
    got_arrays, got_meta = read_front(path)
    assert got_meta["training_speakers"] == ["x"] and got_meta["lookahead_ms"] == 100
    for k in front_net.ARRAYS:
        np.testing.assert_array_equal(got_arrays[k], arrays[k])
    y = sound(22050, 1.0)
    np.testing.assert_array_equal(run(CausalStream(22050, FPS, 3, 2, model=path), y),
                                  run(CausalStream(22050, FPS, 3, 2, model=front), y))
    name = front_name(path)
    assert name.startswith("causal-front v1 sha256:") and len(name.split(":")[1]) == 12
    assert load(str(path)) is load(path)  # read once per file version
    changed = dict(arrays, head_b=arrays["head_b"] + np.float32(1e-3))
    other = write_front(tmp_path / "other.npz", changed, metadata)
    assert front_name(other) != name
    write_front(path, changed, metadata)  # retrained in place: the new weights are read
    assert front_name(path) == front_name(other)


def test_a_missing_model_file_is_named(tmp_path, monkeypatch):
    missing = tmp_path / "nope.npz"
    with pytest.raises(ParameterError, match=rf"^phone front model file {missing} not found$"):
        CausalStream(16000, model=missing)
    with pytest.raises(ParameterError, match=rf"^phone front model file {missing} not found$"):
        front_name(str(missing))
    shipped = write_front(tmp_path / "shipped.npz", *random_front(2, hidden=8))
    monkeypatch.setattr(front_net, "SHIPPED", shipped)
    assert resolve(None) == shipped == resolve("")
    assert front_name(None) == front_name(shipped)


def test_a_file_of_another_kind_or_damaged_is_refused_in_one_line(tmp_path):
    other = write_model(tmp_path / "other.npz", {"w": np.zeros(3)}, {}, kind="keyframes",
                        version=1)
    with pytest.raises(ModelFileError, match=r"not a phone front model file \(its kind is "
                                             r"'keyframes', expected 'phone_front'\)"):
        load(other)
    arrays, metadata = random_front(1, hidden=8)
    path = write_front(tmp_path / "front.npz", arrays, metadata)
    path.write_bytes(path.read_bytes()[:500])
    with pytest.raises(ModelFileError, match="truncated or damaged"):
        load(path)


def test_arrays_of_the_wrong_shape_are_refused_by_name(tmp_path):
    arrays, metadata = random_front(1, hidden=8)
    arrays["gru_w_hh"] = arrays["gru_w_hh"][:, :4]
    with pytest.raises(ParameterError, match=r"arrays of the wrong shape: gru_w_hh \(24, 4\) "
                                             r"\(expected \(24, 8\)\)"):
        write_front(tmp_path / "f.npz", arrays, metadata)


# -- bad input -----------------------------------------------------------------------------------

@pytest.mark.parametrize("args, message", [
    ((16000, 30, -1), "delay_frames must be an integer ≥ 0, got -1"),
    ((16000, 30, 3, 1.5), r"back must be an integer ≥ 0, got 1\.5"),
    ((16000, 30, True), "delay_frames must be an integer ≥ 0, got True"),
    ((22050.0,), r"sample rate and fps must be positive integers, got 22050\.0 Hz and 30 fps"),
    ((16000, 0), "sample rate and fps must be positive integers, got 16000 Hz and 0 fps"),
])
def test_bad_settings_are_refused(front, args, message):
    with pytest.raises(ParameterError, match=message):
        CausalStream(*args, model=front)


def test_bad_chunks_and_a_push_after_the_end_are_refused(front):
    s = CausalStream(16000, model=front)
    with pytest.raises(ParameterError, match="^the audio chunk must be mono and finite$"):
        s.push(np.zeros((10, 2), np.float32))
    with pytest.raises(ParameterError, match="^the audio chunk must be mono and finite$"):
        s.push(np.array([0.0, np.nan], np.float32))
    s.flush()
    assert s.flush() == []
    with pytest.raises(ParameterError, match="^the phone stream has ended; start a new one$"):
        s.push(np.zeros(10, np.float32))


def test_the_config_mirrors_the_front_end_and_the_recogniser_names():
    from mapping.config import FRONT_MAX_LOOKAHEAD_MS, RECOGNISER_NAMES
    from mapping.recogniser import RECOGNISERS
    assert FRONT_MAX_LOOKAHEAD_MS == front_net.MAX_LOOKAHEAD_MS
    assert RECOGNISER_NAMES == RECOGNISERS
