"""The import layering of DESIGN.md, checked over the import graph of the source tree.

Layers, lowest first: ``groundwork`` (the ground floor: errors, settings fields, files, audio
I/O; it imports no project package) ← ``face_model`` ← ``data_synth``, ``mapping`` ← ``study`` ←
``analysis`` ← ``talkingface``. A module imports only its own package and lower layers (``data_synth`` and
``mapping`` are siblings: neither imports the other); no two files import each other, directly
or around a loop, counting imports inside functions; and imports sit at the top of a file,
except the heavy, optional ones in :data:`LAZY_OK`.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
LAYERS = {"groundwork": 0, "face_model": 1, "data_synth": 2, "mapping": 2, "study": 3,
          "analysis": 4, "talkingface": 5}
# May be imported inside a function: heavy or optional, and only needed on some paths.
LAZY_OK = ("torch", "mlflow", "psychopy", "pyglet", "psychtoolbox", "cv2", "sounddevice",
           "imageio_ffmpeg", "matplotlib", "talkingface.experiments.pyfunc", "distributed",
           "mediapipe", "soundfile", "hama", "openfacefx", "pylipsync", "uvicorn")


def _module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _resolve(modules: set, name: str) -> str | None:
    """The project module ``name`` refers to (its longest known prefix), or None."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        candidate = ".".join(parts[:k])
        if candidate in modules:
            return candidate
    return None


def _imports(tree: ast.Module, module: str, is_package: bool):
    """``(imported name, line, inside a function)`` for every import statement."""
    out = []

    def visit(node, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            inside = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef))
            if isinstance(child, ast.Import):
                out.extend((a.name, child.lineno, in_function) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    pkg = module.split(".")[: len(module.split(".")) - child.level
                                            + (1 if is_package else 0)]
                    base = ".".join(pkg + ([base] if base else []))
                out.extend((f"{base}.{a.name}", child.lineno, in_function)
                           for a in child.names)
            visit(child, inside)

    visit(tree, False)
    return out


def import_problems(root: Path, layers: dict = LAYERS) -> list[str]:
    """Every violation of the rules in the module docstring, one line each."""
    files = {_module_name(root, p): p for pkg in layers for p in sorted((root / pkg).rglob("*.py"))}
    modules = set(files)
    graph: dict[str, set] = {m: set() for m in modules}
    problems = []
    for mod, path in files.items():
        package = mod.split(".")[0]
        tree = ast.parse(path.read_text(), filename=str(path))
        for name, line, in_function in _imports(tree, mod, path.name == "__init__.py"):
            target = _resolve(modules, name)
            where = f"{path.relative_to(root)}:{line}"
            if target is None:
                if in_function and not name.startswith(LAZY_OK) and name != "__future__":
                    problems.append(f"{where}: imports {name} inside a function (only "
                                    f"{', '.join(LAZY_OK)} may be)")
                continue
            if target != mod:
                graph[mod].add(target)
            # importing a.b.c runs a.b's __init__ first (unless the importer is inside a.b)
            parts = target.split(".")
            for k in range(1, len(parts)):
                parent = ".".join(parts[:k])
                if parent in modules and not (mod + ".").startswith(parent + ".") \
                        and parent != mod:
                    graph[mod].add(parent)
            if in_function and not target.startswith(LAZY_OK):
                problems.append(f"{where}: imports {target} inside a function")
            other = target.split(".")[0]
            if other != package and layers[other] >= layers[package]:
                problems.append(f"{where}: {package} (layer {layers[package]}) imports {other} "
                                f"(layer {layers[other]}); only lower layers may be imported")
    problems += [f"import cycle: {' -> '.join(c)}" for c in _cycles(graph)]
    return problems


def _cycles(graph: dict) -> list[list]:
    """The strongly connected components with more than one module (Tarjan), each as a loop."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def strong(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp) + [sorted(comp)[0]])

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return out


def test_the_source_tree_keeps_the_layers():
    assert import_problems(REPO) == []


def _tree(root: Path, files: dict) -> Path:
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    for pkg in LAYERS:
        (root / pkg).mkdir(exist_ok=True)
        (root / pkg / "__init__.py").touch()
    return root


@pytest.mark.parametrize("files, problem", [
    ({"study/stimuli.py": "from analysis.figures import face_grid\n",
      "analysis/figures.py": "def face_grid(): pass\n"},
     "study/stimuli.py:1: study (layer 3) imports analysis (layer 4)"),
    ({"data_synth/gen.py": "import mapping.features\n", "mapping/features.py": ""},
     "data_synth/gen.py:1: data_synth (layer 2) imports mapping (layer 2)"),
    ({"analysis/stats.py": "def f():\n    from analysis.crossover import g\n",
      "analysis/crossover.py": "from analysis.stats import f\ndef g(): pass\n"},
     "import cycle: analysis.crossover -> analysis.stats -> analysis.crossover"),
    ({"talkingface/log.py": "from talkingface.stages.train import f\n",
      "talkingface/stages/__init__.py": "from talkingface.stages.report import r\n",
      "talkingface/stages/train.py": "def f(): pass\n",
      "talkingface/stages/report.py": "from talkingface.log import g\ndef r(): pass\n"},
     "import cycle: talkingface.log -> talkingface.stages -> talkingface.stages.report"),
    ({"face_model/a.py": "def f():\n    import face_model.b\n", "face_model/b.py": ""},
     "face_model/a.py:2: imports face_model.b inside a function"),
    ({"face_model/a.py": "def f():\n    import scipy.linalg\n"},
     "face_model/a.py:2: imports scipy.linalg inside a function"),
    ({"groundwork/errors.py": "from face_model.layout import L\n",
      "face_model/layout.py": "L = 1\n"},
     "groundwork/errors.py:1: groundwork (layer 0) imports face_model (layer 1)"),
])
def test_an_import_against_the_rules_is_reported(tmp_path, files, problem):
    problems = import_problems(_tree(tmp_path, files))
    assert any(p.startswith(problem) for p in problems), problems


def test_lazy_heavy_imports_and_downward_imports_are_allowed(tmp_path):
    root = _tree(tmp_path, {"study/run.py": "import numpy\nfrom mapping.phone_gate import G\n"
                                            "def f():\n    import psychopy.visual\n",
                            "mapping/phone_gate.py": "from groundwork.errors import E\nclass G: pass\n",
                            "groundwork/errors.py": "class E(Exception): pass\n"})
    assert import_problems(root) == []


def test_the_ground_floor_imports_no_project_package():
    """``groundwork`` stands below every package: none of its files names another one."""
    others = [p for p in LAYERS if p != "groundwork"]
    for path in sorted((REPO / "groundwork").rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        names = [n for n, _, _ in _imports(tree, _module_name(REPO, path),
                                           path.name == "__init__.py")]
        assert [n for n in names if n.split(".")[0] in others] == [], path


# Inside ``talkingface``: the command line uses the MLflow logging, which reads the stages; the
# shared modules (config, paths, executor, provenance) sit under all three.
ROOMS = {"talkingface.stages": 1, "talkingface.experiments": 2, "talkingface.cli": 3,
         "talkingface.__main__": 4}


def _room(module: str) -> tuple[str, int]:
    for room, level in ROOMS.items():
        if module == room or module.startswith(room + "."):
            return room, level
    return "talkingface", 0


def room_problems(root: Path) -> list[str]:
    """Every import inside ``talkingface`` that runs against :data:`ROOMS`, one line each."""
    files = {_module_name(root, p): p for p in sorted((root / "talkingface").rglob("*.py"))}
    problems = []
    for mod, path in files.items():
        room, level = _room(mod)
        tree = ast.parse(path.read_text(), filename=str(path))
        for name, line, _ in _imports(tree, mod, path.name == "__init__.py"):
            target = _resolve(set(files), name)
            if target is None:
                continue
            other, other_level = _room(target)
            if other != room and other_level >= level:
                problems.append(f"{path.relative_to(root)}:{line}: {room} imports {other}; "
                                "only talkingface.cli → experiments → stages → shared modules")
    return problems


def test_talkingface_rooms_import_in_one_direction():
    assert room_problems(REPO) == []


def test_an_upward_import_between_rooms_is_reported(tmp_path):
    root = _tree(tmp_path, {"talkingface/stages/train.py": "from talkingface.cli.main import x\n",
                            "talkingface/cli/main.py": "x = 1\n"})
    assert room_problems(root) == ["talkingface/stages/train.py:1: talkingface.stages imports "
                                   "talkingface.cli; only talkingface.cli → experiments → "
                                   "stages → shared modules"]
