"""``talkingface animate`` and ``stream`` on real WAV files, good and bad."""
import json
import shutil
import subprocess
import wave
from pathlib import Path

import numpy as np
import pytest

from talkingface.cli.main import main
from tests.talkingface.bad_input_cases import RUN


@pytest.fixture(scope="module")
def trained(small_run_dir, tmp_path_factory):
    """A run with a trained mapping (runs/t under a module-wide folder): a copy of the small
    run the suite shares (tests/conftest.py; 3 sentences, the gated MLP trained on the
    utterance split), the only run of the folder; ``train`` finds its mapping finished."""
    root = tmp_path_factory.mktemp("animate")
    shutil.copytree(small_run_dir / "runs" / "R", root / "runs" / "t")
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(root)
        assert main(["train", "--name", "t", *RUN]) == 0
    return root


def _write(path, y, sr, channels=1):
    y = np.clip(np.asarray(y), -1, 1)
    data = (y * 32767).astype("<i2")
    with wave.open(str(path), "wb") as w:
        w.setnchannels(channels)
        w.setsampwidth(2)
        w.setframerate(sr)
        w.writeframes(data.tobytes())
    return path


def _probe(path) -> dict:
    out = subprocess.run(["ffprobe", "-v", "error", "-show_entries",
                          "stream=codec_type,codec_name,r_frame_rate,duration", "-of", "json",
                          str(path)], capture_output=True, text=True, check=True).stdout
    return {s["codec_type"]: s for s in json.loads(out)["streams"]}


def _speech(trained, sr_out, stereo):
    from groundwork.audio import read_wav, resample

    wav = sorted((trained / "runs" / "t" / "corpus" / "audio").glob("*smile*.wav"))[0]
    y, sr = read_wav(wav)
    y = resample(y, sr_in=sr, sr_out=sr_out)
    return np.stack([y, 0.5 * y], 1).ravel() if stereo else y


def test_animate_a_16k_stereo_wav_into_an_mp4(trained, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(trained)
    wav = _write(tmp_path / "st.wav", _speech(trained, 16000, True), 16000, channels=2)
    out, npy, kf = tmp_path / "out.mp4", tmp_path / "m.npy", tmp_path / "k.csv"
    assert main(["animate", str(wav), "--expression", "smile", "-o", str(out),
                 "--markers", str(npy), "--keyframes", str(kf)]) == 0
    assert "real time" in capsys.readouterr().out
    streams = _probe(out)
    assert streams["video"]["codec_name"] == "h264"
    assert streams["video"]["r_frame_rate"] == "30/1"
    assert streams["audio"]["codec_name"] == "aac"
    with wave.open(str(wav)) as w:
        audio_s = w.getnframes() / w.getframerate()
    assert abs(float(streams["video"]["duration"]) - audio_s) <= 1 / 30 + 1e-6
    assert abs(float(streams["audio"]["duration"]) - audio_s) <= 1 / 30 + 1e-6
    markers = np.load(npy)
    assert markers.shape == (int(np.ceil(audio_s * 30)), 79, 2)
    assert np.all(np.isfinite(markers))
    from face_model.keyframes import KEYFRAMES, read_keyframe_tracks
    tracks = read_keyframe_tracks(kf)  # validates names, times at 1/30 s, finite weights
    assert tracks.weights.shape == (len(markers), len(KEYFRAMES))


def test_silence_animates_a_closed_neutral_mouth(trained, tmp_path, monkeypatch):
    from face_model.layout import LOWER_INNER, UPPER_INNER, default_layout

    monkeypatch.chdir(trained)
    wav = _write(tmp_path / "silence.wav", np.zeros(22050), 22050)
    npy = tmp_path / "m.npy"
    assert main(["animate", str(wav), "-o", str(tmp_path / "s.mp4"), "--markers", str(npy)]) == 0
    m = np.load(npy)
    neutral = default_layout().neutral
    gap = m[:, list(LOWER_INNER), 1].mean(1) - m[:, list(UPPER_INNER), 1].mean(1)
    rest = neutral[list(LOWER_INNER), 1].mean() - neutral[list(UPPER_INNER), 1].mean()
    assert np.all(np.abs(gap - rest) < 0.5)  # every frame: the neutral, closed mouth
    assert np.ptp(m, axis=0).max() < 1e-3  # and it does not move


def test_a_clipped_wav_is_animated_with_a_warning(trained, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(trained)
    wav = _write(tmp_path / "clip.wav", 8 * _speech(trained, 22050, False), 22050)
    assert main(["animate", str(wav), "-o", str(tmp_path / "c.mp4")]) == 0
    assert "clipped" in capsys.readouterr().err


@pytest.mark.parametrize("make, message", [
    (lambda p: _write(p, np.zeros(0), 22050), "holds no samples"),
    (lambda p: p.write_text("this is not audio") and p, "not a readable PCM WAV"),
    (lambda p: p, "not found"),
])
def test_bad_wavs_give_one_clear_error_line(trained, tmp_path, monkeypatch, capsys, make,
                                            message):
    monkeypatch.chdir(trained)
    wav = make(tmp_path / "bad.wav")
    assert main(["animate", str(wav), "-o", str(tmp_path / "b.mp4")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and "bad.wav" in err
    assert "Traceback" not in err
    assert not (tmp_path / "b.mp4").exists()


def test_without_a_trained_run_or_a_shipped_model_the_message_says_how_to_get_one(
        tmp_path, monkeypatch, capsys):
    """With a trained run, or the model shipped with the package (tests/talkingface/
    test_ship_default.py), animate has a model; with neither, one line says how to get one."""
    from talkingface.stages import models

    monkeypatch.setattr(models, "SHIPPED_DIR", tmp_path / "no_shipped_model")
    monkeypatch.chdir(tmp_path)
    wav = _write(tmp_path / "x.wav", np.zeros(2205), 22050)
    assert main(["animate", str(wav), "-o", str(tmp_path / "x.mp4")]) == 2
    err = capsys.readouterr().err
    assert "make replicate" in err and "no trained mapping under runs/" in err
    assert "no shipped default model" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.mp4").exists()


def test_stream_reports_the_latency(trained, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(trained)
    wav = _write(tmp_path / "s.wav", _speech(trained, 22050, False)[:22050], 22050)
    assert main(["stream", str(wav), "--fast"]) == 0
    captured = capsys.readouterr()
    out = captured.out
    assert "30 frames streamed" in out and "algorithmic latency 112 ms" in out
    assert "compute per frame" in out
    # the run's own model, not the shipped default, and the stream says which
    assert "model: runs/t/mapping/gated_mlp_utterance.tfmap" in captured.err


def test_a_paced_stream_never_beats_its_look_ahead(trained, tmp_path, monkeypatch):
    """Paced in real time, no frame can be emitted before its look-ahead has been captured:
    every measured latency is at least the algorithmic latency (less a chunk, 10 ms)."""
    from talkingface.cli.animate import stream_file

    monkeypatch.chdir(trained)
    wav = _write(tmp_path / "p.wav", _speech(trained, 22050, False)[:22050], 22050)
    res = stream_file(wav, paced=True)
    assert res["paced"] and res["frames"] == 30
    assert res["latency_p50_s"] >= res["algorithmic_latency_s"] - 0.0105
    assert res["latency_p50_s"] <= res["latency_p99_s"]


def test_stream_from_the_microphone(trained, tmp_path):
    """The real PortAudio path on ALSA's null device (no sound card here): one second of what
    it delivers streams into 30 frames; the null device is not paced, so no latency is
    claimed."""
    import os
    import sys

    home = tmp_path / "home"
    home.mkdir()
    (home / ".asoundrc").write_text("pcm.!default { type null }\n")
    repo = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "HOME": str(home),
           "PYTHONPATH": os.pathsep.join(filter(None, [repo, os.environ.get("PYTHONPATH")]))}
    run = subprocess.run([sys.executable, "-m", "talkingface.cli.main", "stream", "--mic",
                          "--seconds", "1"], cwd=trained, env=env, capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "30 frames streamed from 1.00 s of audio from the microphone (default" in run.stdout
    assert "no latency is measured" in run.stdout
    listed = subprocess.run([sys.executable, "-m", "talkingface.cli.main", "stream",
                             "--list-devices"], env=env, capture_output=True, text=True)
    assert listed.returncode == 0 and "default" in listed.stdout


class _FakeSoundDevice:
    """Stands in for the sounddevice module: a 48 kHz device that refuses other rates and
    reads a 440 Hz tone."""

    class PortAudioError(Exception):
        pass

    def __init__(self, devices):
        self.devices = devices
        self.t = 0

    def query_devices(self, device=None, kind=None):
        if kind is None:
            return self.devices
        return next(d for d in self.devices if d["max_input_channels"] > 0)

    def check_input_settings(self, *, samplerate, **kw):
        if samplerate != 48000:
            raise self.PortAudioError(f"Invalid sample rate {samplerate}")

    def InputStream(self, *, samplerate, blocksize, **kw):
        fake = self

        class Stream:
            def __enter__(self):
                return self

            def __exit__(self, *exc):
                return False

            def read(self, n):
                t = (fake.t + np.arange(n)) / samplerate
                fake.t += n
                tone = 0.3 * np.sin(2 * np.pi * 440 * t)
                return np.round(32767 * tone)[:, None].astype(np.int16), False

        assert samplerate == 48000
        return Stream()


def test_a_device_at_another_rate_is_resampled(monkeypatch):
    import talkingface.live as live

    fake = _FakeSoundDevice([{"name": "fake mic", "max_input_channels": 1,
                              "default_samplerate": 48000.0}])
    monkeypatch.setattr(live, "_sounddevice", lambda: fake)
    stats = live.MicrophoneStats()
    chunks = list(live.microphone_chunks(22050, seconds=0.5, stats=stats))
    y = np.concatenate([c for c, _ in chunks])
    assert stats.rate == 48000 and stats.device == "fake mic"
    assert abs(len(y) - 11025) <= 2
    spectrum = np.abs(np.fft.rfft(y[2000:2000 + 8192] * np.hanning(8192)))
    assert abs(np.argmax(spectrum) * 22050 / 8192 - 440) < 3


def test_microphone_errors_are_clear(trained, monkeypatch, capsys):
    import talkingface.live as live

    monkeypatch.setattr(live, "_sounddevice", lambda: _FakeSoundDevice(
        [{"name": "speakers", "max_input_channels": 0, "default_samplerate": 48000.0}]))
    monkeypatch.chdir(trained)
    assert main(["stream", "--mic", "--seconds", "1"]) == 2
    assert "no audio input device found" in capsys.readouterr().err
    assert main(["stream"]) == 2
    assert "give a WAV file or --mic" in capsys.readouterr().err
