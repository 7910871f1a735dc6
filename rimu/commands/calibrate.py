"""``rimu calibrate PROCEDURE ...``: one subcommand per calibration procedure, each with only
its own options.

==============  =========================================================================
``turntable``   a turntable session (:mod:`rimu.commands.calibrate_turntable`)
``ferraris``    a Ferraris session: static positions and known-angle rotations
                (:mod:`rimu.commands.calibrate_ferraris`)
``in-flight``   an IMU set against itself in flight (:mod:`rimu.commands.calibrate_inflight`)
``static``      IMUs at rest against one of them (:mod:`rimu.commands.calibrate_static`)
==============  =========================================================================

The spellings of the single option list before the split (``rimu calibrate SESSION``,
``--in-flight F``, ``--static DIR``, ``--ferraris CSV``) are refused in one line with the new
spelling (:func:`old_spelling`, called by :func:`rimu.cli.main` before parsing).
"""

from __future__ import annotations

import argparse
import importlib
import shlex
from collections.abc import Sequence

__all__ = ["HELP", "OLD_OPTIONS", "PROCEDURES", "configure", "old_spelling", "run"]

HELP = ("calibrate redundant gyros/accelerometers: rimu calibrate turntable | ferraris | "
        "in-flight | static (each with its own options)")

PROCEDURES: dict[str, str] = {
    "turntable": "rimu.commands.calibrate_turntable",
    "ferraris": "rimu.commands.calibrate_ferraris",
    "in-flight": "rimu.commands.calibrate_inflight",
    "static": "rimu.commands.calibrate_static",
}
"""Subcommand → module (``HELP``, ``configure(parser)``, ``run(args)``)."""
OLD_OPTIONS: dict[str, str] = {"--in-flight": "in-flight", "--static": "static",
                               "--ferraris": "ferraris"}
"""The options that chose a procedure before the split → its subcommand."""


def configure(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="what", metavar="PROCEDURE", required=True)
    for name, module in PROCEDURES.items():
        mod = importlib.import_module(module)
        q = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.configure(q)
        q.set_defaults(_procedure=mod.run)


def run(args: argparse.Namespace) -> int:
    """Run the procedure's subcommand."""
    return int(args._procedure(args) or 0)


def old_spelling(rest: Sequence[str]) -> str | None:
    """The one-line refusal of a spelling from before the split, with the new one, or None.

    ``rest`` is what follows ``calibrate`` on the command line.

    >>> old_spelling(["--static", "rest", "--out", "c.json"])[:70]
    'rimu calibrate --static is now a subcommand: rimu calibrate static rest'
    >>> old_spelling(["static", "rest", "--out", "c.json"]) is None
    True
    """
    rest = [str(a) for a in rest]
    if not rest or rest[0] in PROCEDURES or rest[0] in ("-h", "--help"):
        return None
    for i, a in enumerate(rest):
        opt, eq, value = a.partition("=")
        if opt in OLD_OPTIONS:
            new = OLD_OPTIONS[opt]
            tail = [value, *rest[:i], *rest[i + 1:]] if eq else [*rest[i + 1:], *rest[:i]]
            return (f"rimu calibrate {opt} is now a subcommand: "
                    f"{shlex.join(['rimu', 'calibrate', new, *tail])} "
                    f"(its options: rimu calibrate {new} --help)")
    return ("rimu calibrate SESSION is now a subcommand: "
            f"{shlex.join(['rimu', 'calibrate', 'turntable', *rest])} (the procedures: "
            f"rimu calibrate {' | '.join(PROCEDURES)}; rimu calibrate --help)")
