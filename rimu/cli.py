"""The ``rimu`` command: one sub-command per module in :mod:`rimu.commands`.

Every module there defines ``HELP`` (one line), ``configure(parser)`` and
``run(args) -> int``. A :class:`fdi.errors.RimuError` becomes one line on stderr and exit
code 2; Ctrl-C exits 130; nothing prints a traceback unless ``--debug`` is given.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from fdi.errors import RimuError
from rimu import __version__

__all__ = ["COMMANDS", "build_parser", "main"]

COMMANDS: dict[str, str] = {
    "calibrate": "rimu.commands.calibrate",
    "demo": "rimu.commands.demo",
    "diagnose": "rimu.commands.diagnose",
    "evaluate": "rimu.commands.evaluate",
    "ingest": "rimu.commands.ingest",
    "monitor": "rimu.commands.monitor",
    "monitor-file": "rimu.commands.monitor_file",
    "parity": "rimu.commands.parity",
    "replay": "rimu.commands.replay",
    "tune": "rimu.commands.tune",
}
"""Top-level sub-commands and their modules."""

SIMULATE: dict[str, str] = {
    "calibration": "rimu.commands.simulate_calibration",
    "flight": "rimu.commands.simulate_flight",
}
"""``rimu simulate KIND`` sub-commands."""


def _add(sub: argparse._SubParsersAction, name: str, module: str) -> None:
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name != module:
            raise
        return
    p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
    mod.configure(p)
    p.set_defaults(_run=mod.run)


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser."""
    parser = argparse.ArgumentParser(
        prog="rimu", description="Fault detection and isolation for redundant IMUs.")
    parser.add_argument("--version", action="version", version=f"rimu {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="show a traceback on errors (for bug reports)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module in COMMANDS.items():
        _add(sub, name, module)
    sim = sub.add_parser("simulate", help="simulate a calibration session or a flight",
                         description="Simulate a calibration session or a flight, with a "
                                     "truth sidecar.")
    simsub = sim.add_subparsers(dest="what", metavar="WHAT")
    for name, module in SIMULATE.items():
        _add(simsub, name, module)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    run = getattr(args, "_run", None)
    if run is None:
        parser.print_help()
        return 2
    try:
        return int(run(args) or 0)
    except RimuError as exc:
        if args.debug:
            raise
        print(f"rimu: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("rimu: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 1
