"""Lazy package exports (PEP 562): a package's names are imported when first used.

A package ``__init__`` lists what it re-exports (name → module) and calls :func:`attach`;
``import fdi.errors`` then no longer loads the monitor, numba and scipy, and the first use
of ``fdi.Monitor`` imports :mod:`fdi.monitor` as ``from fdi.monitor import Monitor`` would.

A re-exported name that is also a submodule's name (``thresholds.tune``, the function, in
the module ``thresholds.tune``) stays the re-exported object when the submodule is
imported, as it did with eager imports.

Examples
--------
>>> _EXPORTS = {"Monitor": "fdi.monitor", "load_calibration": "fdi.calfile"}
>>> __getattr__, __dir__ = attach(__name__, _EXPORTS)
"""

from __future__ import annotations

import importlib
import sys
import types
from collections.abc import Callable, Mapping

__all__ = ["attach"]


class _Package(types.ModuleType):
    """A package whose re-exported names win over submodules of the same name."""

    _shadowed: frozenset[str] = frozenset()

    def __setattr__(self, name: str, value: object) -> None:
        # the import system sets ``package.sub = module`` after loading a submodule; for a
        # name the package re-exports, keep the re-exported object instead
        if isinstance(value, types.ModuleType) and name in type(self)._shadowed:
            return
        super().__setattr__(name, value)


def attach(package: str, exports: Mapping[str, str]
           ) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of a lazy package.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    exports : mapping of str to str
        Public name → module that defines it.

    Returns
    -------
    (__getattr__, __dir__)
        To be bound to those names in the package.
    """
    mod = sys.modules[package]
    names = dict(exports)
    shadowed = frozenset(n for n, m in names.items() if m == f"{package}.{n}")
    if shadowed:
        mod.__class__ = type("_Package", (_Package,), {"_shadowed": shadowed})

    def __getattr__(name: str) -> object:
        where = names.get(name)
        if where is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(where), name)
        types.ModuleType.__setattr__(mod, name, value)     # later look-ups are direct
        return value

    def __dir__() -> list[str]:
        return sorted(set(mod.__dict__) | set(names))

    return __getattr__, __dir__
