"""What ``replicate`` prints when it ends: a line per stage with its wall and CPU seconds (from
done.json, which records both), or that it was reused."""
from __future__ import annotations

import time

from talkingface.config import Config
from talkingface.paths import RunPaths
from talkingface.stages.base import Stage, read_done, run_stages, time_summary


def _busy(name):
    def run(paths, cfg):
        t = time.process_time()
        while time.process_time() - t < 0.25:  # CPU work the record must count (os.times: 10-ms ticks)
            pass
        (paths.stage(name) / "out.txt").write_text(name)
        return {}
    return run


def test_summary_gives_wall_and_cpu_seconds_and_names_reused_stages(tmp_path):
    stages = {s.name: s for s in (Stage("corpus", _busy("corpus"), config=("seed",)),
                                  Stage("units", _busy("units"), config=("units",),
                                        upstream=("corpus",)))}
    paths = RunPaths.create("t", runs_dir=tmp_path / "runs")
    run_stages(["corpus"], stages, paths, Config())
    done_corpus = read_done(paths.stage("corpus"))
    assert done_corpus["cpu_seconds"] >= 0.19 and done_corpus["seconds"] >= 0.19
    time.sleep(0.05)
    since = time.time()
    done = run_stages(["units"], stages, paths, Config())
    lines = time_summary(done, paths, since)
    assert lines[0].split() == ["corpus", "reused"]
    units = read_done(paths.stage("units"))
    assert lines[1].split() == ["units", f"{units['seconds']:.1f}", "s", "wall",
                                f"{units['cpu_seconds']:.1f}", "s", "CPU"]
    assert lines[2].split()[:2] == ["total", f"{units['seconds']:.1f}"]
