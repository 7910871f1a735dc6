"""The optional dependencies: which extra of ``pyproject.toml`` brings each, and the one-line
refusal when a command reaches one that is not installed.

The core install (``pip install rimu``) calibrates, monitors and replays; the rest comes
with extras (``pip install "rimu[logs]"``). Each module imports such a package where it
needs it (inside the function), so the command gets as far as it can without it; when it
is missing the import raises :class:`ModuleNotFoundError`, which :func:`rimu.cli.main` turns
into :func:`missing_text` (one line, exit 2). Where a command would do its work first and
reach the package only at the end (the plots of ``rimu evaluate``, a ``--report`` folder),
:func:`needed` names it from the options and the command is refused before it starts.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys

__all__ = ["EXTRAS", "available", "missing_extra", "missing_text", "needed", "refusal"]

EXTRAS: dict[str, tuple[str, str]] = {
    "dask": ("fleet", "distributed"),
    "distributed": ("fleet", "distributed"),
    "matplotlib": ("plots", "matplotlib"),
    "pymavlink": ("logs", "pymavlink"),
    "pyulog": ("logs", "pyulog"),
    "rdata": ("logs", "rdata"),
}
"""Top-level import name → (extra that installs it, its distribution name)."""


def missing_extra(exc: ModuleNotFoundError) -> tuple[str, str] | None:
    """(extra, distribution) of the optional package ``exc`` failed to import, or None when
    the missing module is not one of :data:`EXTRAS` (then it is a broken install)."""
    name = (exc.name or "").split(".")[0]
    return EXTRAS.get(name)


def missing_text(exc: ModuleNotFoundError, command: str | None = None) -> str | None:
    """The one-line refusal for ``exc``, or None when it is not an optional package.

    >>> missing_text(ModuleNotFoundError("x", name="pymavlink.DFReader"), "ingest")
    'rimu ingest needs pymavlink, which the "logs" extra installs: pip install "rimu[logs]"'
    """
    found = missing_extra(exc)
    if found is None:
        return None
    extra, dist = found
    who = f"rimu {command}" if command else "this command"
    return (f'{who} needs {dist}, which the "{extra}" extra installs: '
            f'pip install "rimu[{extra}]"')


def available(module: str) -> bool:
    """Whether top-level ``module`` can be imported (looked up, not imported)."""
    if module in sys.modules:
        return sys.modules[module] is not None
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


_PLOTTING = {"calibrate turntable": ("plot",), "calibrate in-flight": ("report",),
             "characterise": ("report",),
             "diagnose": ("report",), "monitor-file": ("baseline_plot",)}
"""Commands whose options, when given, make them draw figures at the end of their work."""


def needed(command: str, args: argparse.Namespace) -> tuple[str, ...]:
    """Optional packages ``rimu command`` with ``args`` will import after its main work:
    ``rimu evaluate`` always draws its plots (matplotlib) and runs on Dask for any other
    ``--scheduler`` than ``serial``; ``--plot`` and ``--report`` draw figures."""
    out = []
    if command == "evaluate":
        out.append("matplotlib")
        if getattr(args, "scheduler", "serial") != "serial":
            out.append("distributed")
    if any(getattr(args, opt, None) for opt in _PLOTTING.get(command, ())):
        out.append("matplotlib")
    return tuple(out)


def refusal(command: str, args: argparse.Namespace) -> str | None:
    """The one-line refusal of :func:`missing_text` for the first package of
    :func:`needed` that is not installed, or None when all are."""
    for module in needed(command, args):
        if not available(module):
            return missing_text(ModuleNotFoundError(module, name=module), command)
    return None
