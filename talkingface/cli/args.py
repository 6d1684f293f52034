"""Arguments every sub-command shares, the options of the commands that train a grid, and the
config they resolve to."""
from __future__ import annotations

import argparse

from talkingface.config import apply_overrides, load_config


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


def corpus_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--corpus", dest="corpus_source", metavar="DIR",
                   help="a given corpus folder (manifest.csv, audio/, markers/, phones/, e.g. a "
                   "real speaker's recordings made from video) instead of the synthetic corpus; "
                   "validated and linked into runs/<name>/corpus (same as --set "
                   "corpus.source=DIR)")


def run_args(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--name", required=True, help=what)
    p.add_argument("--overwrite", action="store_true",
                   help="re-run the stages a changed config affects in an existing run")
    config_args(p)


def resolve_config(args, *extra: str):
    """The config of ``--config``, ``--set``, ``--seed``, ``--visual-source``, ``extra``
    overrides (``section.key=value``) and ``--corpus``, in that order (``--corpus DIR`` sets
    ``corpus.source`` to DIR as typed, not parsed as YAML)."""
    overrides = list(getattr(args, "overrides", []))
    if getattr(args, "seed", None) is not None:
        overrides.append(f"seed={args.seed}")
    if getattr(args, "visual_source", None) is not None:
        overrides.append(f"mapping.visual_source={args.visual_source}")
    cfg = load_config(getattr(args, "config", None), overrides + list(extra))
    if getattr(args, "corpus_source", None) is not None:
        cfg = apply_overrides(cfg, {"corpus": {"source": args.corpus_source}})
    return cfg


def grid_args(p: argparse.ArgumentParser, *, required: bool, workers_help: str) -> None:
    """The options of a command that trains the ablation grid (``replicate``, ``ablate``).

    Parameters
    ----------
    p : argparse.ArgumentParser
        The sub-command's parser.
    required : bool
        The command needs ``--grid`` (``ablate``); otherwise it defaults to the project's grid.
    workers_help : str
        The help of ``--workers``.

    Notes
    -----
    ``--grid`` and ``--ablations`` are two spellings of one option (``ablations.grid``);
    :func:`grid_overrides` turns the options into config overrides.
    """
    default = ("" if required else "; 'none' to skip; default: the project's "
               "configs/ablations.yaml")
    p.add_argument("--grid", "--ablations", dest="grid", metavar="GRID", required=required,
                   help=f"ablation grid file, e.g. configs/ablations.yaml, trained as MLflow "
                   f"child runs and tabulated{default} (same as --set ablations.grid=GRID; "
                   "--ablations GRID is another name for this option)")
    p.add_argument("--workers", type=int, help=workers_help)
    p.add_argument("--seeds", type=int, help="training seeds per ablation setting (default 5; "
                   "same as --set ablations.seeds=N)")
    p.add_argument("--scheduler", metavar="WHERE", help="where grid tasks run: local (a Dask "
                   "LocalCluster, the default), processes (a process pool), or a running Dask "
                   "scheduler tcp://HOST:8786 (same as --set cluster.scheduler=...)")


def grid_overrides(args) -> list[str]:
    """The config overrides (``section.key=value``) of the grid options of :func:`grid_args`
    and ``replicate``'s ``--voices``, for :func:`resolve_config`."""
    out = []
    if getattr(args, "grid", None) is not None:
        out.append(f"ablations.grid={args.grid}")
    if getattr(args, "workers", None) is not None:
        out.append(f"ablations.workers={args.workers}")
    if getattr(args, "voices", None) is not None:
        out.append(f"voices.grid={args.voices}")
    if getattr(args, "seeds", None) is not None:
        out.append(f"ablations.seeds={args.seeds}")
    if getattr(args, "scheduler", None) is not None:
        out.append(f"cluster.scheduler={args.scheduler}")
    return out
