"""Look-ahead as a setting (issue 13, part 1): with the analysis window right-aligned and no
context look-ahead, a frame reads no sample after its instant; the streaming animator gives the
offline frames for every look-ahead; the algorithmic latency is exact."""
import json

import numpy as np
import pytest

from groundwork import modelfile
from groundwork.errors import ParameterError
from mapping.animator import FaceAnimator, StreamingAnimator
from mapping.checkpoint import AudioMapping
from mapping.features import (algorithmic_latency_s, aligned, frame_rms_dbfs, mfcc,
                              window_future)
from tests.mapping.small_mapping import stream_frames, train_small

SR = 22050
HOP = SR // 30


@pytest.fixture(scope="module", params=[0, 1, 2, 3, 4, 5])
def causal(request, small_corpus):
    """A gated MLP with a right-aligned window and ``forward`` frames of look-ahead."""
    t = train_small(small_corpus, context_forward=request.param, window_align="right")
    return request.param, t


def _future_changed(y, k):
    """``y`` with every sample after frame k's instant (k·hop) replaced by loud noise."""
    other = y.copy()
    other[k * HOP + 1:] = np.random.default_rng(k).normal(0, 0.3, len(y) - k * HOP - 1)
    return other


def test_the_window_future_is_the_samples_a_centred_frame_reads_after_its_instant():
    assert window_future(22050) == 275 and window_future(16000) == 200
    y = np.zeros(SR, np.float32)
    np.testing.assert_array_equal(aligned(y, SR, "right")[:275], 0)
    assert len(aligned(y, SR, "right")) == SR + 275 and aligned(y, SR, "centre") is y
    with pytest.raises(ParameterError, match="window alignment must be one of"):
        aligned(y, SR, "left")


def test_a_right_aligned_frame_reads_nothing_after_its_instant(speech_audio):
    y = speech_audio
    k = 40
    other = _future_changed(y, k)
    a, b = mfcc(y, sr=SR, align="right"), mfcc(other, sr=SR, align="right")
    np.testing.assert_array_equal(a[:k + 1], b[:k + 1])
    la = frame_rms_dbfs(y, sr=SR, n_frames=len(a), align="right")
    lb = frame_rms_dbfs(other, sr=SR, n_frames=len(a), align="right")
    np.testing.assert_array_equal(la[:k + 1], lb[:k + 1])
    # the centred window (the paper's) does read past the instant: the test can fail
    c, d = mfcc(y, sr=SR), mfcc(other, sr=SR)
    assert not np.array_equal(c[k], d[k])


@pytest.fixture(scope="module")
def speech_audio(small_corpus):
    u = small_corpus.utterances[0]
    assert u.sample_rate == SR
    return np.asarray(u.audio, np.float32)


def test_a_model_with_no_look_ahead_uses_no_future_sample(causal, speech_audio):
    forward, t = causal
    k = 40
    y = speech_audio
    a = t.mapping.predict_audio(y, SR, "smile")
    b = t.mapping.predict_audio(_future_changed(y, k), SR, "smile")
    decided = k - forward  # frames whose look-ahead ends at or before sample k·hop
    np.testing.assert_array_equal(a[:decided + 1], b[:decided + 1])
    assert not np.array_equal(a, b)


def test_streaming_equals_offline_for_every_look_ahead(causal, small_corpus):
    forward, t = causal
    animator = FaceAnimator(t.mapping, t.units)
    u = small_corpus.utterances[1]
    mups, _ = animator.animate(u.audio, u.sample_rate, "sad")
    for chunk in (1, 733, 10**7):
        frames = stream_frames(animator, u.audio, chunk, "sad")
        assert [f.index for f in frames] == list(range(len(mups)))
        np.testing.assert_allclose(np.stack([f.mups for f in frames]), mups, rtol=0, atol=1e-3)
    assert StreamingAnimator(animator).latency_s == pytest.approx(forward / 30)  # look-ahead


def test_a_frame_leaves_the_stream_once_its_look_ahead_has_arrived(causal, small_corpus):
    forward, t = causal
    s = StreamingAnimator(FaceAnimator(t.mapping, t.units), "neutral")
    y = small_corpus.utterances[0].audio
    k = 20
    got = s.push(y[:(k + forward) * HOP + 1])  # up to and including frame k+forward's instant
    assert [f.index for f in got] == list(range(k + 1))


def test_algorithmic_latency_is_the_look_ahead_plus_the_window_past_the_instant():
    assert algorithmic_latency_s(3, 22050) == pytest.approx(0.1 + 275 / 22050)
    assert algorithmic_latency_s(0, 22050, align="right") == 0.0
    assert algorithmic_latency_s(5, 48000, align="right") == pytest.approx(5 / 30)


def test_a_model_saved_before_the_alignment_existed_loads_centred(causal, tmp_path):
    _, t = causal
    path = t.mapping.save(tmp_path / "m.tfmap")
    assert AudioMapping.load(path).window_align == "right"
    with np.load(path, allow_pickle=False) as z:
        members = {name: z[name] for name in z.files}
    header = json.loads(str(members.pop("metadata")))  # as format /3 wrote it
    del header["window_align"], header["kind"], header["version"]
    header.update(format="talkingface.mapping/3", sha256=modelfile.checksum(members))
    with open(path, "wb") as f:
        np.savez(f, allow_pickle=False, header=np.array(json.dumps(header)), **members)
    assert AudioMapping.load(path).window_align == "centre"
