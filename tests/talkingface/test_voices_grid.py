"""The voices grid (configs/voices.yaml): what its children may change, and its default model."""
import dataclasses
from pathlib import Path

import pytest

from groundwork.errors import ParameterError
from talkingface.config import Config, load_config
from talkingface.stages.grid import VOICES
from talkingface.stages.grid_files import load_voices_grid

GRID = """model: {model}
base:
  mapping.splits: [utterance]
children:
  one: {{}}
  many:
    synth.voices: [espeak:en-us+f3, flite:awb]
    {extra}
"""


def test_the_project_grid_holds_the_issue_configurations():
    children, model = load_voices_grid(VOICES.default, Config())
    assert list(children) == ["one-voice", "many-voices", "many-cmvn", "many-cmvn-warp",
                              "many-cmvn-warp-augment", "many-cmvn-warp-augment-recogniser",
                              "one-voice-recogniser", "one-voice-phones", "many-phones",
                              "many-augment-phones", "one-voice-phones-labels",
                              "many-phones-labels", "one-voice-hama-labels",
                              "one-voice-causal-labels", "many-causal-labels",
                              "fitted-one-voice", "fitted-causal-labels",
                              "real-face-hama-labels", "real-face-mfcc",
                              "real-face-causal-labels", "real-and-drawn-hama-labels"]
    assert model == "one-voice-recogniser"  # tools/choose_voice_model.py runs/<name> --check
    assert [children[n].voices.real_face for n in list(children)[-5:]] == \
        ["none", "alone", "alone", "alone", "added"]
    # the fitted articulation's children: the paper's single voice, the fitted faces
    for name, like in (("fitted-one-voice", "one-voice"),
                       ("fitted-causal-labels", "one-voice-causal-labels")):
        assert children[name].synth.articulation == "grid-s1"
        assert children[name].mapping == children[like].mapping
        assert dataclasses.replace(children[name].synth, articulation="table") == \
            children[like].synth
    assert children["real-face-causal-labels"].mapping == \
        children["one-voice-causal-labels"].mapping
    assert children["real-face-hama-labels"].mapping == children["one-voice-hama-labels"].mapping
    full = children["many-cmvn-warp-augment"].mapping
    assert full.cmvn == "meanvar" and full.vtlp_range == (0.9, 1.1) and full.augment.copies >= 1
    default = children[model].mapping
    assert (default.gate_front_end, default.mlp_input, default.recogniser) == (
        "recogniser", "mfcc", "pocketsphinx")  # pocketsphinx's phones gate, the MLPs read MFCC
    assert children["many-phones"].synth == children["many-augment-phones"].synth
    assert children["many-phones-labels"].mapping.phone_training == "labels"
    hama = children["one-voice-hama-labels"].mapping
    assert (hama.recogniser, hama.gate_front_end, hama.mlp_input, hama.phone_training) == \
        ("hama", "recogniser", "phones", "labels")
    assert children["one-voice-phones"].mapping.recogniser == "pocketsphinx"
    causal = children["one-voice-causal-labels"].mapping
    assert causal == hama.__class__(**{
        **hama.__dict__, "recogniser": "causal"})  # the hama child with our front end
    assert children["many-causal-labels"].synth == children["many-phones-labels"].synth
    for name in ("one-voice", "one-voice-recogniser", "one-voice-phones",
                 "one-voice-phones-labels", "one-voice-hama-labels", "one-voice-causal-labels"):
        assert children[name].synth == Config().synth  # the paper's single voice
    # no evaluation speaker is a training voice of the default model: a0009 stays unseen
    from data_synth.backends import voice_speaker

    sources = {voice_speaker(v) for v in children[model].synth.voices}
    assert "arctic-slt" not in sources


def test_the_real_face_children_are_left_out_of_a_run_without_a_real_speaker(tmp_path):
    off = load_config(None, ["real_speaker.corpus="])
    children, model = load_voices_grid(VOICES.default, off)
    assert all(c.voices.real_face == "none" for c in children.values()) and len(children) == 17
    grid = tmp_path / "g.yaml"
    grid.write_text(GRID.format(model="real", extra="").replace(
        "children:", "children:\n  real: {voices.real_face: alone}"))
    assert set(load_voices_grid(grid, Config())[0]) == {"one", "many", "real"}
    with pytest.raises(ParameterError, match=r"g\.yaml: 'model' 'real' trains on the real "
                                             r"speaker \(voices\.real_face: alone\), which "
                                             r"this run has none of"):
        load_voices_grid(grid, off)


@pytest.mark.parametrize("model, extra, names", [
    ("many", "synth.n_sentences: 7", ["'many'", "synth.voices"]),
    ("many", "seed: 3", ["'many'", "seed"]),
    ("nobody", "", ["'nobody'", "one, many"]),
    ("many", "synth.voice_weights: [1, 2, 3]", ["synth.voice_weights"]),
])
def test_a_child_may_change_only_voices_and_mapping(tmp_path, model, extra, names):
    grid = tmp_path / "g.yaml"
    grid.write_text(GRID.format(model=model, extra=extra))
    with pytest.raises(ParameterError) as info:
        load_voices_grid(grid, Config())
    for n in names:
        assert n in str(info.value), str(info.value)


def test_a_malformed_grid_is_refused_before_a_run_is_touched(tmp_path, monkeypatch, capsys):
    from talkingface.cli.main import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "g.yaml").write_text("model: one\nchildren: [one]\n")
    code = main(["replicate", "--name", "r", "--voices", "g.yaml", "--set",
                 "mlflow.enabled=false"])
    assert code == 2 and "g.yaml" in capsys.readouterr().err
    assert not Path("runs").exists()


def test_none_switches_the_stage_off():
    cfg = load_config(None, ["voices.grid=none"])
    from talkingface.stages import stale
    from talkingface.paths import RunPaths

    assert "voices" not in stale(["voices", "speech_eval"], RunPaths.create("x"), cfg)
