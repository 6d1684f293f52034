"""The shipped default model (``mapping/models/default/``) made from a run's ``voices`` stage, so
that ``talkingface animate`` and ``stream`` work from any folder before any run.

    make replicate                                   # or the small run of mapping/models/NOTICE.md
    python tools/ship_default_model.py runs/paper [--check]

Copies the run's default child (the ``model`` its ``voices/done.json`` names: its ``.tfmap``, the
causal front end kept beside it, the Motion Units it animates with) over the shipped files and
writes ``provenance.json`` beside them: the child, its settings (and their hash), the run seed,
what it was trained on (corpus, faces, voices, training speakers, front end), the commit of the
checkout holding the run, and the SHA-256 of each file and of each model file's arrays
(:func:`groundwork.modelfile.checksum`). Every file is read whole and checked first: a damaged
one, a child that is not ``configs/voices.yaml``'s ``model`` or settings that are not those
``configs/paper.yaml`` and ``configs/voices.yaml`` give that child are refused before anything
is replaced (the folder is swapped in whole).

``--check`` changes nothing: it exits 1 with one line when the shipped model's child is not
``configs/voices.yaml``'s ``model``, its recorded settings are not those the paper's config and
``configs/voices.yaml`` give that child today, or a shipped file is not the one recorded (make
it again); ``--check RUN_DIR`` also says whether the run's trained files reproduce the shipped
ones (the same checksum of the arrays of the ``.tfmap`` and of the Motion Units), exit 1 when
they do not; whether the front end kept beside it is the same is said, not required (the
``front_end`` stage's training is not reproduced to the bit everywhere, and the default child's
weights do not depend on it). Errors exit 2.

The tool imports nothing written after the runs it ships (it can run in the checkout that made
the run, whose commit it then records as it is).
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from analysis.speech_eval import training_speakers  # noqa: E402
from face_model import motion_units  # noqa: E402
from face_model.motion_units import MotionUnits  # noqa: E402
from groundwork import modelfile  # noqa: E402
from groundwork.atomic import fresh_partial_folder, swap_in  # noqa: E402
from groundwork.errors import ParameterError, TalkingFaceError  # noqa: E402
from mapping import checkpoint, front_net  # noqa: E402
from mapping.animator import FaceAnimator  # noqa: E402
from mapping.checkpoint import AudioMapping, front_file  # noqa: E402
from talkingface.config import load_config, select, to_dict  # noqa: E402
from talkingface.stages import STAGES  # noqa: E402
from talkingface.stages.grid_files import load_voices_grid  # noqa: E402

# where talkingface.stages.models finds the shipped model (its SHIPPED_DIR and PROVENANCE; not
# imported, so that this tool runs in a checkout made before them, e.g. the run's own)
SHIPPED_DIR = REPO / "mapping" / "models" / "default"
PROVENANCE = "provenance.json"
PAPER = REPO / "configs" / "paper.yaml"
VOICES_GRID = REPO / "configs" / "voices.yaml"
UNITS = "motion_units.npz"
# keys of the stages' reuse keys that do not describe the model: the grid file (its child's
# settings are recorded instead) and the run's front end's path (its checksummed name is)
NOT_SETTINGS = ("voices.grid", "mapping.front_model")
KINDS = {"tfmap": (checkpoint.KIND, (checkpoint.VERSION,)),
         "front": (front_net.KIND, (front_net.VERSION,)),
         "units": (motion_units.KIND, (motion_units.VERSION,))}


# -- the settings ---------------------------------------------------------------------------------

def setting_keys(cfg) -> tuple[list, set]:
    """The config keys the default child's model depends on, for the child's config ``cfg``:
    the reuse keys of the ``voices`` stage and of the stages it reads, that ``cfg`` switches on
    (:data:`talkingface.stages.STAGES`), and ``voices.real_face``; and their speed-only keys."""
    keys, speed, todo, seen = [], set(), ["voices"], set()
    while todo:
        name = todo.pop(0)
        stage = STAGES[name]
        if name in seen or not stage.enabled(cfg):
            continue
        seen.add(name)
        own = stage.config(cfg) if callable(stage.config) else stage.config
        keys += [k for k in own if k not in keys]
        speed |= set(stage.speed_only)
        todo += list(stage.upstream)
    return keys + ["voices.real_face"], speed


def settings_of(tree: dict, cfg) -> dict:
    """``{"section.key": value}`` of the config dict ``tree`` (a child's resolved config) on
    :func:`setting_keys` of ``cfg``, without worker counts and :data:`NOT_SETTINGS`; a key
    ``tree`` lacks (made by another version) is ``"(missing)"``."""
    keys, speed = setting_keys(cfg)
    out = {}

    def walk(prefix: str, value) -> None:
        if isinstance(value, dict):
            for k, v in value.items():
                walk(f"{prefix}.{k}", v)
        elif prefix not in speed and prefix not in NOT_SETTINGS \
                and not prefix.endswith(".workers"):
            out[prefix] = value

    for key in keys:
        try:
            walk(key, select(tree, key))
        except (KeyError, TypeError):
            out[key] = "(missing)"
    return dict(sorted(out.items()))


def settings_hash(settings: dict) -> str:
    return hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()


def expected(paper=None, grid=None) -> tuple[str, object]:
    """``(child, its Config)``: ``grid``'s ``model`` as ``paper`` and ``grid`` resolve it
    (default: :data:`PAPER` and :data:`VOICES_GRID`)."""
    children, child = load_voices_grid(grid or VOICES_GRID, load_config(paper or PAPER))
    return child, children[child]


def mismatch(child: str, settings: dict, where, paper=None, grid=None) -> str | None:
    """One line saying how ``child`` and its ``settings`` differ from the default child of
    ``grid`` under ``paper`` (:func:`expected`; None: they are the same)."""
    paper, grid = Path(paper or PAPER), Path(grid or VOICES_GRID)
    want_child, cfg = expected(paper, grid)
    if child != want_child:
        return (f"{where}: its model is child {child!r}, but {grid.name}'s model is "
                f"{want_child!r}; make it again (tools/ship_default_model.py)")
    want = settings_of(to_dict(cfg), cfg)
    diff = [k for k in sorted(set(want) | set(settings)) if want.get(k) != settings.get(k)]
    if not diff:
        return None
    shown = ", ".join(f"{k}={settings.get(k, '(missing)')!r} (now "
                      f"{want.get(k, '(missing)')!r})" for k in diff[:3])
    more = f" and {len(diff) - 3} more" if len(diff) > 3 else ""
    return (f"{where}: child {child!r} was trained with {shown}{more}, not what {paper.name} "
            f"and {grid.name} give it today; make it again (tools/ship_default_model.py)")


# -- the files ------------------------------------------------------------------------------------

def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def arrays_sha256(path: Path, part: str) -> str:
    """:func:`groundwork.modelfile.checksum` of the arrays of the model file ``path`` (read
    whole and checked against its own checksum: a damaged file is refused, naming it)."""
    kind, versions = KINDS[part]
    return modelfile.checksum(modelfile.read_model(path, kind=kind, versions=versions).arrays)


def read_json(path: Path, what: str) -> dict:
    if not path.is_file():
        raise ParameterError(f"{path} not found; {what}")
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise ParameterError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(record, dict):
        raise ParameterError(f"{path}: not a JSON object")
    return record


def run_child(run) -> dict:
    """The default child of the run ``run`` (its ``voices/done.json``'s ``model``): its name,
    model files (``tfmap``, ``front`` or None, ``units``), training corpus and the stage's
    record, each file read whole and checked; one line naming the file otherwise."""
    run = Path(run)
    if not run.is_dir():
        raise ParameterError(f"RUN_DIR {run}: not a folder (a run whose voices stage has run)")
    done_file = run / "voices" / "done.json"
    done = read_json(done_file, "RUN_DIR must be a run whose voices stage has run (make "
                                "replicate, or the small run of mapping/models/NOTICE.md)")
    try:
        child = done["model"]
        entry = done["models"][child]
        tfmap = run / "voices" / entry["tfmap"]
        corpus = run / "voices" / entry["corpus"] if entry.get("corpus") else run / "corpus"
        units = run / "voices" / entry["units"] if entry.get("units") else \
            run / "units" / UNITS
    except (KeyError, TypeError) as exc:
        raise ParameterError(f"{done_file}: not a finished voices stage (no {exc}); make the "
                             "run's voices stage again") from None
    for path in (tfmap, units, corpus / "manifest.csv"):
        if not path.is_file():
            raise ParameterError(f"{path} not found: the run's default child {child!r} is not "
                                 "complete; make the run's voices stage again")
    front = front_file(tfmap) if front_file(tfmap).is_file() else None
    files = {"tfmap": tfmap, "front": front, "units": units}
    arrays = {part: arrays_sha256(p, part) for part, p in files.items() if p is not None}
    mapping = AudioMapping.load(tfmap)  # its front end beside it, and the one it was trained with
    FaceAnimator(mapping, MotionUnits.load(units))  # the units it animates with
    return {"child": child, "files": files, "arrays_sha256": arrays, "mapping": mapping,
            "run": run, "corpus": corpus, "done": done}


def trained_on(found: dict) -> dict:
    """What the child learned from: its corpus (hash, utterances, faces, voices, training
    speakers), the split, and the causal front end it reads."""
    corpus, meta = found["corpus"], found["mapping"].metadata
    with open(corpus / "manifest.csv", newline="", encoding="utf-8-sig") as f:
        rows = list(csv.DictReader(f))
    info_file = corpus / "corpus.json"
    info = json.loads(info_file.read_text(encoding="utf-8")) if info_file.is_file() else {}
    synth = info.get("settings") or {}
    voices = sorted({r["voice"] for r in rows if r.get("voice")}) or (
        [f"{synth['backend']}:{synth['voice']}"] if "voice" in synth else [])
    out = {"corpus": str(corpus.relative_to(found["run"])),
           "corpus_hash": meta.get("corpus_hash"), "utterances": len(rows),
           "expressions": sorted({r["expression"] for r in rows}),
           "faces": sorted({r["speaker"] for r in rows}), "voices": voices,
           "training_speakers": sorted(training_speakers(corpus)),
           "split": meta.get("split")}
    front = found["files"]["front"]
    if front is not None:
        _, record = front_net.read_front(front)
        out["front_end"] = {"name": front_net.front_name(front),
                            "corpora": record.get("corpora"),
                            "training_speakers": record.get("training_speakers"),
                            "teacher": record.get("teacher")}
    return out


def checkout_commit(folder: Path) -> str:
    """The commit of the git checkout holding ``folder`` (``+dirty`` with uncommitted changes
    to tracked files), or ``unknown``."""
    try:
        def git(*args):
            return subprocess.run(["git", *args], cwd=folder, capture_output=True, text=True,
                                  check=True, timeout=30).stdout.strip()
        sha = git("rev-parse", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.CalledProcessError, subprocess.TimeoutExpired):
        return "unknown"
    return sha + ("+dirty" if dirty else "")


# -- ship, describe, check ------------------------------------------------------------------------

def ship(run, target=None, paper=None, grid=None, command: str = "") -> dict:
    """Copy the run's default child into ``target`` (swapped in whole, after every check) and
    write its record (:data:`PROVENANCE`; ``command``: how it was shipped); returns it."""
    run, target = Path(run), Path(target or SHIPPED_DIR)
    found = run_child(run)
    child, mapping = found["child"], found["mapping"]
    _, cfg = expected(paper, grid)
    settings = settings_of(mapping.metadata.get("config") or {}, cfg)
    problem = mismatch(child, settings, run, paper, grid)
    if problem:
        raise ParameterError(problem)
    names = {"tfmap": found["files"]["tfmap"].name, "units": UNITS,
             "front": None if found["files"]["front"] is None else found["files"]["front"].name}
    record = {"child": child, "seed": mapping.metadata.get("seed"), "settings": settings,
              "settings_sha256": settings_hash(settings), "files": names,
              "trained_on": trained_on(found), "run": str(run.resolve()),
              "voices_stage_fingerprint": found["done"].get("fingerprint"),
              "commit": checkout_commit(run),
              "command": command or f"python tools/ship_default_model.py {run}"}
    target.parent.mkdir(parents=True, exist_ok=True)
    partial = fresh_partial_folder(target)
    try:
        sums, arrays = {}, {}
        for part, src in found["files"].items():
            if src is None:
                continue
            dst = partial / names[part]
            shutil.copyfile(src, dst)
            sums[names[part]] = sha256_file(dst)
            arrays[names[part]] = arrays_sha256(dst, part)
            if sums[names[part]] != sha256_file(src) or \
                    arrays[names[part]] != found["arrays_sha256"][part]:
                raise ParameterError(f"{src}: its copy {dst} is not the same file (changed "
                                     "while copied?); ship it again")
        record.update({"sha256": sums, "arrays_sha256": arrays})
        (partial / PROVENANCE).write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")
        swap_in(partial, target)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return record


def shipped_record(target=None) -> dict:
    """The record of the shipped model in ``target`` (default :data:`SHIPPED_DIR`)."""
    target = Path(target or SHIPPED_DIR)
    record = read_json(target / PROVENANCE, "no shipped default model there (make it: "
                                            "tools/ship_default_model.py RUN_DIR)")
    if not all(isinstance(record.get(k), dict) for k in ("files", "sha256", "arrays_sha256",
                                                          "settings")):
        raise ParameterError(f"{target / PROVENANCE}: not a shipped model's record (files, "
                             "sha256, arrays_sha256, settings); ship it again")
    return record


def shipped_problem(target=None, paper=None, grid=None) -> str | None:
    """One line when a shipped file is not the one recorded, or the shipped child or settings
    are not today's (:func:`mismatch`); None when all agree."""
    target = Path(target or SHIPPED_DIR)
    record = shipped_record(target)
    for name, digest in record["sha256"].items():
        path = target / name
        if not path.is_file():
            return f"{path}: missing (the shipped default model's file); ship it again"
        if sha256_file(path) != digest:
            return (f"{path}: not the file shipped (sha256 {sha256_file(path)}, recorded "
                    f"{digest}); ship it again")
    return mismatch(record.get("child"), record["settings"], target / PROVENANCE, paper, grid)


def reproduces(run, target=None) -> tuple[str | None, str]:
    """``(problem, note)``: one line when the run's default child does not reproduce the
    shipped model — the checksums of the arrays of its ``.tfmap`` (the child's training) and
    of its Motion Units — else None and a line on the front end kept beside it, which the
    ``front_end`` stage made: the same arrays, or not (its training is not reproduced to the
    bit on every machine; the child's weights do not depend on it when it trains on the
    corpus's phone labels, ``mapping.phone_training: labels``)."""
    record, found = shipped_record(target), run_child(run)
    if found["child"] != record.get("child"):
        return (f"{run}: its default child is {found['child']!r}, the shipped model is "
                f"{record.get('child')!r}"), ""
    shipped = {part: record["arrays_sha256"].get(name)
               for part, name in record["files"].items() if name}
    if set(shipped) != set(found["arrays_sha256"]):
        return (f"{run}: its default child has the files {sorted(found['arrays_sha256'])}, "
                f"the shipped model {sorted(shipped)}"), ""
    for part in ("tfmap", "units"):
        digest = found["arrays_sha256"][part]
        if shipped[part] != digest:
            return (f"{found['files'][part]}: does not reproduce the shipped "
                    f"{record['files'][part]} (arrays sha256 {digest}, shipped "
                    f"{shipped[part]})"), ""
    if "front" not in shipped:
        return None, ""
    if shipped["front"] == found["arrays_sha256"]["front"]:
        return None, "and the front end kept beside it"
    return None, (f"but not its front end {found['files']['front']} (arrays sha256 "
                  f"{found['arrays_sha256']['front'][:12]}, shipped {shipped['front'][:12]}: "
                  "the run's front_end stage trained other last bits)")


def describe(target=None) -> str:
    """What the shipped model is and was trained on, in a few lines."""
    record = shipped_record(target)
    on = record.get("trained_on") or {}
    lines = [f"{Path(target or SHIPPED_DIR) / record['files']['tfmap']}: the shipped default model "
             f"{record['child']} (seed {record.get('seed')}, settings sha256 "
             f"{record.get('settings_sha256', '')[:12]}, commit {record.get('commit')})",
             f"  trained on {on.get('utterances')} utterances of the run's {on.get('corpus')}/ "
             f"(faces {', '.join(on.get('faces') or [])}; voices "
             f"{', '.join(on.get('voices') or [])}; training speakers "
             f"{', '.join(on.get('training_speakers') or [])}), split {on.get('split')}"]
    front = on.get("front_end")
    if front:
        lines.append(f"  its front end {front.get('name')}: training speakers "
                     f"{', '.join(front.get('training_speakers') or [])}")
    lines += [f"  {name}: sha256 {digest} (arrays {record['arrays_sha256'].get(name)})"
              for name, digest in record["sha256"].items()]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", nargs="?", help="a run whose voices stage has run")
    ap.add_argument("--check", action="store_true",
                    help="compare the shipped model with configs/paper.yaml and "
                    "configs/voices.yaml (and with RUN_DIR's files, when given)")
    ap.add_argument("--target", type=Path, help="the shipped model's folder (default: "
                    "mapping/models/default)")
    args = ap.parse_args(argv)
    try:
        if args.check:
            problem, note = shipped_problem(args.target), ""
            if problem is None and args.run_dir is not None:
                problem, note = reproduces(args.run_dir, args.target)
            if problem:
                print(problem)
                return 1
            print(describe(args.target))
            if args.run_dir is not None:
                print(f"{args.run_dir}: its default child reproduces the shipped model (the "
                      f"same arrays of its .tfmap and Motion Units), {note}")
            return 0
        if args.run_dir is None:
            raise ParameterError("give RUN_DIR (a run whose voices stage has run) or --check")
        ship(args.run_dir, args.target, command=" ".join(
            ["python tools/ship_default_model.py", *(sys.argv[1:] if argv is None else argv)]))
        print(describe(args.target))
        return 0
    except TalkingFaceError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a folder that cannot be written, a full disk
        print(f"error: {e.filename or ''}: {e.strerror or e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
