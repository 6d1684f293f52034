"""Offline and streaming animation: streaming frames equal offline frames for any chunk size,
frames leave as soon as their look-ahead has arrived, silence gives the neutral face (the
mapping's silence rule, the same offline, in the animator and streaming), and the renderer draws
what the markers say."""
import numpy as np
import pytest

from groundwork.audio import resample
from groundwork.errors import ParameterError
from mapping import build_dataset, make_mapper, split_masks
from mapping.animator import FaceAnimator, StreamingAnimator
from mapping.checkpoint import AudioMapping, rest_mups
from mapping.features import MFCC_SETTINGS, frame_rms_dbfs, hop_samples
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
    mapper = make_mapper("gated_mlp", cfg.mapping, n_utterance=units.n_utterance,
                         random_state=cfg.seed).fit(data, masks)
    sr = small_corpus.utterances[0].sample_rate
    return FaceAnimator(AudioMapping(mapper, sample_rate=sr, n_utterance=units.n_utterance,
                                     rest_mups=rest_mups(units)), units)


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


PAD_S = 0.5  # digital silence before and after the speech


@pytest.fixture(scope="module")
def padded_speech(animator, small_corpus):
    """An utterance with 0.5 s of zeros before and after it, and the frames whose whole
    analysis window lies in the zeros (frame k is centred at sample k · hop)."""
    u = small_corpus.utterances[4]  # a smiling utterance
    sr = u.sample_rate
    pad = int(PAD_S * sr)
    y = np.concatenate([np.zeros(pad, np.float32), u.audio, np.zeros(pad, np.float32)])
    hop, half = hop_samples(sr, 30), int(round(MFCC_SETTINGS["window_s"] * sr)) // 2
    centres = np.arange(int(np.ceil(len(y) / hop))) * hop
    silent = (centres + half < pad) | (centres - half >= pad + len(u.audio))
    return u, y, silent


@pytest.mark.parametrize("expression", ["neutral", "smile"])
def test_digital_silence_around_speech_gives_exactly_the_rest_mups(animator, padded_speech,
                                                                   expression):
    u, y, silent = padded_speech
    mapping, a0 = animator.mapping, animator.mapping.n_utterance
    assert 2 * 13 <= silent.sum() <= 2 * 15 and silent[:13].all() and silent[-13:].all()
    mups = mapping.predict_audio(y, u.sample_rate, expression)
    assert mups.shape == (len(silent), a0 + 2) and mups.dtype == np.float32
    raw = mapping.mapper.predict(mapping.features(y, u.sample_rate), expression)
    # quiet: the zeros, and the corpus's own faint pauses at the ends of the utterance
    quiet = frame_rms_dbfs(y, sr=u.sample_rate, n_frames=len(mups)) < mapping.silence_dbfs
    assert quiet[silent].all() and not quiet.all()
    # silent frames: the neutral face's utterance MUPs, whatever the network said
    rest = mapping.rest_mups.astype(np.float32)
    np.testing.assert_array_equal(mups[silent, :a0], np.broadcast_to(rest, (silent.sum(), a0)))
    np.testing.assert_array_equal(mups[quiet, :a0], np.broadcast_to(rest, (quiet.sum(), a0)))
    assert np.abs(raw[silent, :a0] - rest).max() > 1e-3  # the rule did act
    # the expression part is kept, and sounding frames are the network's estimate unchanged
    np.testing.assert_array_equal(mups[:, a0:], raw[:, a0:])
    np.testing.assert_array_equal(mups[~quiet], raw[~quiet])
    # streaming applies the same rule
    frames = _stream(animator, y, 4096, expression)
    streamed = np.stack([f.mups for f in frames])
    np.testing.assert_array_equal(streamed[silent, :a0], np.broadcast_to(rest, (silent.sum(), a0)))


@pytest.mark.parametrize("sr", [None, 44100])
def test_the_animator_mups_are_the_mappings_predict_audio(animator, padded_speech, sr):
    """One audio → MUP entry point: FaceAnimator.mups is AudioMapping.predict_audio, bit for
    bit, at the model's rate and at another one (resampled by the mapping)."""
    u, y, _ = padded_speech
    if sr is not None:
        y = resample(y, sr_in=u.sample_rate, sr_out=sr)
    sr = sr or u.sample_rate
    for expression in ("neutral", "smile"):
        expected = animator.mapping.predict_audio(y, sr, expression)
        np.testing.assert_array_equal(animator.mups(y, sr, expression), expected)
        mups, _ = animator.animate(y, sr, expression)
        np.testing.assert_array_equal(mups, expected)


def test_animator_refuses_a_mapping_of_other_motion_units(animator):
    m = animator.mapping
    other = AudioMapping(m.mapper, sample_rate=m.sample_rate, n_utterance=m.n_utterance,
                         rest_mups=m.rest_mups + 0.01)
    with pytest.raises(ParameterError, match="saved with other Motion Units"):
        FaceAnimator(other, animator.units)


def test_stream_errors(animator):
    s = StreamingAnimator(animator)
    with pytest.raises(ParameterError, match="mono"):
        s.push(np.zeros((10, 2)))
    with pytest.raises(ParameterError, match="NaN or inf"):
        s.push(np.array([0.0, np.nan]))
    s.flush()
    with pytest.raises(ParameterError, match="was flushed"):
        s.push(np.zeros(10))
    with pytest.raises(ParameterError, match="expression 'angry' is not known to this model"):
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
