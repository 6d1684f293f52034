"""Every stage of a run, its reuse rule, and the order ``replicate`` runs them in.

Each line of :data:`STAGES` is one stage's whole reuse rule (see :mod:`talkingface.stages.base`):
the config it depends on, the stages whose results it reads, and when the config switches it
off or the run's corpus rules out (:mod:`talkingface.stages.applies`: a given corpus, one
without smile and sad); a grid stage's rule is made from its
:class:`talkingface.stages.grid.GridStage` by :func:`_grid_stage`. :data:`REPLICATION` is the
order ``talkingface replicate`` runs them in; the other commands run the stages they need with
:func:`run`, which runs missing or stale upstream stages first.
"""
from __future__ import annotations

from talkingface.paths import RunPaths
from talkingface.stages.base import (Stage, prepare_run, read_done, run_order, run_stages,
                                     stale_stages)
from talkingface.stages.applies import study_applies, switched_off, synthesised
from talkingface.stages.articulation import (articulation_applies, articulation_files,
                                             evaluate_articulation, every_articulation_file)
from talkingface.stages.front_end import (front_end_applies, front_inputs, front_model_inputs,
                                          train_front_end)
from talkingface.stages.foundation import (fit_keyframes, fit_units, make_corpus, sentence_file,
                                           units_inputs)
from talkingface.stages.given_corpus import corpus_config, corpus_inputs
from talkingface.stages.motion import (evaluate_tracker, make_tracked_corpus, render_held_out,
                                       uses_tracked_corpus)
from talkingface.stages.report import build_report
from talkingface.stages.speech_eval import evaluate_speech, set_files
from talkingface.stages.study import (analyze, keep_real_participants, make_stimuli,
                                      simulate_participants)
from talkingface.stages.ablations import ablate
from talkingface.stages.ceiling import decompose
from talkingface.stages.grid import (ABLATIONS, CEILING, GRID_STAGES, REAL_STEPS, VOICES,
                                     GridStage)
from talkingface.stages.real_speaker import evaluate_real_speaker, real_inputs, \
    real_speaker_applies
from talkingface.stages.real_faces import (evaluate_real_faces, real_faces_applies,
                                           real_faces_inputs)
from talkingface.stages.real_steps import measure_real_steps
from talkingface.stages.training import train
from talkingface.stages.voices import train_voices, voices_inputs

_TRAINING_INPUTS = ("corpus", "units", "tracked")


def _with_files(*sources):
    """A stage's ``files``: the files of every source (``(paths, cfg) -> list``) in turn."""
    return lambda paths, cfg: [f for source in sources for f in source(paths, cfg)]


def _grid_stage(grid: GridStage, run, *, config: tuple, speed_only: tuple,
                applies=None, upstream: tuple = _TRAINING_INPUTS, inputs=None,
                files=None) -> Stage:
    """The stage of ``grid``: trained on ``upstream``'s results (the run's training inputs);
    its own settings (:attr:`GridStage.settings`), its grid file's contents and ``inputs``
    (``(paths, cfg) -> dict``: the data outside the run it reads) join its key, and so do the
    grid file and, while a grid is named, ``files`` (``(paths, cfg) -> list``); on when its
    config names a grid and, with ``applies`` (``cfg -> bool``), the run's corpus allows it;
    resumable as the grid stage says."""
    enabled = grid.has_grid if applies is None else (
        lambda cfg: grid.has_grid(cfg) and applies(cfg))
    own = grid.grid_file if files is None else (
        lambda paths, cfg: grid.grid_file(paths, cfg) + (
            files(paths, cfg) if grid.has_grid(cfg) else []))
    return Stage(grid.name, run, config=(*config, *grid.settings), speed_only=speed_only,
                 upstream=upstream, enabled=enabled, files=own,
                 resumable=grid.resumable, **({} if inputs is None else {"inputs": inputs}))


STAGES = {s.name: s for s in (
    Stage("corpus", make_corpus, config=corpus_config, speed_only=("synth.workers",),
          files=_with_files(sentence_file, articulation_files), inputs=corpus_inputs),
    Stage("units", fit_units, config=("units",), upstream=("corpus",), inputs=units_inputs),
    Stage("keyframes", fit_keyframes, upstream=("corpus", "units")),
    Stage("tracking", evaluate_tracker, config=("seed", "tracker.n_utterances",
          "tracker.noise_levels", "tracker.init"), upstream=("corpus", "units"),
          enabled=synthesised),
    Stage("tracked", make_tracked_corpus, config=("seed", "tracker.init",
          "tracker.corpus_noise_sd"), upstream=("corpus", "units"), enabled=uses_tracked_corpus),
    Stage("mapping", train, config=("seed", "mapping"), speed_only=("mapping.workers",),
          upstream=_TRAINING_INPUTS, inputs=front_model_inputs),
    Stage("front_end", train_front_end, config=("seed", "synth", "mapping.augment",
                                                "mapping.train_fraction", "front_end",
                                                "real_speaker.corpus"),
          speed_only=("synth.workers", "front_end.workers"), upstream=("corpus", "tracked"),
          enabled=front_end_applies, inputs=front_inputs, files=articulation_files),
    _grid_stage(VOICES, train_voices, config=("seed", "synth", "units", "mapping",
                                              "real_speaker.corpus"),
                speed_only=("synth.workers", "mapping.workers"), applies=synthesised,
                inputs=voices_inputs, upstream=(*_TRAINING_INPUTS, "front_end"),
                files=every_articulation_file),
    Stage("speech_eval", evaluate_speech, config=("targets.lookahead_ms", "speech_set"),
          upstream=("corpus", "units", "mapping", "front_end", "voices"), files=set_files),
    Stage("render", render_held_out, upstream=("corpus", "keyframes", "mapping")),
    Stage("stimuli", make_stimuli, config=("seed", "synth"), speed_only=("synth.workers",),
          upstream=("units", "mapping", "voices"), enabled=study_applies,
          files=articulation_files),
    Stage("study_data", simulate_participants, config=("seed", "study"),
          upstream=("corpus", "stimuli"), guard=keep_real_participants, enabled=study_applies),
    Stage("analysis", analyze, config=("seed",), upstream=("study_data",),
          enabled=study_applies),
    _grid_stage(ABLATIONS, ablate, config=("seed", "mapping"), speed_only=("mapping.workers",)),
    _grid_stage(CEILING, decompose, config=("seed", "synth", "units", "mapping", "tracker.init",
                                            "tracker.corpus_noise_sd"),
                speed_only=("synth.workers", "mapping.workers"), applies=synthesised,
                files=every_articulation_file),
    Stage("articulation", evaluate_articulation, config=("seed", "synth", "mapping.train_fraction",
                                                         "real_speaker.corpus"),
          speed_only=("synth.workers",), enabled=articulation_applies, inputs=real_inputs,
          files=every_articulation_file),
    Stage("real_speaker", lambda paths, cfg: evaluate_real_speaker(paths, cfg, run),
          config=("seed", "units", "mapping", "real_speaker"), speed_only=("mapping.workers",),
          upstream=("units", "mapping", "voices"), enabled=real_speaker_applies,
          inputs=real_inputs),
    Stage("real_faces", evaluate_real_faces, config=("seed", "mapping.train_fraction",
                                                     "real_speaker.corpus", "real_faces"),
          upstream=("units", "mapping", "voices", "real_speaker"), enabled=real_faces_applies,
          inputs=real_faces_inputs),
    _grid_stage(REAL_STEPS, measure_real_steps, config=("seed", "units", "mapping",
                                                         "real_speaker"),
                speed_only=("mapping.workers",), applies=real_speaker_applies, upstream=(),
                inputs=real_inputs),
    Stage("report", build_report, always=True),
)}

REPLICATION = ("corpus", "units", "keyframes", "tracking", "tracked", "mapping", "front_end",
               "voices", "speech_eval", "render", "stimuli", "study_data", "analysis", "ablations",
               "ceiling", "articulation", "real_speaker", "real_faces", "real_steps",
               "report")


def run(names, paths: RunPaths, cfg) -> dict:
    """Run the named stages of ``paths`` (and the upstream stages they need); returns
    ``{stage: done.json}`` of every stage that ran or was reused."""
    return run_stages(names, STAGES, paths, cfg)


def stale(names, paths: RunPaths, cfg) -> list[str]:
    """The stages :func:`run` would run rather than reuse, in order."""
    return stale_stages(names, STAGES, paths, cfg)


def off_for_corpus(names, cfg) -> dict:
    """``{stage: why}`` for the stages among ``names`` (and their upstream stages) that the
    run's corpus switches off (:func:`talkingface.stages.applies.switched_off`)."""
    return switched_off(cfg, run_order(names, STAGES))


def preflight(names, paths: RunPaths, cfg) -> list[str]:
    """Refuse before any work what :func:`run` would refuse on the way: a missing input file,
    or a stage that would have to replace a folder its guard keeps (real participants' data).
    Returns the stages that would run."""
    todo = stale(names, paths, cfg)
    for name in todo:
        stage, folder = STAGES[name], paths.stage(name)
        if stage.guard is not None and folder.exists():
            stage.guard(folder)
    return todo


__all__ = ["ABLATIONS", "CEILING", "GRID_STAGES", "REAL_STEPS", "GridStage", "REPLICATION",
           "STAGES", "Stage", "VOICES", "off_for_corpus", "preflight", "prepare_run", "read_done", "run", "stale"]
