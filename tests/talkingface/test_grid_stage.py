"""A grid stage described once (talkingface.stages.grid.GridStage): its setting, its stage entry,
its children's tags, and the one command-line option that names the ablation grid."""
from pathlib import Path

import pytest

from groundwork.errors import ParameterError
from talkingface.cli.args import grid_overrides
from talkingface.cli.main import build_parser
from talkingface.config import Config, load_config
from talkingface.stages import GRID_STAGES, STAGES
from talkingface.stages.articulation import every_articulation_file
from talkingface.stages.grid import ABLATIONS, CEILING, VOICES

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("grid", list(GRID_STAGES.values()), ids=list(GRID_STAGES))
def test_a_grid_stage_is_registered_from_its_description(grid):
    stage = STAGES[grid.name]
    assert stage.resumable is grid.resumable is True
    assert f"{grid.name}.grid" in stage.config
    assert set(grid.settings) <= set(stage.config)
    cfg = Config()
    assert grid.grid_path(cfg) == REPO / "configs" / f"{grid.name}.yaml" == grid.default
    files = stage.files(None, cfg)
    assert stage.enabled(cfg) and files[0] == grid.default
    # the grid's children may draw faces with any shipped articulation model: each one's content
    # joins the stage's key, and nothing else does
    assert set(files[1:]) == set(
        every_articulation_file(None, cfg) if grid.name in ("voices", "ceiling") else [])
    assert list(grid.children(cfg))
    off = load_config(None, [f"{grid.name}.grid=none"])
    assert grid.grid_path(off) is None and not stage.enabled(off)
    assert stage.files(None, off) == []


def test_the_children_carry_their_own_kind_s_tags():
    assert ABLATIONS.child_tags("paper", 2002, 0) == {
        "grid": "ablations", "ablation.setting": "paper", "ablation.seed": 2002,
        "ablation.replicate": 0, "ablation.stage": "ablate"}
    assert CEILING.child_tags("ours", 3002, 1) == {
        "grid": "ceiling", "ceiling.setting": "ours", "ceiling.seed": 3002,
        "ceiling.replicate": 1, "ceiling.stage": "ceiling"}
    assert VOICES.child_tags("one", 2002, 0) == {
        "grid": "voices", "voices.setting": "one", "voices.seed": 2002,
        "voices.replicate": 0, "voices.stage": "voices"}


def test_seeds_and_the_reference_child():
    cfg = load_config(None, ["ablations.seeds=4", "ceiling.seeds=2"])
    assert (ABLATIONS.seeds(cfg), CEILING.seeds(cfg), VOICES.seeds(cfg)) == (4, 2, 1)
    assert ABLATIONS.reference_child({"a": 0, "paper": 0}) == "paper"
    assert ABLATIONS.reference_child({"a": 0, "b": 0}) == "a"
    assert CEILING.reference_child({"ours": 0, "paper": 0}) == "ours"


def test_a_missing_grid_file_is_refused_naming_the_setting(tmp_path):
    cfg = load_config(None, [f"voices.grid={tmp_path / 'nope.yaml'}"])
    with pytest.raises(ParameterError, match=r"voices grid .*nope\.yaml not found \(voices\.grid"):
        VOICES.grid_file(None, cfg)


@pytest.mark.parametrize("argv", [
    ["replicate", "--name", "r", "--grid", "g.yaml"],
    ["replicate", "--name", "r", "--ablations", "g.yaml"],
    ["ablate", "--name", "r", "--grid", "g.yaml"],
    ["ablate", "--name", "r", "--ablations", "g.yaml"],
])
def test_grid_and_ablations_are_one_option(argv):
    args = build_parser().parse_args(argv)
    assert [o for o in grid_overrides(args) if o.startswith("ablations.grid")] == [
        "ablations.grid=g.yaml"]
