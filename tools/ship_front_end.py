"""The shipped causal phone front end (``mapping/models/causal_front.npz``) made from a run's
``front_end`` stage, so that ``animate``, ``stream`` and every model with ``mapping.recogniser:
causal`` work before any run.

    python -m talkingface front-end --name front      # teach it (the paper's config)
    python tools/ship_front_end.py runs/front [--check]

Copies ``RUN_DIR/front_end/causal_front.npz`` over the shipped file and prints what it was
trained on (its record: corpora, training speakers, teacher, settings, seed, epochs).
``--check`` changes nothing: it exits 1 with one line when the shipped file's training
settings (``front_end`` section, run seed) are not those of ``configs/paper.yaml`` — the shipped
file was then made under other settings and should be made again.
"""
from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from groundwork.errors import ParameterError  # noqa: E402
from mapping.front_net import SHIPPED, front_name, read_front  # noqa: E402
from talkingface.config import load_config  # noqa: E402

PAPER = REPO / "configs" / "paper.yaml"


def describe(path: Path) -> str:
    """What a front end's model file says it was trained on, in a few lines."""
    _, meta = read_front(path)
    last = (meta.get("history") or [{}])[-1]
    return "\n".join([
        f"{path}: {front_name(path)}",
        f"  teacher {meta.get('teacher')}; corpora {', '.join(meta.get('corpora') or [])}; "
        f"{meta.get('train_minutes', 0):.1f} min of training audio",
        f"  training speakers: {', '.join(meta.get('training_speakers') or [])}",
        f"  run seed {meta.get('run_seed')}; weights of epoch {meta.get('best_epoch')} of "
        f"{len(meta.get('history') or [])} (held-out loss at the last {last.get('heldout_loss')})",
        f"  settings: {meta.get('settings')}"])


def mismatch(path: Path, paper=PAPER) -> str | None:
    """One line saying how the file's training settings differ from ``paper``'s (None: they
    are the same)."""
    cfg = load_config(paper)
    _, meta = read_front(path)
    want = {"settings": dataclasses.asdict(cfg.front_end.train),
            "corpora": list(cfg.front_end.corpora), "run_seed": cfg.seed}
    got = {k: meta.get(k) for k in want}
    diff = [k for k in want if want[k] != got[k]]
    if not diff:
        return None
    return (f"{path}: trained with {', '.join(f'{k}={got[k]!r}' for k in diff)}, but "
            f"{paper.name} has {', '.join(f'{k}={want[k]!r}' for k in diff)}; make it again "
            "(see this file's docstring)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", nargs="?", help="a run whose front_end stage has run")
    ap.add_argument("--check", action="store_true",
                    help="compare the shipped file's settings with configs/paper.yaml")
    args = ap.parse_args(argv)
    try:
        if args.check:
            problem = mismatch(SHIPPED)
            print(problem or describe(SHIPPED))
            return 1 if problem else 0
        if args.run_dir is None:
            raise ParameterError("give RUN_DIR (a run whose front_end stage has run) or --check")
        src = Path(args.run_dir) / "front_end" / "causal_front.npz"
        if not src.is_file():
            raise ParameterError(f"{src}: not found; RUN_DIR must be a run whose front_end "
                                 "stage has run (python -m talkingface front-end --name NAME)")
        read_front(src)  # a damaged file is refused before it replaces the shipped one
        SHIPPED.parent.mkdir(parents=True, exist_ok=True)
        tmp = SHIPPED.with_name(SHIPPED.name + ".tmp")
        shutil.copyfile(src, tmp)
        tmp.replace(SHIPPED)
        print(describe(SHIPPED))
        return 0
    except ParameterError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
