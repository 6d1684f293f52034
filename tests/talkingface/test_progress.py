"""Progress of ``talkingface animate`` and ``stream --fast`` (issue 42): a bar over animate's
passes says what is done, one line what the recogniser costs (measured on the first seconds),
bars follow on stderr, and the outputs are byte for byte those of a run without them.

The models are the small run's (test_animate.py's ``trained``) and one whose gate is the
pocketsphinx recogniser, trained on the run's corpus (tests/mapping/small_mapping.py); hama's
own bar and cost line are tested in tests/mapping/test_progress_front.py."""
import re

import numpy as np
import pytest

from face_model.corpus import load_corpus
from mapping import recogniser
from mapping.recogniser import hearing_cache
from talkingface.cli.animate import animate_file, stream_file
from talkingface.cli.main import main
from tests.mapping.small_mapping import train_small
from tests.talkingface.test_animate import _speech, _write, trained  # noqa: F401 (a fixture)
from tests.terminal_text import screen_lines

COST = re.compile(r"(pocketsphinx|stream): (\d+\.\d) s of audio, ~\d+\.\d\d s of work per s of "
                  r"audio \(about \d+ (s|min)(, paced in real time)? on this machine, measured "
                  r"on the first \d+\.\d s\)")


@pytest.fixture(scope="module")
def phones_model(trained, tmp_path_factory):
    """A ``.tfmap`` whose gate is the pocketsphinx recogniser, beside its own Motion Units
    (``<folder>/mapping/p.tfmap``, ``<folder>/units/motion_units.npz``)."""
    t = train_small(load_corpus(trained / "runs" / "t" / "corpus"), epochs=5,
                    split="random_frames", gate_front_end="recogniser",
                    recogniser="pocketsphinx", min_class_frames=5)
    root = tmp_path_factory.mktemp("phones_model")
    (root / "units").mkdir()
    t.units.save(root / "units" / "motion_units.npz")
    return t.mapping.save(root / "mapping" / "p.tfmap")


@pytest.fixture
def wav(trained, tmp_path):
    """About 3 s of the run's speech at 22,050 Hz: longer than the recogniser's cost sample."""
    y = _speech(trained, 22050, False)
    return _write(tmp_path / "speech.wav", np.concatenate([y, y])[: 3 * 22050], 22050)


def _cost_lines(err: str) -> list[str]:
    return [ln for ln in screen_lines(err) if COST.fullmatch(ln)]


def test_animate_says_what_it_will_do_and_what_the_recogniser_costs(trained, phones_model, wav,
                                                                    tmp_path, monkeypatch,
                                                                    capsys):
    monkeypatch.chdir(trained)
    monkeypatch.setattr(recogniser, "_HEARD", {})  # heard afresh, not from the cache
    npy = tmp_path / "m.npy"
    with hearing_cache(None):  # and from no cache on disk
        assert main(["animate", str(wav), "-o", str(tmp_path / "a.mp4"), "--model",
                     str(phones_model), "--markers", str(npy)]) == 0
    err = capsys.readouterr().err
    n = len(np.load(npy))
    passes = f"animate 3.0 s of audio (~{n} frames at 30 fps): "
    first = err.index(f"{passes}  0%|")
    assert re.search(r"0/2 passes \[\d\d:\d\d, the phones heard by pocketsphinx, the network\]",
                     err)
    (cost,) = _cost_lines(err)
    assert cost.startswith("pocketsphinx: 3.0 s of audio") and "first 2.0 s" in cost
    # the front end's line, then its pass done, then the render's bar, then the render done
    assert first < err.index(cost) < err.index("1/2 passes [") < err.index("render:") \
        < err.index(f"{passes}100%|")
    assert "pocketsphinx: 100%" in err and "3.0/3.0 s" in err  # the recogniser's bar, to the end
    assert "render: 100%" in err and f"{n}/{n}" in err  # the render's bar, to the end


def test_animate_without_a_recogniser_names_its_two_passes(trained, wav, tmp_path, monkeypatch,
                                                          capsys):
    monkeypatch.chdir(trained)
    assert main(["animate", str(wav), "-o", str(tmp_path / "a.mp4")]) == 0
    err = capsys.readouterr().err
    assert "animate 3.0 s of audio (~90 frames at 30 fps):   0%|" in err
    assert re.search(r"0/2 passes \[\d\d:\d\d, the network\]", err) and "2/2 passes [" in err
    assert _cost_lines(err) == [] and "render: 100%" in err


@pytest.mark.parametrize("model", ["run", "phones"])
def test_animate_writes_the_same_bytes_with_and_without_progress(trained, phones_model, wav,
                                                                 tmp_path, monkeypatch, capsys,
                                                                 model):
    monkeypatch.chdir(trained)
    outs = {}
    for progress in (False, True):
        monkeypatch.setattr(recogniser, "_HEARD", {})
        d = tmp_path / str(progress)
        d.mkdir()
        animate_file(wav, d / "a.mp4", model=None if model == "run" else str(phones_model),
                     markers_out=d / "m.npy", progress=progress)
        outs[progress] = [(d / f).read_bytes() for f in ("a.mp4", "m.npy")]
        err = capsys.readouterr().err
        assert ("animate 3.0 s" in err) == progress and ("100%" in err) == progress
    assert outs[False] == outs[True]


def test_a_fast_stream_shows_its_cost_and_a_bar(trained, phones_model, wav, monkeypatch,
                                                capsys):
    monkeypatch.chdir(trained)
    assert main(["stream", str(wav), "--fast", "--model", str(phones_model)]) == 0
    captured = capsys.readouterr()
    assert "90 frames streamed" in captured.out
    (cost,) = _cost_lines(captured.err)
    assert cost.startswith("stream: 3.0 s of audio") and "paced" not in cost
    assert "stream: 100%" in captured.err and "3.0/3.0 s" in captured.err


@pytest.mark.parametrize("model", ["run", "phones"])
def test_a_stream_gives_the_same_frames_with_and_without_progress(trained, phones_model, wav,
                                                                  monkeypatch, capsys, model):
    monkeypatch.chdir(trained)
    frames = {}
    for progress in (False, True):
        got = []
        res = stream_file(wav, model=None if model == "run" else str(phones_model), paced=False,
                          on_frame=got.append, progress=progress)
        assert res["frames"] == len(got) == 90
        frames[progress] = got
        assert ("100%" in capsys.readouterr().err) == progress
    for a, b in zip(frames[False], frames[True]):
        assert a.index == b.index
        assert a.mups.tobytes() == b.mups.tobytes() and a.markers.tobytes() == b.markers.tobytes()
