"""Packages whose names are imported when first used (groundwork.lazy): a light module of a
package does not bring the package's heavy dependencies, and every exported name is the
object its module defines."""
from __future__ import annotations

import subprocess
import sys

import pytest


def _modules_after(statement: str) -> set:
    out = subprocess.run([sys.executable, "-c", f"{statement}\nimport sys\n"
                          "print('\\n'.join(sorted(sys.modules)))"],
                         capture_output=True, text=True, check=True).stdout
    return set(out.split())


def test_the_config_modules_do_not_import_torch():
    """``talkingface.config`` reads ``mapping.config``: before, ``mapping/__init__`` imported
    torch with it (about 2 s of every command's start)."""
    loaded = _modules_after("import talkingface.config")
    assert "mapping.config" in loaded and "torch" not in loaded
    assert "sklearn" not in _modules_after("import face_model.phones")
    assert "torch" in _modules_after("from mapping import GatedMLP")  # what the name needs


@pytest.mark.parametrize("package", ["mapping", "face_model", "data_synth"])
def test_every_exported_name_is_its_modules_object(package):
    import importlib

    pkg = importlib.import_module(package)
    where = {name: module for module, names in pkg._EXPORTS.items() for name in names}
    assert set(pkg.__all__) == set(where) and set(where) <= set(dir(pkg))
    for name in pkg.__all__:
        assert getattr(pkg, name) is getattr(importlib.import_module(where[name]), name), name


def test_a_sub_module_and_an_unknown_name():
    import mapping

    assert mapping.features.mfcc is mapping.mfcc  # a sub-module by attribute, as eager imports
    with pytest.raises(AttributeError, match="module 'mapping' has no attribute 'no_such'"):
        mapping.no_such  # noqa: B018
    with pytest.raises(ImportError):
        from mapping import no_such_name  # noqa: F401
