"""Arguments every sub-command shares, and the config they resolve to."""
from __future__ import annotations

import argparse

from talkingface.config import load_config


def config_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="FILE", help="YAML config (defaults: the paper's values)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override one config value, e.g. --set synth.speakers=2 (repeatable)")
    p.add_argument("--seed", type=int, help="the run seed (same as --set seed=N)")


def visual_source_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--visual-source", choices=("markers", "tracked"),
                   help="MUPs the mapping learns from: the corpus markers, or the corpus "
                   "rendered as marker video and tracked by the MU-constrained tracker, as the "
                   "paper did (same as --set mapping.visual_source=...)")


def run_args(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--name", required=True, help=what)
    p.add_argument("--overwrite", action="store_true",
                   help="re-run the stages a changed config affects in an existing run")
    config_args(p)


def resolve_config(args, *extra: str):
    """The config of ``--config``, ``--set``, ``--seed``, ``--visual-source`` and ``extra``
    overrides (``section.key=value``), in that order."""
    overrides = list(getattr(args, "overrides", []))
    if getattr(args, "seed", None) is not None:
        overrides.append(f"seed={args.seed}")
    if getattr(args, "visual_source", None) is not None:
        overrides.append(f"mapping.visual_source={args.visual_source}")
    return load_config(getattr(args, "config", None), overrides + list(extra))
