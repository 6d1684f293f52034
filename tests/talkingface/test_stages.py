"""The stage contract (talkingface.stages.base): reuse decided by exactly the declared config
keys, upstream fingerprints and input files; stale folders remade, never mixed; and the real
registry's rules for a study and a mapping setting."""
from __future__ import annotations

import dataclasses
import json

import pytest

from groundwork.errors import ParameterError
from talkingface.config import Config, load_config
from talkingface.paths import RunPaths
from talkingface.stages import REPLICATION, STAGES, stale
from talkingface.stages.base import Stage, prepare_run, read_done, run_stages, stale_stages


def _toy_stages(calls: list, text_file):
    """corpus ← units ← mapping, and tracking beside them: each records that it ran."""

    def make(name):
        def run(paths, cfg):
            calls.append(name)
            (paths.stage(name) / "out.txt").write_text(name)
            return {"ran": name}
        return run

    return {s.name: s for s in (
        Stage("corpus", make("corpus"), config=("seed", "synth"), speed_only=("synth.workers",),
              files=lambda paths, cfg: [text_file]),
        Stage("units", make("units"), config=("units",), upstream=("corpus",)),
        Stage("mapping", make("mapping"), config=("mapping",), upstream=("corpus", "units")),
        Stage("tracking", make("tracking"), config=("tracker.init",), upstream=("corpus",)),
        Stage("report", make("report"), always=True),
    )}


@pytest.fixture
def toy(tmp_path):
    calls: list = []
    text = tmp_path / "sentences.txt"
    text.write_text("One sentence.\n")
    stages = _toy_stages(calls, text)
    paths = RunPaths.create("toy", runs_dir=tmp_path / "runs", reports_dir=tmp_path / "reports")
    return stages, paths, calls, text


def test_a_finished_stage_is_reused_and_its_done_file_says_why(toy):
    stages, paths, calls, _ = toy
    cfg = Config()
    first = run_stages(["mapping", "tracking"], stages, paths, cfg)
    assert calls == ["corpus", "units", "mapping", "tracking"]
    again = run_stages(["mapping", "tracking"], stages, paths, cfg)
    assert calls == ["corpus", "units", "mapping", "tracking"]  # nothing ran twice
    assert again == first
    done = read_done(paths.stage("units"))
    assert done["key"]["config"] == {"units": dataclasses.asdict(cfg.units)}
    assert done["key"]["upstream"] == {"corpus": first["corpus"]["fingerprint"]}
    assert (paths.stage("units") / "config.yaml").is_file()


@pytest.mark.parametrize("override, reruns", [
    ("units.n_utterance=6", ["units", "mapping"]),
    ("mapping.train.max_epochs=3", ["mapping"]),
    ("tracker.init=corners", ["tracking"]),
    ("tracker.workers=1", []),  # not in any key
    ("synth.workers=1", []),  # speed only
    ("seed=7", ["corpus", "units", "mapping", "tracking"]),
    ("study.n_participants=4", []),
])
def test_a_changed_setting_reruns_its_stage_and_what_reads_it(toy, override, reruns):
    stages, paths, calls, _ = toy
    run_stages(["mapping", "tracking"], stages, paths, Config())
    cfg = load_config(None, [override])
    assert stale_stages(["mapping", "tracking"], stages, paths, cfg) == reruns
    calls.clear()
    run_stages(["mapping", "tracking"], stages, paths, cfg)
    assert calls == reruns


def test_a_changed_input_file_reruns_and_a_missing_done_file_remakes_the_folder(toy):
    stages, paths, calls, text = toy
    run_stages(["mapping"], stages, paths, Config())
    text.write_text("Another sentence.\n")
    calls.clear()
    run_stages(["mapping"], stages, paths, Config())
    assert calls == ["corpus", "units", "mapping"]
    # an interrupted stage: its leftovers are removed, never mixed with the new results
    (paths.stage("units") / "done.json").unlink()
    (paths.stage("units") / "half_written.npz").write_text("x")
    calls.clear()
    run_stages(["units"], stages, paths, Config())
    assert calls == ["units"] and not (paths.stage("units") / "half_written.npz").exists()


def test_the_report_is_never_reused_and_unknown_stages_are_refused(toy):
    stages, paths, calls, _ = toy
    run_stages(["report"], stages, paths, Config())
    run_stages(["report"], stages, paths, Config())
    assert calls == ["report", "report"]
    with pytest.raises(ParameterError, match=r"unknown stage 'nope'; allowed: corpus, units"):
        run_stages(["nope"], stages, paths, Config())


def test_a_run_refuses_other_settings_unless_overwrite_and_deletes_nothing(tmp_path):
    paths = RunPaths.create("r", runs_dir=tmp_path / "runs")
    prepare_run(paths, Config(), overwrite=False)
    (paths.root / "corpus").mkdir()
    prepare_run(paths, load_config(None, ["synth.workers=1", "mlflow.enabled=false"]),
                overwrite=False)  # speed and logging settings: the same run
    with pytest.raises(ParameterError, match="was made with a different config"):
        prepare_run(paths, load_config(None, ["seed=1"]), overwrite=False)
    prepare_run(paths, load_config(None, ["seed=1"]), overwrite=True)
    assert (paths.root / "corpus").is_dir()  # kept: the stages decide what is remade
    assert "seed: 1" in paths.config.read_text()


def test_the_replication_order_runs_every_stage_after_what_it_reads():
    assert set(REPLICATION) == set(STAGES)
    for i, name in enumerate(REPLICATION):
        assert all(REPLICATION.index(u) < i for u in STAGES[name].upstream), name


def test_real_stages_declare_what_a_study_and_a_mapping_setting_rerun(tmp_path):
    """The registry's rules on a run whose stages all look finished (fingerprints written as
    run_stages would write them, without running anything heavy)."""
    from talkingface.stages.base import fingerprint, stage_key

    paths = RunPaths.create("r", runs_dir=tmp_path / "runs")
    cfg = Config()
    for name in REPLICATION:
        stage = STAGES[name]
        if not stage.enabled(cfg) or stage.always:
            continue
        paths.stage(name).mkdir(parents=True)
        fp = fingerprint(stage_key(stage, STAGES, paths, cfg))
        (paths.stage(name) / "done.json").write_text(json.dumps({"fingerprint": fp}))
    assert stale(REPLICATION, paths, cfg) == ["report"]
    study = load_config(None, ["study.n_participants=12"])
    assert stale(REPLICATION, paths, study) == ["study_data", "analysis", "report"]
    mapping = load_config(None, ["mapping.hidden_max=30"])
    # the voice-robust models are trained with the run's mapping settings too
    assert stale(REPLICATION, paths, mapping) == ["mapping", "voices", "speech_eval", "render",
                                                  "stimuli", "study_data", "analysis",
                                                  "ablations", "ceiling", "real_speaker",
                                                  "real_faces", "real_steps", "report"]
    tracked = load_config(None, ["mapping.visual_source=tracked"])
    assert stale(REPLICATION, paths, tracked)[:2] == ["tracked", "mapping"]


def test_a_failing_stage_leaves_the_previous_result_exactly_as_it_was(toy):
    stages, paths, calls, _ = toy
    run_stages(["units"], stages, paths, Config())
    before = {p.name: p.read_bytes() for p in paths.stage("units").iterdir()}

    def broken(p, cfg):
        (p.stage("units") / "out.txt").write_text("half")
        raise RuntimeError("killed mid-way")

    stages["units"] = dataclasses.replace(stages["units"], run=broken)
    with pytest.raises(RuntimeError, match="killed mid-way"):
        run_stages(["units"], stages, paths, load_config(None, ["units.n_utterance=6"]))
    assert {p.name: p.read_bytes() for p in paths.stage("units").iterdir()} == before
    # the next run clears what the failed build left and builds afresh
    stages["units"] = _toy_stages(calls, paths.root / "x")["units"]
    run_stages(["units"], stages, paths, load_config(None, ["units.n_utterance=6"]))
    assert not list(paths.root.glob(".*"))  # no .partial or .replaced folder left


def _two_tasks(name: str, seen: list, kill: bool):
    """A stage ``name`` of two tasks, each skipped when its file is there; with ``kill`` the
    second one dies (a lost scheduler). ``seen`` gets what the stage found in its folder."""

    def run(p, cfg):
        folder = p.stage(name)
        seen.append(sorted(f.name for f in folder.iterdir()))
        for task in ("a", "b"):
            if not (folder / task).is_file():
                if task == "b" and kill:
                    raise RuntimeError("scheduler lost")
                (folder / task).write_text(task)
        return {"tasks": 2}
    return run


def test_a_resumable_stage_goes_on_from_an_interrupted_build_of_the_same_key_only(toy):
    stages, paths, calls, _ = toy
    seen: list = []
    units = stages["units"]
    same = load_config(None, ["units.n_expression=1"])
    stages["units"] = dataclasses.replace(units, run=_two_tasks("units", seen, True),
                                          resumable=True)
    with pytest.raises(RuntimeError, match="scheduler lost"):
        run_stages(["units"], stages, paths, same)
    assert seen == [["building.json"]]  # a fresh build, with the key it is built under
    assert not paths.stage("units").exists()  # nothing half-made under the final name
    # the same settings again: the finished task a is still there, and only b runs
    stages["units"] = dataclasses.replace(units, run=_two_tasks("units", seen, False),
                                          resumable=True)
    run_stages(["units"], stages, paths, same)
    assert seen[-1] == ["a", "building.json"]
    assert sorted(f.name for f in paths.stage("units").iterdir()) == [
        "a", "b", "config.yaml", "done.json"]  # the build's own record is not left in it
    # other settings: an interrupted build is not theirs, so they start from nothing
    stages["units"] = dataclasses.replace(units, run=_two_tasks("units", seen, True),
                                          resumable=True)
    with pytest.raises(RuntimeError, match="scheduler lost"):
        run_stages(["units"], stages, paths, load_config(None, ["units.n_utterance=5"]))
    stages["units"] = dataclasses.replace(units, run=_two_tasks("units", seen, False),
                                          resumable=True)
    run_stages(["units"], stages, paths, load_config(None, ["units.n_utterance=6"]))
    assert seen[-1] == ["building.json"]
    # and a stage that is not resumable never goes on from one
    tracking = stages["tracking"]
    stages["tracking"] = dataclasses.replace(tracking, run=_two_tasks("tracking", seen, True))
    with pytest.raises(RuntimeError, match="scheduler lost"):
        run_stages(["tracking"], stages, paths, Config())
    stages["tracking"] = dataclasses.replace(tracking, run=_two_tasks("tracking", seen, False))
    run_stages(["tracking"], stages, paths, Config())
    assert seen[-2:] == [[], []]


def test_a_guard_refuses_to_replace_a_folder(toy):
    stages, paths, calls, _ = toy
    run_stages(["units"], stages, paths, Config())

    def refuse(folder):
        raise ParameterError(f"{folder} holds real participants")

    stages["units"] = dataclasses.replace(stages["units"], guard=refuse)
    before = (paths.stage("units") / "done.json").read_bytes()
    with pytest.raises(ParameterError, match="holds real participants"):
        run_stages(["units"], stages, paths, load_config(None, ["units.n_utterance=6"]))
    assert (paths.stage("units") / "done.json").read_bytes() == before


def test_study_data_with_real_participants_is_never_replaced(tmp_path):
    from talkingface.stages.study import keep_real_participants, real_participants

    folder = tmp_path / "study_data"
    for pid, simulated in (("SIM01", "true"), ("P01", "false")):
        (folder / f"sub-{pid}").mkdir(parents=True)
        (folder / f"sub-{pid}" / f"sub-{pid}_task-emotion_beh.csv").write_text(
            f"\ufeffparticipant_id,simulated\n{pid},{simulated}\n")
    assert real_participants(folder) == ["P01"]
    with pytest.raises(ParameterError, match=r"holds the judgments of real participants \(P01\)"):
        keep_real_participants(folder)
    (folder / "sub-P01" / "sub-P01_task-emotion_beh.csv").unlink()
    keep_real_participants(folder)  # simulated only: may be remade


def test_a_stage_that_fails_leaves_its_previous_folder_and_no_partial(toy):
    """A full disk (or any error) in a stage: the finished folder of the previous build as it
    was, no ``.<stage>.partial`` left filling the disk; a resumable stage keeps its partial
    folder, whose finished parts the same command goes on from."""
    import errno

    stages, paths, calls, _ = toy
    run_stages(["mapping"], stages, paths, Config())
    before = (paths.stage("mapping") / "out.txt").read_text()

    def full(p, cfg):
        (p.stage("mapping") / "half.txt").write_text("half")
        raise OSError(errno.ENOSPC, "No space left on device")

    for resumable in (False, True):
        failing = {**stages, "mapping": dataclasses.replace(stages["mapping"], run=full,
                                                            always=True, resumable=resumable)}
        with pytest.raises(OSError):
            run_stages(["mapping"], failing, paths, Config())
        assert (paths.stage("mapping") / "out.txt").read_text() == before
        partial = paths.root / ".mapping.partial"
        assert partial.exists() == resumable
        if resumable:
            assert (partial / "half.txt").is_file()
