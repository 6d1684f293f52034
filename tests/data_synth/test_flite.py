"""The flite speech backend: audio format, phone timing and mapping, determinism, prosody
controls, errors, and a small corpus generated with ``backend: flite``."""
import dataclasses
import subprocess
import wave

import numpy as np
import pytest

from data_synth import flite as flite_mod
from data_synth.backends import get_backend
from data_synth.flite import FLITE_TO_CLASS, FliteBackend, flite_features
from data_synth.generate import synthesize_corpus
from data_synth.speech import SynthRequest
from face_model.corpus import load_corpus
from face_model.phones import PHONE_INDEX
from groundwork.errors import ParameterError
from talkingface.config import Config

SR = 22050
# Sentences from data_synth/sentences.txt; the onset ones start with a sonorant (m, w, vowel),
# whose acoustic onset coincides with the phone boundary.
SENTENCES = ("My mother keeps her treasure in a cotton bag.",
             "We enjoyed a quiet morning by the mountain lake.",
             "A loud sound woke the whole town.",
             "The little boy found a coin in the garden.")


@pytest.fixture(scope="module")
def backend():
    return FliteBackend()


@pytest.fixture(scope="module")
def results(backend):
    return backend.synthesize_many([SynthRequest(t) for t in SENTENCES], workers=2)


def _f0_median(audio: np.ndarray, sr: int = SR) -> float:
    """Median autocorrelation F0 (Hz) over loud, clearly periodic 40 ms frames."""
    y = audio.astype(np.float64)
    frame, hop, vals = int(0.04 * sr), int(0.01 * sr), []
    lo, hi = int(sr / 400), int(sr / 50)
    for i in range(0, len(y) - frame, hop):
        x = y[i:i + frame] - y[i:i + frame].mean()
        if np.sqrt(np.mean(x ** 2)) < 500:
            continue
        ac = np.correlate(x, x, "full")[frame - 1:]
        k = lo + int(np.argmax(ac[lo:hi]))
        if ac[k] > 0.5 * ac[0]:
            vals.append(sr / k)
    assert len(vals) > 20
    return float(np.median(vals))


def test_backend_writes_22050_hz_int16(backend, results):
    assert backend.name == "flite" and backend.sample_rate == SR
    assert SR % 30 == 0 and SR // 30 == 735
    for res in results:
        assert res.sample_rate == SR and res.audio.dtype == np.int16 and res.audio.ndim == 1
        assert 0.5 * SR < len(res.audio) < 10 * SR
        assert np.abs(res.audio.astype(np.int32)).max() > 3000  # not silent
    assert backend.version().startswith("flite 2.") and "slt" in backend.version()
    assert isinstance(get_backend("flite"), FliteBackend)


def test_phones_are_ordered_inside_the_audio_and_mapped(backend, results):
    for text, res in zip(SENTENCES, results):
        samples = [p.sample for p in res.phones]
        assert samples[0] == 0 and samples == sorted(samples)
        assert samples[-1] < len(res.audio)
        assert res.phones[0].mnemonic == "pau" and res.phones[-1].mnemonic == "pau"
        assert len(res.phones) > 15
        for p in res.phones:
            assert backend.to_class(p.mnemonic, text=text) in PHONE_INDEX


def test_phone_map_targets_the_44_classes():
    assert set(FLITE_TO_CLASS.values()) <= set(PHONE_INDEX)
    assert FLITE_TO_CLASS["pau"] == "sil" and FLITE_TO_CLASS["ax"] == "ax"
    # every class but the silence is reachable from a flite symbol of the same name
    assert {p for p in PHONE_INDEX if p != "sil"} <= set(FLITE_TO_CLASS)


def test_same_request_twice_gives_identical_audio(backend):
    req = SynthRequest(SENTENCES[0], rate_wpm=150, pitch=60)
    a, b, c = backend.synthesize_many([req, req, req], workers=3)
    assert a.audio.tobytes() == b.audio.tobytes() == c.audio.tobytes()
    assert a.phones == b.phones == c.phones


def test_first_phone_starts_at_the_energy_onset(results):
    for text, res in list(zip(SENTENCES, results))[:3]:
        y = res.audio.astype(np.float64) / 32768.0
        win = int(0.005 * SR)
        rms = np.sqrt(np.convolve(y ** 2, np.ones(win) / win, mode="same"))
        onset = int(np.argmax(rms > 0.1 * rms.max()))  # -20 dB re the loudest 5 ms
        first = next(p for p in res.phones if p.mnemonic != "pau")
        assert abs(onset - first.sample) / SR < 0.030, (text, onset, first)


def test_results_keep_request_order_and_report_progress(backend):
    reqs = [SynthRequest(t) for t in ("Bob ate.", SENTENCES[1], "Hi.", SENTENCES[3])]
    calls = []
    batch = backend.synthesize_many(reqs, workers=4, progress=calls.append)
    assert calls == [1, 1, 1, 1]
    single = [backend.synthesize_many([r], workers=1)[0] for r in reqs]
    for got, want in zip(batch, single):
        assert got.audio.tobytes() == want.audio.tobytes() and got.phones == want.phones


def test_slower_rate_gives_longer_audio(backend):
    slow, normal, fast = backend.synthesize_many(
        [SynthRequest(SENTENCES[1], rate_wpm=r) for r in (110, 165, 220)], workers=3)
    assert len(slow.audio) > 1.3 * len(normal.audio) > 1.3 * 1.2 * len(fast.audio)
    assert slow.phones[-1].sample > normal.phones[-1].sample > fast.phones[-1].sample


def test_pitch_moves_the_f0(backend):
    low, high = backend.synthesize_many(
        [SynthRequest(SENTENCES[1], pitch=p) for p in (20, 80)], workers=2)
    assert _f0_median(high.audio) > 1.3 * _f0_median(low.audio)


def test_neutral_settings_are_the_voice_defaults(tmp_path):
    feats = flite_features(SynthRequest("x", rate_wpm=165, pitch=50, pitch_range=50))
    assert feats == {"duration_stretch": 1.0, "int_f0_target_mean": 172.0,
                     "int_f0_target_stddev": 27.0}
    args = [f for k, v in feats.items() for f in ("--setf", f"{k}={v:g}")]
    wavs = []
    for i, extra in enumerate(([], args)):
        path = tmp_path / f"{i}.wav"
        subprocess.run(["flite", "-voice", flite_mod.VOICE, *extra, "-o", str(path),
                        "-t", SENTENCES[2]], check=True, capture_output=True)
        with wave.open(str(path)) as w:
            assert w.getframerate() == flite_mod.VOICE_SAMPLE_RATE
        wavs.append(path.read_bytes())
    assert wavs[0] == wavs[1]


@pytest.mark.parametrize("changes", [dict(rate_wpm=0), dict(pitch=101), dict(pitch_range=-1)])
def test_bad_request_values_are_refused(backend, changes):
    with pytest.raises(ParameterError, match="flite"):
        backend.synthesize_many([SynthRequest("Hello there.", **changes)], workers=1)


def test_flite_failure_raises_parameter_error(backend, tmp_path, monkeypatch):
    fake = tmp_path / "fake-flite"
    fake.write_text("#!/bin/sh\necho 'cannot load voice data' >&2\nexit 3\n")
    fake.chmod(0o755)
    monkeypatch.setattr(flite_mod, "FLITE", str(fake))
    with pytest.raises(ParameterError, match=r"(?s)Say this please.*cannot load voice data"):
        backend.synthesize_many([SynthRequest("Say this please.")], workers=1)


def test_corpus_with_the_flite_backend_loads(tmp_path):
    cfg = dataclasses.replace(Config().synth, backend="flite", n_sentences=2,
                              expressions=("neutral",), workers=2)
    out = synthesize_corpus(tmp_path / "corpus", cfg, Config().seed, progress=False)
    corpus = load_corpus(out)
    assert len(corpus.utterances) == 2 and corpus.info["backend"].startswith("flite")
    for utt in corpus.utterances:
        assert utt.sample_rate == SR and len(utt.audio) == 735 * utt.markers.shape[0]
        phones = {s.phone for s in utt.phones}
        assert phones <= set(PHONE_INDEX) and len(phones - {"sil"}) > 5
        assert utt.phones[0].start_s == 0.0
        assert utt.phones[-1].end_s == pytest.approx(len(utt.audio) / SR, abs=1e-4)


def test_a_speech_program_that_never_finishes_is_stopped_and_one_line(monkeypatch):
    """A hung program (waiting on a sound device, say) is killed after its time, not waited on
    for ever."""
    from data_synth import speech
    from groundwork.errors import ParameterError

    monkeypatch.setattr(speech, "PROGRAM_TIMEOUT_S", 1)
    with pytest.raises(ParameterError, match=r"^sleeper did not finish within 2 s \(2 "
                                             r"utterances\); it was stopped"):
        speech.run_program(["sleep", "30"], what="sleeper", utterances=2)
    assert speech.run_program(["echo", "ok"], what="echo").stdout == "ok\n"
