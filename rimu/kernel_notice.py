"""Say on stderr when the monitor kernel is being compiled (the first use after an
install): ``rimu: info: compiling the monitor kernel, once, about 8 s``.

The kernel (:mod:`fdi.kernel`) is compiled by numba with ``cache=True``: numba writes the
machine code beside the source (``fdi/__pycache__``) or, where the package folder is
read-only, in the user's cache folder (numba's ``UserWideCacheLocator``,
``~/.cache/numba/...``; ``NUMBA_CACHE_DIR`` overrides both), and later processes load it.
:func:`install` hooks the first import of :mod:`fdi.kernel` (``sys.meta_path``) to register
a listener for numba's ``"numba:compile"`` event, which numba broadcasts only when it really
compiles (a cache miss), not when it loads the cached code: the notice comes once, just
before the compile, and never for a command that stops before running the monitor.
"""

from __future__ import annotations

import importlib.abc
import logging
import sys

__all__ = ["MESSAGE", "install", "uninstall"]

MESSAGE = "compiling the monitor kernel, once, about 8 s"
_KERNEL = "fdi.kernel"


def _compiles_kernel(event) -> bool:
    """True for a compile event of a function defined in :mod:`fdi.kernel`."""
    d = getattr(event, "data", None) or {}
    fn = getattr(d.get("dispatcher"), "py_func", None)
    return getattr(fn, "__module__", "") == _KERNEL


def _listen() -> None:
    """Register the one-shot listener of numba's compile events."""
    from numba.core import event

    class _Once(event.Listener):
        said = False

        def on_start(self, ev) -> None:
            if not self.said and _compiles_kernel(ev):
                self.said = True
                logging.getLogger("rimu").info(MESSAGE)

        def on_end(self, ev) -> None:
            pass

    event.register("numba:compile", _Once())


class _Notice(importlib.abc.MetaPathFinder):
    """On the first import of :mod:`fdi.kernel`, listens for its compile; finds nothing."""

    def find_spec(self, name, path=None, target=None):
        if name == _KERNEL:
            uninstall()
            _listen()
        return None


_FINDER = _Notice()


def install() -> None:
    """Hook the first import of :mod:`fdi.kernel` (no-op when it is already imported)."""
    if _KERNEL not in sys.modules and _FINDER not in sys.meta_path:
        sys.meta_path.insert(0, _FINDER)


def uninstall() -> None:
    """Remove the hook."""
    if _FINDER in sys.meta_path:
        sys.meta_path.remove(_FINDER)
