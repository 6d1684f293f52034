"""Offline and streaming animation: streaming frames equal offline frames for any chunk size,
frames leave as soon as their look-ahead has arrived, silence gives the neutral face, and the
renderer draws what the markers say."""
import numpy as np
import pytest

from face_model.errors import ParameterError
from mapping import GatedMLP, build_dataset, split_masks
from mapping.animator import FaceAnimator, StreamingAnimator
from mapping.model import AudioMapping
from talkingface.config import Config

# Streaming and offline run the same arithmetic on (1, d) rows and (n, d) blocks; BLAS may round
# the two differently, so MUPs agree to float32 precision, not bit for bit.
MUP_TOL = 1e-3
MARKER_TOL_PX = 1e-3


@pytest.fixture(scope="module")
def animator(small_corpus):
    from face_model.motion_units import fit_corpus_units

    cfg = Config()
    units, _ = fit_corpus_units(small_corpus)
    data = build_dataset(small_corpus, units)
    masks = split_masks(data, "random_frames", seed=cfg.seed)
    mapper = GatedMLP(cfg.mapping, n_utterance=units.n_utterance, seed=cfg.seed).fit(data, masks)
    sr = small_corpus.utterances[0].sample_rate
    return FaceAnimator(AudioMapping(mapper, sample_rate=sr, n_utterance=units.n_utterance),
                        units)


def _stream(animator, y, chunk, expression):
    s = StreamingAnimator(animator, expression)
    frames = []
    for i in range(0, len(y), chunk):
        frames += s.push(y[i:i + chunk])
    return frames + s.flush()


@pytest.mark.parametrize("chunk", [1, 333, 735, 4096, 10**7])
@pytest.mark.parametrize("expression", ["neutral", "smile"])
def test_streaming_frames_equal_offline_frames(animator, small_corpus, chunk, expression):
    u = small_corpus.utterances[1]
    mups, markers = animator.animate(u.audio, u.sample_rate, expression)
    frames = _stream(animator, u.audio, chunk, expression)
    assert [f.index for f in frames] == list(range(len(mups)))
    assert [f.time_s for f in frames] == [k / 30 for k in range(len(mups))]
    np.testing.assert_allclose(np.stack([f.mups for f in frames]), mups, rtol=0, atol=MUP_TOL)
    np.testing.assert_allclose(np.stack([f.markers for f in frames]), markers, rtol=0,
                               atol=MARKER_TOL_PX)


def test_a_frame_leaves_once_its_look_ahead_has_arrived(animator, small_corpus):
    u = small_corpus.utterances[0]
    s = StreamingAnimator(animator)
    hop, half, fwd = s.hop, s.half, s.forward
    k = 10
    need = (k + fwd) * hop + half + 1  # samples frame k needs: frame k+3's whole window
    first = s.push(u.audio[:need - 1])
    assert [f.index for f in first] == list(range(k))
    assert [f.index for f in s.push(u.audio[need - 1:need])] == [k]
    assert s.latency_s == pytest.approx(fwd / 30 + half / u.sample_rate)


def test_silence_gives_the_neutral_face(animator):
    silence = np.zeros(animator.mapping.sample_rate, np.float32)
    mups, markers = animator.animate(silence, animator.mapping.sample_rate, "neutral")
    rest = np.concatenate([animator.rest_, np.zeros(mups.shape[1] - len(animator.rest_))])
    np.testing.assert_allclose(mups, np.broadcast_to(rest, mups.shape), atol=1e-6)
    # the MU model's closest face to the neutral one: within a fraction of a pixel of it
    assert np.abs(markers - animator.neutral).max() < 0.5
    frames = _stream(animator, silence, 512, "neutral")
    np.testing.assert_allclose(np.stack([f.markers for f in frames]), markers, atol=1e-9)


def test_stream_errors(animator):
    s = StreamingAnimator(animator)
    with pytest.raises(ParameterError, match="mono"):
        s.push(np.zeros((10, 2)))
    with pytest.raises(ParameterError, match="NaN or inf"):
        s.push(np.array([0.0, np.nan]))
    s.flush()
    with pytest.raises(ParameterError, match="was flushed"):
        s.push(np.zeros(10))
    with pytest.raises(ParameterError, match="unknown expression 'angry'"):
        StreamingAnimator(animator, "angry")


def test_renderer_draws_the_mouth_the_markers_open(animator):
    from face_model.layout import LOWER_INNER, LOWER_OUTER, default_layout
    from face_model.render import FaceRenderer

    r = FaceRenderer()
    neutral = default_layout().neutral
    opened = neutral.copy()
    opened[list(LOWER_INNER), 1] += 12.0
    opened[list(LOWER_OUTER), 1] += 12.0
    a, b = r.render(neutral), r.render(opened)
    assert a.shape == (400, 368, 3) and a.dtype == np.uint8
    np.testing.assert_array_equal(a, r.render(neutral))  # deterministic

    def dark(img):  # mouth-opening pixels: dark red
        return int(((img[..., 0] < 110) & (img[..., 1] < 50) & (img[..., 2] < 60)).sum())
    assert dark(b) > dark(a) + 200
    moved = neutral + [15.0, 0.0]  # a head moved right moves the drawing right
    cols = lambda img: np.flatnonzero((np.abs(img.astype(int) - [236, 240, 244]).sum(2) > 30)
                                      .any(0))  # noqa: E731
    assert cols(r.render(moved)).mean() > cols(a).mean() + 10
    with pytest.raises(ParameterError, match=r"shape \(79, 2\)"):
        r.render(neutral[:10])
    with pytest.raises(ParameterError, match="NaN"):
        r.render(np.full((79, 2), np.nan))
