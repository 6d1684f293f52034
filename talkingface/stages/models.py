"""The trained models of a run, found from what a user names: ``--model`` of ``animate``,
``stream`` and ``evaluate-speech``, and the stages that animate with a run's model.

``--model`` is a run name, a run folder or a ``.tfmap`` file; by default, the most recent run under
``runs/`` that has a trained mapping. A run's model is its voice-robust model (stage ``voices``,
trained on many voices for real speech) when it has one, else the paper's single-voice mapping
(``mapping/<method>_utterance.tfmap``, which ``--model`` can name as a file).

Where no run under ``runs/`` has a trained mapping, ``animate`` and ``stream`` (``shipped=True``)
use the project's default model shipped with the package (:data:`SHIPPED_DIR`: the default child
of ``configs/voices.yaml`` trained under ``configs/paper.yaml``, put there by
``tools/ship_default_model.py``, its provenance in ``provenance.json`` beside it). The commands
that write beside their model or score a run's default (``evaluate-face``) keep refusing.
"""
from __future__ import annotations

import json
from pathlib import Path

import mapping
from face_model.motion_units import MotionUnits
from groundwork.errors import ParameterError
from mapping.animator import FaceAnimator
from mapping.checkpoint import AudioMapping

# the shipped default model: its .tfmap (and the front end kept beside it), the Motion Units it
# animates with and its provenance record (tools/ship_default_model.py; mapping/models/NOTICE.md)
SHIPPED_DIR = Path(mapping.__file__).resolve().parent / "models" / "default"
PROVENANCE = "provenance.json"


def find_model(model: str | None, runs_dir="runs", *, shipped: bool = False
               ) -> tuple[Path, Path]:
    """``(mapping .tfmap, motion_units.npz)`` for ``--model`` (see the module docstring);
    ``shipped``: without ``--model`` and with no trained run, the shipped default model
    (:func:`shipped_default`) instead of a refusal."""
    runs = Path(runs_dir)
    if model is None:
        done = sorted(runs.glob("*/mapping/done.json"), key=lambda p: p.stat().st_mtime)
        if not done and shipped:
            return shipped_default(no_run=runs)[:2]
        if not done:
            raise ParameterError(
                f"no trained mapping under {runs}/: run `make replicate` (or `talkingface train "
                "--name NAME`) first, or pass --model with a run name or a .tfmap file")
        run = done[-1].parent.parent
    else:
        p = Path(model)
        if p.suffix == ".tfmap":
            if p.is_dir():
                raise ParameterError(f"--model {p} is a folder, not a .tfmap model file")
            if not p.is_file():
                raise ParameterError(f"--model {p}: file not found")
            return p, model_units(p)
        if p.is_file():
            raise ParameterError(f"--model {p} is not a .tfmap model file; give a run name, a "
                                 "run folder or a .tfmap file")
        run = p if p.is_dir() else runs / model
        if not (run / "mapping" / "done.json").is_file():
            raise ParameterError(f"--model {model}: no trained mapping in {run}/mapping (train "
                                 "it with `talkingface train --name NAME`)")
    try:
        done = json.loads((run / "mapping" / "done.json").read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise ParameterError(f"{run / 'mapping' / 'done.json'}: not valid JSON ({exc}); train "
                             "the run again") from None
    models = done.get("models", {})
    if not models:
        raise ParameterError(f"{run}/mapping holds no saved model")
    robust = voices_default(run)
    if robust is not None:  # the run's voice-robust model (stage voices) is the default
        return robust, model_units(robust)
    split = "utterance" if "utterance" in models else next(iter(models))
    return run / "mapping" / models[split], run / "units" / "motion_units.npz"


def shipped_default(folder=None, *, no_run=None) -> tuple[Path, Path, dict]:
    """``(tfmap, motion_units.npz, provenance record)`` of the shipped default model in
    ``folder`` (default :data:`SHIPPED_DIR`), each file checked to be there; ``no_run``: the
    runs folder that had no trained mapping, named in the refusal when the model is missing."""
    folder = Path(SHIPPED_DIR if folder is None else folder)
    record_file = folder / PROVENANCE
    how = ("run `make replicate` (or `talkingface train --name NAME`) first, or pass --model "
           "with a run name or a .tfmap file")
    if not record_file.is_file():
        where = f"no trained mapping under {no_run}/ and " if no_run is not None else ""
        raise ParameterError(f"{where}no shipped default model ({record_file} not found): {how}")
    try:
        record = json.loads(record_file.read_text(encoding="utf-8"))
        files = {k: folder / Path(record["files"][k]).name for k in ("tfmap", "units")}
    except (ValueError, UnicodeDecodeError, KeyError, TypeError) as exc:
        raise ParameterError(f"{record_file}: not a shipped model's record ({exc!r}); ship it "
                             "again (tools/ship_default_model.py RUN_DIR)") from None
    missing = [str(p) for p in files.values() if not p.is_file()]
    if missing:
        raise ParameterError(f"the shipped default model's {', '.join(missing)} missing; ship "
                             "it again (tools/ship_default_model.py RUN_DIR) or pass --model")
    return files["tfmap"], files["units"], record


def is_shipped(tfmap) -> bool:
    """Whether ``tfmap`` is the shipped default model's file (in :data:`SHIPPED_DIR`)."""
    return Path(tfmap).resolve().parent == SHIPPED_DIR


def model_label(tfmap) -> str:
    """How ``animate`` and ``stream`` name the model they used: its path, or for the shipped
    default ``the shipped default model <child> (<path>)``."""
    if not is_shipped(tfmap):
        return str(tfmap)
    try:
        child = shipped_default()[2].get("child", "?")
    except ParameterError:
        child = "?"
    return f"the shipped default model {child} ({tfmap})"


def voices_default(run: Path) -> Path | None:
    """The voice-robust model of a run (``voices/done.json``: its ``model`` child), if any."""
    done_file = run / "voices" / "done.json"
    if not done_file.is_file():
        return None
    try:
        done = json.loads(done_file.read_text(encoding="utf-8"))
        return run / "voices" / done["models"][done["model"]]["tfmap"]
    except (ValueError, UnicodeDecodeError, KeyError, TypeError) as exc:
        raise ParameterError(f"{done_file}: not a finished voices stage ({exc!r}); make the "
                             "run's voices stage again (talkingface replicate --name NAME)") \
            from None


def model_units(tfmap: Path) -> Path:
    """The Motion Units of a ``.tfmap``: its own, beside it (a voice-robust model trained on
    the real speaker: ``<run>/voices/<child>/motion_units.npz``), else those of the run it
    belongs to: ``<run>/mapping/x.tfmap`` or a voice-robust model
    ``<run>/voices/<child>/x.tfmap``."""
    tfmap = Path(tfmap)
    if (tfmap.parent / "motion_units.npz").is_file():
        return tfmap.parent / "motion_units.npz"
    return model_run(tfmap) / "units" / "motion_units.npz"


def model_run(tfmap: Path) -> Path:
    """The run folder a ``.tfmap`` belongs to: ``<run>/mapping/x.tfmap`` or a voice-robust model
    ``<run>/voices/<child>/x.tfmap`` (the folder holding ``units/motion_units.npz``)."""
    tfmap = Path(tfmap)
    for run in (tfmap.parent.parent, tfmap.parent.parent.parent):
        if (run / "units" / "motion_units.npz").is_file():
            return run
    if is_shipped(tfmap):
        raise ParameterError(f"--model {tfmap} is the shipped default model: it belongs to no "
                             "run (no corpus, cache or keyframes of its own); name the run it "
                             "was made from (see mapping/models/NOTICE.md)")
    raise ParameterError(f"--model {tfmap}: the Motion Units of its run "
                         f"({tfmap.parent.parent / 'units' / 'motion_units.npz'}) are missing")


def load_animator(model: str | None, runs_dir="runs", *, shipped: bool = False):
    """``(FaceAnimator, its .tfmap path)`` for ``--model`` (see :func:`find_model`)."""
    tfmap, units = find_model(model, runs_dir, shipped=shipped)
    return FaceAnimator(AudioMapping.load(tfmap), MotionUnits.load(units)), tfmap
