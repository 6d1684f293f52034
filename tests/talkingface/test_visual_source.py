"""--visual-source tracked: the mapping learns from the corpus as the MU-constrained tracker
sees it (paper §V), and the setting is validated wherever it is given."""
import contextlib
import io
import json
import shutil

import numpy as np
import pytest

from face_model.corpus import corpus_hash, load_corpus
from groundwork.errors import ParameterError
from mapping.checkpoint import AudioMapping
from talkingface.cli.main import main
from talkingface.config import Config, load_config

TINY = ["--set", "synth.n_sentences=4", "--set", "synth.workers=2", "--set", "real_speaker.corpus=''"]
# what the tracked source changes is where the training's targets come from, not how long it
# trains: a few epochs make the same model files, metadata and stage records (`track` reads no
# mapping setting; its run records them, so `train` must be given the same)
SMALL_TRAIN = ["--set", "mapping.baselines=[linear]", "--set", "mapping.splits=[utterance]",
               "--set", "mapping.train.max_epochs=5"]


@pytest.fixture(scope="session")
def tracked_run(shared_build):
    """A folder with ``runs/v`` made by ``talkingface track`` (its corpus, Motion Units and the
    tracked copy of the corpus) and what the command printed (``track.out``), made once per test
    run (tests/conftest.py); read-only, tests that run more commands copy it."""
    def build(root):
        out = io.StringIO()
        with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(out):
            mp.chdir(root)
            mp.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{root / 'mlflow.db'}")
            assert main(["track", "--name", "v", *TINY, *SMALL_TRAIN]) == 0
        (root / "track.out").write_text(out.getvalue())

    return shared_build("tracked_run", build)


def test_train_on_tracked_mups(tracked_run, workdir):
    """`train --visual-source tracked` reuses the tracked corpus `track` made and trains on it:
    the models record the tracked corpus's hash, not the markers' (a training of a few epochs,
    not logged to MLflow: the provenance is the same at any length)."""
    out = (tracked_run / "track.out").read_text()  # what `track --name v` printed
    assert "utterances" in out and "marker error mean" in out
    shutil.copytree(tracked_run / "runs", workdir / "runs")
    run = workdir / "runs" / "v"
    tracked = load_corpus(run / "tracked")
    original = load_corpus(run / "corpus")
    assert [u.utt_id for u in tracked.utterances] == [u.utt_id for u in original.utterances]
    stamp = (run / "tracked" / "done.json").stat().st_mtime_ns

    # not logged: what it trains on is in its files (MLflow's logging is tested on its own)
    assert main(["train", "--name", "v", *TINY, *SMALL_TRAIN, "--visual-source", "tracked",
                 "--set", "mlflow.enabled=false"]) == 0
    assert (run / "tracked" / "done.json").stat().st_mtime_ns == stamp  # reused, not redone
    done = json.loads((run / "mapping" / "done.json").read_text())
    assert done["config"]["mapping"]["visual_source"] == "tracked"
    model = AudioMapping.load(run / "mapping" / "gated_mlp_utterance.tfmap")
    assert model.metadata["corpus_hash"] == corpus_hash(run / "tracked")
    assert model.metadata["corpus_hash"] != corpus_hash(run / "corpus")


def test_the_tracked_mups_differ_from_the_marker_mups_by_the_tracking_error(tracked_run):
    """Through the same MUs, the tracked corpus gives MUPs close to, not equal to, the
    markers': the large utterance MUPs follow the markers' closely; the small ones carry the
    tracking error (a quarter-pixel is a good part of their range)."""
    from face_model.motion_units import MotionUnits
    from mapping import build_dataset

    # made by `talkingface track`, which reads no mapping setting: the corpus, units and
    # tracked copy are those of `track` with TINY alone
    run = tracked_run / "runs" / "v"
    units = MotionUnits.load(run / "units" / "motion_units.npz")
    a = build_dataset(load_corpus(run / "corpus"), units)
    b = build_dataset(load_corpus(run / "tracked"), units)
    ya = np.concatenate([u.mups for u in a])
    yb = np.concatenate([u.mups for u in b])
    assert ya.shape == yb.shape and not np.array_equal(ya, yb)
    r = [np.corrcoef(ya[:, i], yb[:, i])[0, 1] for i in range(ya.shape[1])]
    assert min(r[:3]) > 0.97, r


@pytest.mark.parametrize("assignment, message", [
    ("mapping.visual_source=video", r"mapping\.visual_source is 'video'; allowed: markers, "
                                    r"tracked"),
    ("tracker.init=nose", r"tracker\.init is 'nose'; allowed: image, corners, markers"),
])
def test_closed_choices_are_checked_when_the_config_is_read(assignment, message):
    with pytest.raises(ParameterError, match=message):
        load_config(None, [assignment])


def test_an_ablation_child_may_not_change_the_visual_source(tmp_path):
    from talkingface.stages.grid_files import load_grid

    grid = tmp_path / "g.yaml"
    grid.write_text("children:\n  t: {mapping.visual_source: tracked}\n")
    with pytest.raises(ParameterError, match=r"child 't' changes the visual source"):
        load_grid(grid, Config())
