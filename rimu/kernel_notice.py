"""Say on stderr when the monitor kernel is about to be compiled (the first use after an
install): ``rimu: info: compiling the monitor kernel, once, about 8 s``.

The kernel (:mod:`fdi.kernel`) is compiled by numba with ``cache=True``: numba writes the
machine code beside the source (``fdi/__pycache__``) or, where the package folder is
read-only, in the user's cache folder (numba's ``UserWideCacheLocator``,
``~/.cache/numba/...``; ``NUMBA_CACHE_DIR`` overrides both). When neither holds the
kernel's index, the next import of :mod:`fdi.kernel` is followed by a compile of about 8 s;
:func:`install` hooks that import (``sys.meta_path``) to say so first, once.
"""

from __future__ import annotations

import importlib.abc
import logging
import os
import sys
from pathlib import Path

__all__ = ["MESSAGE", "install", "kernel_cached", "uninstall"]

MESSAGE = "compiling the monitor kernel, once, about 8 s"
_ENTRY = "kernel.*advance*.nbi"
"""numba's index file of the kernel's entry point (``kernel.<qualname>-<line>.pyXY.nbi``)."""


def _cache_dirs(src: Path) -> list[Path]:
    """Where numba may have cached :mod:`fdi.kernel`, most likely first."""
    out = []
    env = os.environ.get("NUMBA_CACHE_DIR")
    if env:
        out.append(Path(env))
    out.append(src.parent / "__pycache__")
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    out.append(Path(xdg) / "numba")
    return out


def kernel_cached() -> bool:
    """True when an index of the compiled kernel exists in one of numba's cache folders."""
    import fdi

    src = Path(fdi.__file__).resolve().parent / "kernel.py"
    for d in _cache_dirs(src):
        if not d.is_dir():
            continue
        hits = d.glob(_ENTRY) if d.name == "__pycache__" else d.rglob(_ENTRY)
        if next(iter(hits), None) is not None:
            return True
    return False


class _Notice(importlib.abc.MetaPathFinder):
    """Announces the compile when :mod:`fdi.kernel` is first imported; finds nothing."""

    def find_spec(self, name, path=None, target=None):
        if name == "fdi.kernel":
            uninstall()
            if not kernel_cached():
                logging.getLogger("rimu").info(MESSAGE)
        return None


_FINDER = _Notice()


def install() -> None:
    """Hook the first import of :mod:`fdi.kernel` (no-op when already imported)."""
    if "fdi.kernel" not in sys.modules and _FINDER not in sys.meta_path:
        sys.meta_path.insert(0, _FINDER)


def uninstall() -> None:
    """Remove the hook."""
    if _FINDER in sys.meta_path:
        sys.meta_path.remove(_FINDER)
