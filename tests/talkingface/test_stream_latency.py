"""The live latency of a trained mapping, measured as ``talkingface stream`` measures it
(talkingface/stages/latency.py): a recording paced in real time through the streaming loop.
No wall-clock limit is asserted: only what the measurement guarantees (finite figures, a paced
stream, a 99th percentile no shorter than the look-ahead the animator must wait), the file it
writes read back by the development rule, and its errors."""
from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.dev_rule import LATENCY_FILE, latency_p99, read_latency
from groundwork.audio import read_wav
from groundwork.errors import ParameterError
from talkingface.stages.latency import RECORDING, measure_latency, measure_models
from tests.mapping.small_mapping import train_small
from tests.talkingface.test_animate import _write


@pytest.fixture(scope="module")
def tiny_model(small_corpus, tmp_path_factory):
    """A ``.tfmap`` of the paper's gated MLP trained briefly on the small corpus, beside its
    Motion Units (``<folder>/mapping/m.tfmap``, ``<folder>/units/motion_units.npz``)."""
    t = train_small(small_corpus, epochs=3)
    root = tmp_path_factory.mktemp("latency_model")
    (root / "units").mkdir()
    t.units.save(root / "units" / "motion_units.npz")
    return t.mapping.save(root / "mapping" / "m.tfmap")


@pytest.fixture(scope="module")
def one_second(small_corpus, tmp_path_factory):
    """One second of the small corpus's speech, as a 16 kHz WAV (the rate of the real set)."""
    from groundwork.audio import resample

    u = small_corpus.utterances[0]
    y = resample(np.asarray(u.audio, np.float32), sr_in=u.sample_rate, sr_out=16000)
    assert len(y) >= 16000
    return _write(tmp_path_factory.mktemp("latency_wav") / "one.wav", y[:16000], 16000)


def test_a_paced_stream_gives_finite_latency_no_shorter_than_the_look_ahead(tiny_model,
                                                                          one_second):
    res = measure_latency(tiny_model, one_second)
    assert res["paced"] is True
    assert res["seconds"] == pytest.approx(1.0, abs=1e-3)
    assert res["frames"] == pytest.approx(30, abs=1)
    for k in ("latency_p50_ms", "latency_p99_ms", "compute_p50_ms", "compute_p99_ms",
              "algorithmic_latency_ms"):
        assert math.isfinite(res[k]) and res[k] >= 0, k
    # a frame is emitted only once the audio up to its look-ahead has arrived
    assert res["latency_p99_ms"] >= res["algorithmic_latency_ms"] > 0
    assert res["latency_p99_ms"] >= res["latency_p50_ms"]


def test_models_are_measured_into_the_file_the_rule_reads(tiny_model, one_second, tmp_path):
    res = measure_models({"voices-a": tiny_model,
                          "voices-b": (tiny_model, tiny_model.parent.parent / "units"
                                       / "motion_units.npz", None)},
                         one_second, tmp_path, progress=False)
    assert read_latency(tmp_path) == res and (tmp_path / LATENCY_FILE).is_file()
    assert res["paced"] is True and res["chunk_s"] == 0.01
    assert res["seconds"] == pytest.approx(1.0, abs=1e-3)
    p99 = latency_p99(res)
    assert set(p99) == {"voices-a", "voices-b"} and all(math.isfinite(v) for v in p99.values())


def test_the_fixed_recording_is_a_real_sentence_of_the_speech_set():
    y, sr = read_wav(RECORDING)
    assert RECORDING.name == "awb_a0007.wav" and len(y) / sr == pytest.approx(4.0, abs=0.05)


def test_a_missing_model_or_recording_or_a_bad_chunk_is_refused(tiny_model, tmp_path):
    with pytest.raises(ParameterError, match=r"nope\.tfmap: model file not found"):
        measure_latency(tmp_path / "nope.tfmap")
    with pytest.raises(ParameterError, match=r"nope\.wav: recording file not found"):
        measure_latency(tiny_model, tmp_path / "nope.wav")
    with pytest.raises(ParameterError, match=r"chunk_s is 0; allowed: a number of seconds > 0"):
        measure_latency(tiny_model, chunk_s=0)
