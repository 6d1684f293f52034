"""``talkingface animate`` and ``stream`` on real WAV files, good and bad."""
import json
import subprocess
import wave

import numpy as np
import pytest

from talkingface.cli import main

TINY = ["--set", "synth.n_sentences=4", "--set", "synth.workers=2", "--set",
        "mapping.baselines=[]", "--set", "mapping.splits=[utterance]", "--set",
        "tracking.enabled=false"]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A run with a trained mapping (runs/t under a module-wide folder)."""
    import os

    root = tmp_path_factory.mktemp("animate")
    old = os.getcwd()
    os.chdir(root)
    try:
        assert main(["train", "--name", "t", *TINY]) == 0
    finally:
        os.chdir(old)
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
    from face_model.audio import read_wav, resample

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


def test_without_a_trained_run_the_message_says_how_to_get_one(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    wav = _write(tmp_path / "x.wav", np.zeros(2205), 22050)
    assert main(["animate", str(wav), "-o", str(tmp_path / "x.mp4")]) == 2
    assert "make replicate" in capsys.readouterr().err


def test_stream_reports_the_latency(trained, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(trained)
    wav = _write(tmp_path / "s.wav", _speech(trained, 22050, False)[:22050], 22050)
    assert main(["stream", str(wav), "--fast"]) == 0
    out = capsys.readouterr().out
    assert "30 frames streamed" in out and "algorithmic latency 112 ms" in out
    assert "compute per frame" in out
