"""The peers' adapters on a known input: silence, a 0.5 s vowel-like burst, silence."""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest

from face_model.phones import VISEMES
from groundwork.audio import write_wav
from groundwork.errors import ParameterError
from mapping.peers import (OCULUS_TABLE, PEERS, ULIPSYNC_TABLE, PeerTrack, _sample_track,
                           loudness_opening, peer_track, peer_versions)

SR = 16000
BURST = (0.5, 1.0)          # seconds
DURATION = 1.5
WORD = [(0.5, 1.0, "papa")]  # the word on the burst


def vowel_burst(sr: int = SR) -> np.ndarray:
    """0.5 s silence, 0.5 s of a 120 Hz harmonic tone shaped by /a/-like formants (700, 1200,
    2600 Hz), 0.5 s silence; peak 0.3."""
    t = np.arange(int(0.5 * sr)) / sr
    tone = np.zeros_like(t)
    for h in range(1, 30):
        f = 120.0 * h
        amp = sum(np.exp(-((f - formant) / 100.0) ** 2) for formant in (700, 1200, 2600)) + 0.05
        tone += amp * np.sin(2 * np.pi * f * t)
    tone *= 0.3 / np.abs(tone).max()
    silence = np.zeros(int(0.5 * sr))
    return np.concatenate([silence, tone, silence]).astype(np.float32)


def old_loudness_opening(y: np.ndarray, sr: int, n: int, window_s: float = 0.04) -> np.ndarray:
    """The reference: ``talkingface.stages.real_speaker.loudness_opening`` before the move."""
    half = int(round(window_s * sr / 2))
    centres = (np.arange(n) * sr / 30).astype(int)
    out = np.empty(n)
    for k, c in enumerate(centres):
        seg = y[max(0, c - half):c + half]
        out[k] = 10 * np.log10(np.mean(seg.astype(np.float64) ** 2) + 1e-10) if len(seg) else -100
    return out


def track(peer: str, fps: float = 30.0, y=None, **kw) -> PeerTrack:
    y = vowel_burst() if y is None else y
    n = int(round(len(y) / SR * fps))
    if peer == "openfacefx-text" and "transcript" not in kw:
        kw.setdefault("words", WORD)
    return peer_track(peer, y, SR, n_frames=n, fps=fps, **kw)


@pytest.fixture(scope="module")
def tracks():
    return {(p, fps): track(p, fps) for p in PEERS for fps in (25.0, 30.0)}


@pytest.mark.parametrize("fps", [25.0, 30.0])
@pytest.mark.parametrize("peer", PEERS)
def test_every_peer_opens_in_the_burst_and_not_in_the_silences(tracks, peer, fps):
    tr = tracks[(peer, fps)]
    t = np.arange(len(tr.opening)) / fps
    burst = (t >= BURST[0] + 0.1) & (t <= BURST[1] - 0.1)
    silent = (t < BURST[0] - 0.2) | (t > BURST[1] + 0.45)
    assert tr.peer == peer
    assert tr.opening.dtype == np.float64 and np.all(tr.opening >= 0)
    # the median: the text mode's word ("papa") closes the lips twice inside the burst
    assert np.median(tr.opening[burst]) > tr.opening[silent].max()
    if tr.visemes is not None:
        assert tr.visemes.dtype.kind == "i"
        assert set(tr.visemes[silent]) == {VISEMES.index("neutral")}
        assert VISEMES.index("neutral") not in set(tr.visemes[burst][tr.opening[burst] > 0.5])


@pytest.mark.parametrize("fps, n", [(25.0, 37), (30.0, 45), (30.0, 1), (25.0, 60), (29.97, 50)])
@pytest.mark.parametrize("peer", PEERS)
def test_the_output_has_exactly_n_frames(peer, fps, n):
    kw = {"words": WORD} if peer == "openfacefx-text" else {}
    tr = peer_track(peer, vowel_burst(), SR, n_frames=n, fps=fps, **kw)
    assert tr.opening.shape == (n,)
    assert tr.visemes is None if peer == "loudness" else tr.visemes.shape == (n,)
    assert np.all(np.isfinite(tr.opening))


def test_the_moved_loudness_envelope_equals_the_old_one():
    y = vowel_burst() + np.random.default_rng(7).normal(0, 1e-3, int(DURATION * SR))
    n = 47                                     # two frames past the audio: the -100 dB branch
    ref = old_loudness_opening(y, SR, n)
    np.testing.assert_array_equal(loudness_opening(y, SR, n), ref)
    np.testing.assert_array_equal(loudness_opening(y, SR, n, fps=30.0), ref)
    tr = peer_track("loudness", y, SR, n_frames=n, fps=30)
    np.testing.assert_array_equal(tr.opening, ref - ref.min())
    assert tr.visemes is None


def test_the_loudness_envelope_follows_fps():
    """At 25 fps frame k is centred at k / 25 s: the 30 fps envelope of the audio stretched by
    30/25 in time (same samples, rate 16 kHz → read as 19.2 kHz) is the 25 fps one here."""
    y = vowel_burst()
    db25 = loudness_opening(y, SR, 37, fps=25.0)
    db30 = loudness_opening(y, int(SR * 30 / 25), 37, window_s=0.04 * 25 / 30, fps=30.0)
    np.testing.assert_allclose(db25, db30, atol=1e-9)


def test_the_text_mode_puts_the_words_visemes_inside_its_interval():
    """words [(0.3, 0.7, "papa")]: the closures (m, from PP) fall inside the two /p/ segments of
    the package's own anchored alignment, so inside [0.3, 0.7]; the open visemes reach no
    further than the package's coarticulation lead (CoartParams.lead, jaw) beyond the word; the
    widest opening is inside the word."""
    from openfacefx.anchors import Anchor, anchored_segments
    from openfacefx.coarticulation import CoartParams

    fps, start, end = 30.0, 0.3, 0.7
    tr = peer_track("openfacefx-text", vowel_burst(), SR, n_frames=45, fps=fps,
                    words=[(start, end, "papa")])
    t = np.arange(45) / fps
    closed = t[tr.visemes == VISEMES.index("m")]
    p_segments = [(s.start, s.end) for s in anchored_segments("papa", DURATION,
                                                              [Anchor("papa", start, end)])
                  if s.phoneme == "P"]
    assert len(p_segments) == 2 and len(closed) >= 2
    assert all(any(a - 1e-9 <= x <= b + 1e-9 for a, b in p_segments) for x in closed)
    assert all(start <= x <= end for x in closed)
    lead = max(CoartParams().lead["jaw"])
    is_open = np.isin(tr.visemes, [VISEMES.index(v) for v in "iaou"])
    assert is_open.any()
    assert np.all((t[is_open] >= start - lead) & (t[is_open] <= end + lead))
    assert np.all(tr.visemes[(t < start - lead) | (t > end + lead)] == VISEMES.index("neutral"))
    assert start <= t[np.argmax(tr.opening)] <= end


def test_the_text_mode_with_a_transcript_only_spans_the_clip_and_words_take_precedence():
    only_text = track("openfacefx-text", transcript="papa")
    assert VISEMES.index("m") in set(only_text.visemes)
    with_words = track("openfacefx-text", words=[(0.3, 0.7, "papa")], transcript="papa")
    words_only = track("openfacefx-text", words=[(0.3, 0.7, "papa")])
    np.testing.assert_array_equal(with_words.opening, words_only.opening)
    assert not np.array_equal(only_text.opening, words_only.opening)


def test_pause_tokens_in_word_alignments_are_dropped():
    plain = track("openfacefx-text", words=[(0.3, 0.7, "papa")])
    grid = track("openfacefx-text", words=[(0.0, 0.3, "sil"), (0.3, 0.7, "papa"),
                                           (0.7, 1.5, "sp")])
    np.testing.assert_array_equal(plain.opening, grid.opening)


def test_the_openfacefx_tracks_are_sampled_as_its_own_sampler_does():
    from openfacefx.energy import generate_from_energy
    from openfacefx.retarget import _sampler

    with tempfile.TemporaryDirectory() as tmp:
        path = str(Path(tmp) / "a.wav")
        write_wav(path, vowel_burst(), SR)
        face = generate_from_energy(path, fps=25.0)
    times = np.arange(40) / 25.0
    sampled = _sample_track(face, times)
    assert set(sampled) == {c.name for c in face.channels}
    for channel in face.channels:
        np.testing.assert_allclose(sampled[channel.name],
                                   [_sampler(channel)(x) for x in times], atol=1e-12)


def test_the_tables_cover_every_channel_of_the_packages():
    from openfacefx.visemes import VISEMES as OCULUS
    from pylipsync import PhonemeAnalyzer

    assert set(OCULUS_TABLE) == set(OCULUS)
    assert set(ULIPSYNC_TABLE) == set(PhonemeAnalyzer().phoneme_mfccs)
    for table in (OCULUS_TABLE, ULIPSYNC_TABLE):
        for opening, viseme in table.values():
            assert 0.0 <= opening <= 1.0 and viseme in VISEMES
    assert OCULUS_TABLE["PP"] == (0.0, "m") and ULIPSYNC_TABLE["silence"] == (0.0, "neutral")


def test_the_versions_are_the_pinned_ones():
    assert peer_versions() == {"openfacefx": "0.24.0", "pylipsync": "0.2.1"}


@pytest.mark.parametrize("peer", PEERS)
def test_every_peer_is_deterministic(tracks, peer):
    again = track(peer, 30.0)
    first = tracks[(peer, 30.0)]
    np.testing.assert_array_equal(again.opening, first.opening)
    if first.visemes is not None:
        np.testing.assert_array_equal(again.visemes, first.visemes)


def test_pylipsync_reads_audio_below_16_khz_at_its_true_rate():
    """At 8 kHz the burst is resampled to 16 kHz first: the same track as at 16 kHz."""
    y16 = vowel_burst(16000)
    y8 = vowel_burst(8000)
    a = peer_track("pylipsync", y16, 16000, n_frames=45, fps=30)
    b = peer_track("pylipsync", y8, 8000, n_frames=45, fps=30)
    t = np.arange(45) / 30
    on_a, on_b = t[a.opening > 0.3], t[b.opening > 0.3]
    assert abs(on_a.min() - on_b.min()) <= 1 / 30 and abs(on_a.max() - on_b.max()) <= 1 / 30


@pytest.mark.parametrize("call, match", [
    (dict(peer="rhubarb"),
     r"^peer 'rhubarb': unknown; allowed: loudness, openfacefx-text, openfacefx-energy, "
     r"pylipsync$"),
    (dict(n_frames=0), r"^n_frames 0: an integer ≥ 1 is needed$"),
    (dict(fps=0.0), r"^fps 0.0: a finite frame rate > 0 is needed$"),
    (dict(sr=0), r"^sr 0: a positive integer sample rate \(Hz\) is needed$"),
    (dict(y=np.zeros((2, 100))), r"^y: shape \(2, 100\); non-empty 1-D mono audio is needed$"),
    (dict(y=np.zeros(0)), r"^y: shape \(0,\); non-empty 1-D mono audio is needed$"),
    (dict(y=np.r_[np.zeros(5), np.nan, np.inf]),
     r"^y: 2 non-finite samples \(NaN/inf\), the first at sample 5; finite audio is needed$"),
    (dict(peer="openfacefx-text"),
     r"^peer 'openfacefx-text': needs words \(start_s, end_s, word\) or a transcript; "
     r"got neither$"),
    (dict(peer="openfacefx-text", words=[(0.0, 0.3, "sil")]),
     r"^words: no word left after dropping pause tokens"),
    (dict(peer="openfacefx-text", words=[(0.3, 0.7, "pa"), (0.5, 0.9, "pa")]),
     r"^words: openfacefx rejects them: anchors overlap"),
    (dict(peer="openfacefx-text", words=[(0.3, 0.7, "pa"), (0.5, 0.9, "pa")], each_word=True),
     r"^words: word 1 'pa' starts at 0.5 s, before the previous word ends \(0.7 s\); allowed: "
     r"words in time order, not overlapping$"),
    (dict(peer="openfacefx-text", words=[(0.7, 0.3, "pa")], each_word=True),
     r"^words: word 0 'pa' from 0.7 s to 0.3 s; allowed: 0 <= start_s < end_s$"),
    (dict(peer="openfacefx-text", words=[(0.0, 0.3, "sp")], each_word=True),
     r"^words: no word left after dropping pause tokens"),
])
def test_bad_input_is_refused_with_its_message(call, match):
    args = dict(peer="loudness", y=np.zeros(1600), sr=SR, n_frames=3, fps=30.0)
    args.update(call)
    with pytest.raises(ParameterError, match=match):
        peer_track(args.pop("peer"), args.pop("y"), args.pop("sr"), **args)


# -- openfacefx-text with each word segmented on its own interval (each_word) ------------------
SENTENCE = [(0.20, 0.45, "bin"), (0.45, 0.70, "blue"), (0.95, 1.30, "papa")]  # a pause at 0.7–0.95


@pytest.mark.parametrize("fps", [25.0, 30.0])
def test_each_word_keeps_its_mouth_inside_its_own_interval(fps):
    """Closed (exactly 0, silence) at every frame outside every word, open inside each word,
    and the bilabials' closures (m) inside the words."""
    n = int(DURATION * fps)
    tr = peer_track("openfacefx-text", vowel_burst(), SR, n_frames=n, fps=fps, words=SENTENCE,
                    each_word=True)
    t = np.arange(n) / fps
    inside = [(t >= s) & (t < e) for s, e, _ in SENTENCE]
    outside = ~np.logical_or.reduce(inside)
    assert outside.sum() > 10
    assert np.all(tr.opening[outside] == 0)
    assert np.all(tr.visemes[outside] == VISEMES.index("neutral"))
    for frames in inside:
        assert tr.opening[frames].max() > 0.3
    closed = t[tr.visemes == VISEMES.index("m")]
    for s, e, _ in SENTENCE:  # every word has a /b/ or /p/: each closes, inside itself
        assert np.any((closed >= s) & (closed < e))
    assert all(any(s <= x < e for s, e, _ in SENTENCE) for x in closed)


def test_a_word_segmented_alone_is_the_word_shifted_to_its_start():
    """Moving a word in time moves its track by as much (at frame-aligned starts)."""
    fps, n, shift = 30.0, 45, 12
    at = [peer_track("openfacefx-text", vowel_burst(), SR, n_frames=n, fps=fps, each_word=True,
                     words=[(k / fps, (k + shift) / fps, "papa")]).opening for k in (6, 18)]
    np.testing.assert_allclose(at[1][shift:], at[0][:-shift], atol=1e-9)
    assert at[0].max() > 0.3


def test_each_word_differs_from_the_anchored_alignment_only_in_where_the_mouth_may_move():
    """The anchored alignment lets the package's coarticulation open the mouth before the first
    word; each word alone never does. Pause tokens are dropped in both."""
    fps, n = 30.0, 45
    anchored = peer_track("openfacefx-text", vowel_burst(), SR, n_frames=n, fps=fps,
                          words=SENTENCE)
    alone = peer_track("openfacefx-text", vowel_burst(), SR, n_frames=n, fps=fps,
                       words=[(0.0, 0.2, "sil"), *SENTENCE, (1.3, 1.5, "sp")], each_word=True)
    t = np.arange(n) / fps
    before = t < SENTENCE[0][0]
    assert anchored.opening[before].max() > 0 and alone.opening[before].max() == 0
