"""A grid file read and checked (:mod:`talkingface.stages.grid`): the children of an ablation,
ceiling, real-speaker steps or voices grid as resolved configs, each refused in one line that
names the file, the child and what it may not change.

A grid file::

    base:                  # settings applied to every child (optional)
      mapping.splits: [utterance]
    children:              # one child per entry: name → settings
      paper: {}
      no-gate: {mapping.method: mlp_large}

Keys are ``section.key`` as for ``--set``.
"""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

from groundwork.errors import ParameterError
from talkingface.config import apply_overrides, parse_set, read_yaml
from talkingface.stages.real_speaker import real_speaker_applies

_CHILD_NAME = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_.-"
RESERVED = ("corpora", "replicates")  # folders of a grid stage beside its children


def load_grid(path, cfg, *, what: str = "ablation grid", extra_keys: tuple = (),
              shared_corpus: bool = True) -> dict:
    """``{child name: resolved Config}`` from a grid file, in file order. ``extra_keys``: other
    top-level keys the caller reads itself (the voices grid's ``model``). ``shared_corpus``: the
    children train on the run's training corpus, so none may change the visual source or the
    tracker (False: the caller builds each child's corpus, as the ceiling does)."""
    path = Path(path)
    if not path.is_file():
        raise ParameterError(f"{what} {path} not found")
    tree = read_yaml(path, what) or {}
    if not isinstance(tree, dict) or not isinstance(tree.get("children"), dict) \
            or not tree["children"]:
        raise ParameterError(f"{path}: {what} needs a non-empty 'children' mapping "
                             "(name → settings)")
    unknown = set(tree) - {"base", "children", *extra_keys}
    if unknown:
        raise ParameterError(f"{path}: unknown top-level keys {sorted(unknown)}; allowed: "
                             f"{', '.join(['base', 'children', *extra_keys])}")

    def settings(where, d) -> dict:
        if d is None:
            return {}
        if not isinstance(d, dict):
            raise ParameterError(f"{path}: {where} must map section.key to a value, got {d!r}")
        return parse_set([f"{k}={json.dumps(v)}" for k, v in d.items()])

    base = settings("base", tree.get("base"))
    out = {}
    for name, d in tree["children"].items():
        name = str(name)
        if not name or any(ch not in _CHILD_NAME for ch in name) or name in RESERVED \
                or ".partial" in name:
            raise ParameterError(f"{path}: child name {name!r} may use letters, digits, '_.-' "
                                 f"(not {', '.join(RESERVED)}, nor containing .partial)")
        try:
            child = apply_overrides(apply_overrides(cfg, base), settings(name, d))
        except ParameterError as e:
            raise ParameterError(f"{path}: child {name!r}: {e}") from None
        if child.seed != cfg.seed:
            raise ParameterError(f"{path}: child {name!r} sets seed {child.seed}; the children's "
                                 "replicates are paired by seed with the reference's, so set "
                                 "it for the whole run (--seed)")
        if shared_corpus and (child.mapping.visual_source != cfg.mapping.visual_source
                              or child.tracker != cfg.tracker):
            raise ParameterError(f"{path}: child {name!r} changes the visual source or the "
                                 "tracker; the children share the run's training corpus, so set "
                                 "these for the whole run (--visual-source, --set tracker.…)")
        out[name] = child
    return out


def load_ceiling_grid(path, cfg) -> dict:
    """``{child: Config}`` of a ceiling grid; a child may not change the seed (:func:`load_grid`)
    or the Motion Units' settings (every step is the run's replication with its own corpus)."""
    children = load_grid(path, cfg, what="ceiling grid", shared_corpus=False)
    for name, child in children.items():
        if child.units != cfg.units:
            raise ParameterError(f"{path}: child {name!r} changes the Motion Units' settings; "
                                 "set these for the whole run")
    return children


def load_real_steps_grid(path, cfg) -> dict:
    """``{child: Config}`` of a real-speaker steps grid: the children share the training
    sentences' corpus and Motion Units, so none may change the seed, the visual source, the
    tracker (:func:`load_grid`) or the Motion Units' settings."""
    children = load_grid(path, cfg, what="real-speaker steps grid")
    for name, child in children.items():
        if child.units != cfg.units:
            raise ParameterError(f"{path}: child {name!r} changes the Motion Units' settings; "
                                 "set these for the whole run")
    return children


def load_voices_grid(path, cfg) -> tuple[dict, str]:
    """``({child: Config}, default model child)`` of a voices grid; the children may not change
    what the run's Motion Units or faces are made from (seed, units, tracker, visual source),
    only the voices that speak and how the mouth moves (``synth.articulation``).
    A child that trains on the real speaker (``voices.real_face``) is left out when the run has
    none (:func:`talkingface.stages.real_speaker.real_speaker_applies`); the default model may not be one of those then."""
    what = "voices grid"
    children = load_grid(path, cfg, what=what, extra_keys=("model",))
    model = (read_yaml(path, what) or {}).get("model")
    if model not in children:
        raise ParameterError(f"{path}: 'model' is {model!r}; allowed: the name of a child "
                             f"({', '.join(children)})")
    if not real_speaker_applies(cfg):  # the children that ask for the real speaker: left out
        if children[model].voices.real_face != "none":
            raise ParameterError(f"{path}: 'model' {model!r} trains on the real speaker "
                                 f"(voices.real_face: {children[model].voices.real_face}), "
                                 "which this run has none of (real_speaker.corpus)")
        children = {n: c for n, c in children.items() if c.voices.real_face == "none"}
    for name, child in children.items():
        if child.seed != cfg.seed or child.units != cfg.units:
            raise ParameterError(f"{path}: child {name!r} changes the seed or the Motion Units; "
                                 "the children share the run's, so set these for the whole run")
        same_faces = replace(child.synth, voices=cfg.synth.voices,
                             voice_weights=cfg.synth.voice_weights, workers=cfg.synth.workers,
                             articulation=cfg.synth.articulation)
        if same_faces != cfg.synth:
            raise ParameterError(f"{path}: child {name!r} changes synth settings other than "
                                 "synth.voices, synth.voice_weights and synth.articulation; its "
                                 "corpus must show the run's faces saying the run's sentences")
    return children, model


def voices_children(path, cfg) -> dict:
    """The children of a voices grid (:func:`load_voices_grid` without its default model)."""
    return load_voices_grid(path, cfg)[0]
