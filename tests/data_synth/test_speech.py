"""Speech synthesis interface: phone events → contiguous 44-class segments, and espeak-ng."""
from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from data_synth import backends, speech
from data_synth.backends import get_backend
from data_synth.espeak import ESPEAK_TO_CLASS, EspeakBackend
from data_synth.speech import (
    RawPhone,
    SpeechBackend,
    SynthRequest,
    SynthResult,
    phone_segments,
)
from face_model.corpus import PhoneSegment
from face_model.phones import PHONE_INDEX, PHONES
from groundwork.errors import ParameterError


class FakeBackend(SpeechBackend):
    """Phone events are given by the test; nothing is synthesised."""

    name = "fake"
    phone_map = {"_": "sil", "h": "hh", "@": "ax", "l": "l", "oU": "ow", "m": "m", "i:": "iy"}

    def synthesize_many(self, requests, *, workers, progress=None):
        raise AssertionError("not used")


FAKE = FakeBackend()
SR = 1000  # 1 sample = 1 ms, so the arithmetic in the tests is readable


def _result(n_samples: int, events) -> SynthResult:
    return SynthResult(audio=np.zeros(n_samples, np.int16), sample_rate=SR,
                       phones=[RawPhone(s, m) for s, m in events])


def _check_contiguous(segs, total_s):
    assert segs[0].start_s == 0.0
    assert segs[-1].end_s == pytest.approx(total_s, abs=1e-12)
    for a, b in zip(segs, segs[1:]):
        assert a.end_s == b.start_s
        assert a.end_s > a.start_s
        assert not (a.phone == b.phone == "sil")


def test_segments_are_the_events_shifted_by_the_lead_and_padded_with_silence():
    res = _result(500, [(0, "_"), (50, "h"), (120, "@"), (200, "l"), (300, "oU"), (450, "_")])
    segs = phone_segments(res, FAKE, text="hello", lead_samples=100, total_samples=800)
    assert segs == [PhoneSegment(0.0, 0.15, "sil"),  # lead padding + espeak's own pause, merged
                    PhoneSegment(0.15, 0.22, "hh"),
                    PhoneSegment(0.22, 0.30, "ax"),
                    PhoneSegment(0.30, 0.40, "l"),
                    PhoneSegment(0.40, 0.55, "ow"),
                    PhoneSegment(0.55, 0.80, "sil")]  # final pause + trailing padding
    _check_contiguous(segs, 0.8)


def test_silence_is_added_where_the_backend_reports_none():
    res = _result(300, [(20, "m"), (150, "i:")])
    segs = phone_segments(res, FAKE, text="me", lead_samples=200, total_samples=700)
    assert [(s.phone, s.start_s, s.end_s) for s in segs] == [
        ("sil", 0.0, 0.22), ("m", 0.22, 0.35), ("iy", 0.35, 0.5), ("sil", 0.5, 0.7)]


def test_zero_length_events_are_dropped_and_positions_clipped_to_the_audio():
    res = _result(300, [(0, "m"), (100, "h"), (100, "@"), (250, "l"), (400, "oU")])
    segs = phone_segments(res, FAKE, text="x", lead_samples=0, total_samples=300)
    assert [(s.phone, s.start_s, s.end_s) for s in segs] == [
        ("m", 0.0, 0.1), ("ax", 0.1, 0.25), ("l", 0.25, 0.3)]


def test_unknown_mnemonic_is_refused_naming_it_and_the_text():
    res = _result(300, [(0, "m"), (100, "Q!")])
    with pytest.raises(ParameterError, match=r"fake produced phone 'Q!' \(in 'the text'\) that has "
                                             r"no mapping to the 44 classes; known: "):
        phone_segments(res, FAKE, text="the text", lead_samples=10, total_samples=400)


@given(gaps=st.lists(st.integers(0, 120), min_size=1, max_size=25),
       mnemonics=st.lists(st.sampled_from(sorted(FakeBackend.phone_map)), min_size=25,
                          max_size=25),
       lead=st.integers(1, 300), tail=st.integers(0, 200), trail=st.integers(1, 300))
def test_segments_always_cover_the_padded_audio(gaps, mnemonics, lead, tail, trail):
    samples = np.cumsum([0, *gaps[1:]]).tolist()
    n_speech = samples[-1] + tail
    res = _result(n_speech, list(zip(samples, mnemonics)))
    total = lead + n_speech + trail
    segs = phone_segments(res, FAKE, text="t", lead_samples=lead, total_samples=total)
    _check_contiguous(segs, total / SR)
    assert segs[0].phone == "sil" and segs[-1].phone == "sil"
    assert segs[0].end_s >= lead / SR and segs[-1].start_s <= (lead + n_speech) / SR
    # Every event of positive length appears, in order, with its class.
    durations = np.diff([*samples, n_speech])
    kept = [FakeBackend.phone_map[m] for m, d in zip(mnemonics, durations) if d > 0]
    non_sil = [p for p in kept if p != "sil"]
    assert [s.phone for s in segs if s.phone != "sil"] == non_sil


def test_espeak_table_maps_onto_all_44_classes():
    assert set(ESPEAK_TO_CLASS.values()) == set(PHONES)


def test_espeak_synthesis_is_deterministic_and_timed():
    backend = get_backend("espeak")
    assert backend.sample_rate == 22050
    text = "The quick brown fox jumps over the lazy dog."
    reqs = [SynthRequest(text), SynthRequest("Maybe we should meet at noon."), SynthRequest(text),
            SynthRequest(text, rate_wpm=120)]
    calls = []
    res = backend.synthesize_many(reqs, workers=2, progress=calls.append)
    assert calls == [1, 1, 1, 1]
    # The same request in another forked child gives the same bytes (the determinism trap).
    assert np.array_equal(res[0].audio, res[2].audio)
    assert res[0].phones == res[2].phones
    assert not np.array_equal(res[0].audio, res[1].audio)
    # A slower rate lengthens the audio by roughly the rate ratio.
    ratio = len(res[3].audio) / len(res[0].audio)
    assert 1.15 < ratio < 1.6
    for r in res:
        assert r.sample_rate == 22050 and r.audio.dtype == np.int16
        samples = [p.sample for p in r.phones]
        assert samples == sorted(samples) and 0 <= samples[0] and samples[-1] <= len(r.audio)
        lead = 4410
        segs = phone_segments(r, backend, text="", lead_samples=lead,
                              total_samples=lead + len(r.audio) + 4410)
        _check_contiguous(segs, (2 * 4410 + len(r.audio)) / 22050)
        assert all(s.phone in PHONE_INDEX for s in segs)
    phones = [s.phone for s in phone_segments(res[0], backend, text=text, lead_samples=0,
                                                total_samples=len(res[0].audio))]
    for expected in ("dh", "k", "w", "b", "r", "f", "jh", "z", "ow", "l", "d", "g"):
        assert expected in phones


def test_unknown_backend_is_refused():
    with pytest.raises(ParameterError, match="synth.backend 'festival' is unknown; allowed: "
                                             "espeak, flite"):
        get_backend("festival")


def test_backends_are_looked_up_by_name(monkeypatch):
    assert isinstance(get_backend("espeak"), EspeakBackend)
    assert isinstance(get_backend("espeak-ng"), EspeakBackend)
    monkeypatch.setattr(backends.shutil, "which", lambda name: None)
    with pytest.raises(ParameterError, match=r"synth\.backend 'flite' needs the flite program "
                                             r"\(apt-get install flite\); allowed: espeak, flite"):
        get_backend("flite")


def test_the_speech_interface_imports_no_backend():
    """The dependency is one-way: the backends import the interface, the lookup by name lives
    above both (data_synth.backends)."""
    tree = ast.parse(Path(speech.__file__).read_text())
    imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert not any((m or "").startswith("data_synth") for m in imported), imported
