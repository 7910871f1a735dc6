"""The ``rimu`` command: one sub-command per module in :mod:`rimu.commands`.

Every module there defines ``HELP`` (one line), ``configure(parser)`` and
``run(args) -> int``; only the module of the command named is imported (its ``configure``
imports nothing numerical), so ``rimu --version`` and ``rimu COMMAND --help`` start fast.
A :class:`fdi.errors.RimuError` becomes one line on stderr and exit code 2; Ctrl-C exits
130; nothing prints a traceback unless ``--debug`` is given. Python warnings become one
``rimu: warning:`` line each (once per text).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
import warnings
from collections.abc import Sequence

from fdi.errors import RimuError  # light: fdi's package imports lazily (fdi.lazy)
from rimu import __version__
from rimu.optional import missing_text, refusal

__all__ = ["COMMANDS", "build_parser", "main"]

COMMANDS: dict[str, str] = {
    "calibrate": "rimu.commands.calibrate",
    "characterise": "rimu.commands.characterise",
    "demo": "rimu.commands.demo",
    "diagnose": "rimu.commands.diagnose",
    "evaluate": "rimu.commands.evaluate",
    "export": "rimu.commands.export",
    "ingest": "rimu.commands.ingest",
    "inspect": "rimu.commands.inspect",
    "monitor": "rimu.commands.monitor",
    "monitor-file": "rimu.commands.monitor_file",
    "parity": "rimu.commands.parity",
    "repeat": "rimu.commands.repeat",
    "replay": "rimu.commands.replay",
    "tune": "rimu.commands.tune",
}
"""Top-level sub-commands and their modules."""

SIMULATE: dict[str, str] = {
    "calibration": "rimu.commands.simulate_calibration",
    "flight": "rimu.commands.simulate_flight",
}
"""``rimu simulate KIND`` sub-commands."""


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr (exit 2)."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"rimu: error: {message} (see {self.prog} --help)\n")


class _StderrHandler(logging.StreamHandler):
    """Writes to whatever ``sys.stderr`` is at the time (tests swap it)."""

    @property  # type: ignore[override]
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value) -> None:
        pass


class _Lower(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        return super().format(record).replace(record.levelname, record.levelname.lower(), 1)


def _log_to_stderr() -> None:
    """Warnings and diagnostics go to stderr through :mod:`logging` (stdout stays clean)."""
    root = logging.getLogger("rimu")
    if not any(getattr(h, "_rimu", False) for h in root.handlers):
        h = _StderrHandler()
        h.setFormatter(_Lower("rimu: %(levelname)s: %(message)s"))
        h._rimu = True  # type: ignore[attr-defined]
        root.addHandler(h)
    root.setLevel(logging.INFO)
    root.propagate = False
    warnings.showwarning = _show_warning
    _SHOWN.clear()                  # once per text and per command run
    from rimu.kernel_notice import install

    install()                       # "compiling the monitor kernel, once, about 8 s"


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A Python warning as one ``rimu: warning:`` line: its message, without the source
    path, line number and code line Python would print (they mean nothing to a user)."""
    text = " ".join(str(message).split())
    if issubclass(category, RuntimeWarning) and text.startswith(("overflow", "invalid value",
                                                                 "divide by zero")):
        text = f"numerical {text} (a value out of range in the input?)"
    elif category not in (UserWarning, RuntimeWarning):
        text += f" ({category.__name__})"
    if text in _SHOWN:                  # the same numerical warning from many places: once
        return
    _SHOWN.add(text)
    logging.getLogger("rimu").warning(text)


_SHOWN: set[str] = set()


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


def _wanted(argv: Sequence[str] | None) -> tuple[str, ...] | None:
    """The sub-command ``argv`` names (``("tune",)``, ``("simulate", "flight")``), ``()``
    for none (``rimu --version``), or None when every parser is needed (``rimu --help``,
    an unknown command: argparse lists them all)."""
    if argv is None:
        return None
    words = [a for a in argv if not a.startswith("-")]
    if not words:
        return () if any(a == "--version" for a in argv) else None
    if words[0] in COMMANDS:
        return (words[0],)
    if words[0] == "simulate" and len(words) > 1 and words[1] in SIMULATE:
        return ("simulate", words[1])
    return None


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser: every sub-command, or with ``argv`` only the one it names.

    Each sub-command's module is imported to build its parser; building only the one asked
    for keeps ``rimu --version`` and ``rimu COMMAND --help`` from importing the others.
    """
    want = _wanted(argv)
    parser = _Parser(
        prog="rimu", description="Fault detection and isolation for redundant IMUs.")
    parser.add_argument("--version", action="version", version=f"rimu {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="show a traceback on errors (for bug reports)")
    if want == ():
        return parser
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module in COMMANDS.items():
        if want is None or want == (name,):
            _add(sub, name, module)
    if want is not None and want[0] != "simulate":
        return parser
    sim = sub.add_parser("simulate", help="simulate a calibration session or a flight",
                         description="Simulate a calibration session or a flight, with a "
                                     "truth sidecar.")
    simsub = sim.add_subparsers(dest="what", metavar="WHAT")
    for name, module in SIMULATE.items():
        if want is None or want == ("simulate", name):
            _add(simsub, name, module)
    return parser


def _old_spelling(argv: Sequence[str]) -> str | None:
    """The refusal of a command spelled as before a command was split into subcommands
    (``rimu calibrate in-flight F``: :func:`rimu.commands.calibrate.old_spelling`)."""
    words = [i for i, a in enumerate(argv) if not str(a).startswith("-")]
    if not words or argv[words[0]] != "calibrate":
        return None
    from rimu.commands.calibrate import old_spelling

    return old_spelling(argv[words[0] + 1:])


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parsed = _parse(argv)
    if isinstance(parsed, int):             # --help, --version, or refused in one line
        return parsed
    args, command = parsed
    from fdi.progress import session

    try:
        from rimu.argtypes import refuse_ignored_options
        from rimu.outputs import refuse_outputs_over_inputs

        refuse_outputs_over_inputs(args)        # no command writes over or into its input
        refuse_ignored_options(args, f"rimu {args.command}")   # nothing ignored silently
        with session(command or "rimu", enabled=not getattr(args, "no_progress", False)):
            return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("rimu: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 1
    except (RimuError, ModuleNotFoundError, OSError) as exc:
        return _failed(exc, args, command)


def _error(text: str) -> int:
    print(f"rimu: error: {text}", file=sys.stderr)
    return 2


def _parse(argv: list[str]) -> tuple[argparse.Namespace, str] | int:
    """The parsed command line and the command's name (``"simulate flight"``), or the exit
    code when it stops there: ``--help``, ``--version``, a usage error, an old spelling, an
    extra the command needs that is not installed (each one line on stderr, exit 2)."""
    if (hint := _old_spelling(argv)) is not None:   # one line and exit 2, like a usage error
        return _error(hint)
    try:
        parser = build_parser(argv)
    except ModuleNotFoundError as exc:  # a command module needs an extra at import
        if (text := missing_text(exc)) is None or "--debug" in argv:
            raise
        return _error(text)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:       # --help, --version, or a usage error (one line, exit 2)
        return int(exc.code or 0) if not isinstance(exc.code, str) else 2
    _log_to_stderr()
    if getattr(args, "_run", None) is None:
        parser.print_help()
        return 2
    command = " ".join(w for w in (args.command, getattr(args, "what", None)) if w)
    if (text := refusal(command, args)) is not None:  # an extra it needs at the end
        return _error(text)
    return args, command


def _failed(exc: Exception, args: argparse.Namespace, command: str) -> int:
    """A command's error as one line and exit 2 (re-raised with ``--debug``, and when a
    missing module is not an optional package: a broken install)."""
    if isinstance(exc, ModuleNotFoundError) and not isinstance(exc, RimuError):
        text = missing_text(exc, command)   # an optional package (rimu/optional.py) missing
        if text is None or args.debug:
            raise exc
        return _error(text)
    if args.debug:
        raise exc
    return _error(str(exc))
