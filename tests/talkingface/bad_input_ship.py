"""The bad-input table's part for ``tools/ship_default_model.py``: runs that are not runs, a
voices stage that is missing, not JSON or not finished, a default child whose files are missing
or damaged (a changed array, a truncated file, no front end), a child that is not
``configs/voices.yaml``'s model or trained under other settings, and ``--check`` without a
shipped model or against such runs.

``CASES`` are ``(argv, names)`` as in :mod:`tests.talkingface.bad_input_cases`, but ``argv`` is
the tool's (it is not a ``talkingface`` command, so it is not one of that table's ``PARTS``):
:func:`test_ship_default_model_refuses_bad_input_in_one_line` runs them, with the table's
contract — exit 2, exactly one line ``error: ...`` on stderr naming the file or value, no file
of the working folder changed or made, and the shipped model (``mapping/models/default``) left
as it was. :func:`add_inputs` makes the runs they name from copies of the shipped model
(:func:`fake_run`).
"""
from __future__ import annotations

import csv
import hashlib
import importlib.util
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from groundwork import modelfile
from mapping import checkpoint
from mapping.checkpoint import AudioMapping, front_file
from talkingface.config import to_dict
from talkingface.stages.models import SHIPPED_DIR, shipped_default

TOOL = Path(__file__).resolve().parents[2] / "tools" / "ship_default_model.py"
TARGET = ["--target", "shipped_new"]  # never made: every case is refused before


def tool():
    """tools/ship_default_model.py as a module."""
    spec = importlib.util.spec_from_file_location("ship_default_model", TOOL)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def fake_run(run: Path, *, child: str | None = None, config: dict | None = None) -> Path:
    """A run folder with what the tool reads, made from the shipped model's files: its
    ``voices/done.json`` naming ``child`` (default: ``configs/voices.yaml``'s model), the child's
    ``.tfmap`` (the shipped arrays, re-saved with ``config`` as its recorded config; default the
    config the paper's config and voices.yaml give the child today) with its front end, the
    run's Motion Units and its corpus's ``manifest.csv`` and ``corpus.json`` (two rows)."""
    want, cfg = tool().expected()
    child = child or want
    tfmap, units, _ = shipped_default()
    mapping = AudioMapping.load(tfmap)
    mapping.metadata["config"] = to_dict(cfg) if config is None else config
    folder = run / "voices" / child
    folder.mkdir(parents=True)
    mapping.save(folder / tfmap.name)  # its front end is copied beside it
    (run / "units").mkdir()
    shutil.copyfile(units, run / "units" / "motion_units.npz")
    corpus = run / "corpus"
    corpus.mkdir()
    with open(corpus / "manifest.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["utt_id", "speaker", "expression", "text"])
        w.writerows([["s00_neutral_000", "s00", "neutral", "a"],
                     ["s00_smile_000", "s00", "smile", "a"]])
    (corpus / "corpus.json").write_text(json.dumps(
        {"seed": 2002, "settings": {"backend": "espeak", "voice": "en-us+m3"}}))
    (run / "voices" / "done.json").write_text(json.dumps(
        {"model": child, "fingerprint": "fake", "models": {child: {
            "tfmap": f"{child}/{tfmap.name}", "corpus": "", "units": ""}}}))
    return run


def child_tfmap(run: Path) -> Path:
    """The ``.tfmap`` of the default child of a :func:`fake_run`."""
    done = json.loads((run / "voices" / "done.json").read_text())
    return run / "voices" / done["models"][done["model"]]["tfmap"]


def change_array(path: Path, *, keep_checksum: bool) -> str:
    """Add 1 to the first value of the first ``mapper/`` array of the ``.tfmap`` at ``path``,
    with the record as it was (``keep_checksum``: the file is then damaged) or a record of its
    own (a valid file of other weights). Returns the array's name."""
    found = modelfile.read_model(path, kind=checkpoint.KIND, versions=(checkpoint.VERSION,))
    arrays = dict(found.arrays)
    name = next(k for k in sorted(arrays) if arrays[k].dtype.kind == "f" and arrays[k].size)
    arrays[name] = arrays[name].copy()
    arrays[name].flat[0] += 1
    if keep_checksum:
        with np.load(path, allow_pickle=False) as z:
            record = z[modelfile.METADATA]
        with open(path, "wb") as f:
            np.savez(f, **{modelfile.METADATA: record}, **arrays)
    else:
        modelfile.write_model(path, arrays, found.metadata, kind=found.kind,
                              version=found.version)
    return name


def add_inputs(root: Path) -> None:
    """Make the runs :data:`CASES` name in ``root``."""
    (root / "not_a_run").mkdir()
    bad_done = {"ship_notjson": "{ not json", "ship_nochild": json.dumps(
        {"model": "gone", "models": {}, "fingerprint": "x"})}
    for name, text in bad_done.items():
        (root / name / "voices").mkdir(parents=True)
        (root / name / "voices" / "done.json").write_text(text)
    fake_run(root / "ship_notfmap")
    child_tfmap(root / "ship_notfmap").unlink()
    fake_run(root / "ship_tampered")
    change_array(child_tfmap(root / "ship_tampered"), keep_checksum=True)
    fake_run(root / "ship_truncated")
    units = root / "ship_truncated" / "units" / "motion_units.npz"
    units.write_bytes(units.read_bytes()[: units.stat().st_size // 2])
    if CAUSAL:  # a default that reads the causal front end keeps it beside its model
        fake_run(root / "ship_nofront")
        front_file(child_tfmap(root / "ship_nofront")).unlink()
    fake_run(root / "ship_otherchild", child="one-voice")
    config = to_dict(tool().expected()[1])
    config["mapping"]["hidden_max"] = 40
    fake_run(root / "ship_othersettings", config=config)
    (root / "shipped_empty").mkdir()
    good = fake_run(root / "ship_good")
    assert tool().main([str(good), "--target", str(root / "shipped_ok")]) == 0


DEFAULT = tool().expected()[0]  # configs/voices.yaml's model
CAUSAL = tool().expected()[1].mapping.recogniser == "causal"
TAMPERED = f"ship_tampered/voices/{DEFAULT}/gated_mlp_utterance.tfmap"
CASES: list = [
    (["no_such_run", *TARGET], ["RUN_DIR no_such_run", "not a folder"]),
    (["not_a_run", *TARGET], ["not_a_run/voices/done.json not found", "voices stage"]),
    (["ship_notjson", *TARGET], ["ship_notjson/voices/done.json", "not valid JSON"]),
    (["ship_nochild", *TARGET], ["ship_nochild/voices/done.json", "not a finished voices"]),
    (["ship_notfmap", *TARGET], ["gated_mlp_utterance.tfmap not found", DEFAULT]),
    (["ship_tampered", *TARGET], [TAMPERED, "checksum mismatch"]),
    (["ship_truncated", *TARGET], ["ship_truncated/units/motion_units.npz", "truncated"]),
    (["ship_otherchild", *TARGET], ["'one-voice'", f"voices.yaml's model is '{DEFAULT}'"]),
    (["ship_othersettings", *TARGET], ["mapping.hidden_max=40", "(now 25)"]),
    ([*TARGET], ["give RUN_DIR"]),
    (["--check", "--target", "shipped_empty"], ["shipped_empty/provenance.json not found"]),
    (["--check", "not_a_run", "--target", "shipped_ok"],
     ["not_a_run/voices/done.json not found"]),
    (["--check", "ship_tampered", "--target", "shipped_ok"], [TAMPERED, "checksum mismatch"]),
] + ([(["ship_nofront", *TARGET], ["gated_mlp_utterance.front.npz", "missing"])] if CAUSAL
     else [])  # a default read through pocketsphinx or hama has no front end file to miss


def _hashes(root: Path) -> dict:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(Path(root).rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def ship_world(tmp_path_factory):
    """A working folder with the runs of :data:`CASES` (:func:`add_inputs`)."""
    root = tmp_path_factory.mktemp("bad_input_ship")
    add_inputs(root)
    return root


@pytest.mark.parametrize("argv, names", CASES, ids=[" ".join(c[0])[:60] for c in CASES])
def test_ship_default_model_refuses_bad_input_in_one_line(ship_world, monkeypatch, capsys,
                                                          argv, names):
    monkeypatch.chdir(ship_world)
    before, shipped = _hashes(ship_world), _hashes(SHIPPED_DIR)
    capsys.readouterr()
    code = tool().main(argv)
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, (argv, err)
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    for n in names:
        assert n in lines[0], (n, lines[0])
    assert _hashes(ship_world) == before, "a file of the working folder was changed or made"
    assert _hashes(SHIPPED_DIR) == shipped, "the shipped model was changed"
