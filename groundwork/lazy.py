"""A package's names imported when first used (PEP 562), so that importing one light module of
a package (``mapping.config``, ``face_model.phones``) does not import the whole package's heavy
dependencies (torch, scikit-learn, scipy.signal) with it.

A package's ``__init__`` lists what it exports and from which module::

    __getattr__, __dir__ = lazy_exports(__name__, {"mapping.baselines": ["BASELINES", ...]})

``from mapping import BASELINES`` and ``mapping.BASELINES`` then import ``mapping.baselines``
on first use and return the same object an eager import would; ``mapping.features`` (a
sub-module not imported yet) is imported the same way.
"""
from __future__ import annotations

import importlib
import sys


def lazy_exports(package: str, exports: dict):
    """``(__getattr__, __dir__)`` for the package ``package``: each name of ``exports``
    (``{module: [names]}``) comes from its module on first use, any other name from the
    sub-module of that name.

    Raises
    ------
    AttributeError
        (from ``__getattr__``) for a name that is neither exported nor a sub-module, as for any
        module.
    """
    where = {name: module for module, names in exports.items() for name in names}

    def __getattr__(name: str):
        if name in where:
            value = getattr(importlib.import_module(where[name]), name)
        else:
            try:
                value = importlib.import_module(f"{package}.{name}")
            except ModuleNotFoundError as exc:
                if exc.name != f"{package}.{name}":
                    raise  # the sub-module exists but something it imports does not
                raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
        globals_of(package)[name] = value  # later lookups skip this function
        return value

    def __dir__():
        return sorted(set(globals_of(package)) | set(where))

    return __getattr__, __dir__


def globals_of(package: str) -> dict:
    """The namespace of the (imported) package ``package``."""
    return vars(sys.modules[package])
