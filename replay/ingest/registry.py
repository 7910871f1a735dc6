"""The log formats rimu reads: one entry per format (python-can's ``MESSAGE_READERS`` is the
model), built-in ones first, then third parties' through the entry-point group
:data:`ENTRY_POINT_GROUP`.

A format is one module holding its reader and one :class:`LogFormat` entry here: its name
(``rimu ingest --format NAME``), the suffixes and the content sniffer that
``--format auto`` recognises it by, the reader, the options of the command it takes and the
extra that installs the library it is built on. :func:`replay.ingest.read_any` and the
``--format`` choices and help of ``rimu ingest`` and ``rimu inspect`` are built from
:func:`log_formats`, so a new format touches no other file.

A third-party package adds a format with an entry point naming a :class:`LogFormat`
(or a callable returning one), whose ``name`` is the entry point's name::

    [project.entry-points."rimu.log_readers"]
    mcap = "rimu_mcap:FORMAT"

This module imports nothing numerical (the parsers import it to build ``--help``); the
readers are named as ``"module:function"`` and imported when a log is read.
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

from fdi.errors import ConfigError

__all__ = ["BUILTIN", "ENTRY_POINT_GROUP", "FORMATS", "OPTIONS", "LogFormat", "format_help",
           "format_names", "get_format", "log_formats", "register_format"]

ENTRY_POINT_GROUP = "rimu.log_readers"
"""The entry-point group of third-party log formats."""
OPTIONS = ("map_path", "px4_topic")
"""Format-specific options of ``rimu ingest`` a reader may take (``--map``, ``--px4-topic``)
besides ``salvage``, which every reader takes."""


@dataclass(frozen=True)
class LogFormat:
    """One log format.

    Attributes
    ----------
    name : str
        ``--format`` value.
    reader : str or callable
        ``reader(path, *, salvage: bool, **options) -> LogRead``
        (:class:`replay.ingest.stream.LogRead`), or its ``"module:function"`` name; it gets
        the :data:`OPTIONS` listed in ``options`` as keywords.
    suffixes : tuple of str
        Lower-case file suffixes (``".bin"``) that ``--format auto`` takes for this format
        when no sniffer recognised the content.
    sniffer : str or callable or None
        ``sniffer(path) -> bool``: True when the file's first bytes are of this format
        (False on a file it cannot open), or its ``"module:function"`` name.
    options : tuple of str
        The :data:`OPTIONS` it takes (``"map_path"``: a ``rimu.ingest-map/1`` map).
    extra : str or None
        The extra of ``pip install "rimu[EXTRA]"`` that installs its library (None: the
        core install reads it).
    description : str
        A few words for ``--help``.
    """

    name: str
    reader: str | Callable[..., Any]
    suffixes: tuple[str, ...] = ()
    sniffer: str | Callable[[Path], bool] | None = None
    options: tuple[str, ...] = ()
    extra: str | None = None
    description: str = ""

    def __post_init__(self) -> None:
        if not self.name or self.name == "auto" or not self.name.replace("-", "").isalnum():
            raise ConfigError(f"log format name {self.name!r}: expected a word, not 'auto'")
        bad = [o for o in self.options if o not in OPTIONS]
        if bad:
            raise ConfigError(f"log format {self.name!r}: unknown option(s) {bad}; expected "
                              f"some of {', '.join(OPTIONS)}")
        if any(not s.startswith(".") or s != s.lower() for s in self.suffixes):
            raise ConfigError(f"log format {self.name!r}: suffixes must be lower case and "
                              f"start with '.', got {self.suffixes}")

    def read(self, path: str | Path, *, salvage: bool = False, **options: Any) -> Any:
        """Read ``path`` with this format's reader, passing the options it takes."""
        kw = {k: v for k, v in options.items() if k in self.options}
        return _resolve(self.reader)(path, salvage=salvage, **kw)

    def sniff(self, path: str | Path) -> bool:
        """Whether the sniffer recognises the file (False without a sniffer)."""
        return self.sniffer is not None and bool(_resolve(self.sniffer)(Path(path)))


def _resolve(obj: str | Callable[..., Any]) -> Callable[..., Any]:
    if callable(obj):
        return obj
    module, _, attr = obj.partition(":")
    return getattr(importlib.import_module(module), attr)


def _read_px4(path: str | Path, *, salvage: bool = False, px4_topic: str = "auto") -> Any:
    from replay.ingest.px4 import read_px4

    return read_px4(path, salvage=salvage, topic=px4_topic)


def _tabular(fmt: str) -> Callable[..., Any]:
    def read(path: str | Path, *, salvage: bool = False,
             map_path: str | Path | None = None) -> Any:
        from replay.ingest.tabular import read_tabular

        return read_tabular(path, fmt, map_path=map_path, salvage=salvage)

    read.__name__ = read.__qualname__ = f"read_{fmt}"
    return read


BUILTIN = (
    LogFormat("ardupilot", "replay.ingest.ardupilot:read_ardupilot", (".bin",),
              "replay.ingest.ardupilot:looks_like_dataflash", extra="logs",
              description="ArduPilot DataFlash .BIN (pymavlink)"),
    LogFormat("px4", _read_px4, (".ulg",), "replay.ingest.px4:looks_like_ulog",
              options=("px4_topic",), extra="logs", description="PX4 ULog .ulg (pyulog)"),
    LogFormat("mat", _tabular("mat"), (".mat",), options=("map_path",),
              description="MATLAB .mat (scipy.io)"),
    LogFormat("csv", _tabular("csv"), (".csv",), options=("map_path",), description="CSV"),
    LogFormat("rda", _tabular("rda"), (".rda", ".rdata"), options=("map_path",),
              extra="logs", description="R data .rda (rdata)"),
)
"""The built-in formats, in the order ``--format auto`` tries their sniffers."""
FORMATS = ("auto", *(f.name for f in BUILTIN))
"""``--format`` values of the built-in formats (third parties' come after them:
:func:`format_names`)."""

_FORMATS: dict[str, LogFormat] = {f.name: f for f in BUILTIN}
_LOADED = False


def register_format(fmt: LogFormat) -> LogFormat:
    """Add a format in-process (or replace a registered third-party one); returns it.

    Raises
    ------
    ConfigError
        Not a :class:`LogFormat`, or the name of a built-in format.
    """
    if not isinstance(fmt, LogFormat):
        raise ConfigError(f"register_format: expected a LogFormat, got {type(fmt).__name__}")
    if fmt.name in FORMATS:
        raise ConfigError(f"register_format: {fmt.name!r} is a built-in log format")
    _FORMATS[fmt.name] = fmt
    return fmt


def _entry_points() -> Iterable[Any]:
    return metadata.entry_points(group=ENTRY_POINT_GROUP)


def _load() -> None:
    """Register the entry points' formats once. A plug-in that cannot be loaded, names no
    :class:`LogFormat`, or whose format is named otherwise than its entry point or like a
    built-in one is skipped with a one-line warning (the other formats still read)."""
    global _LOADED
    if _LOADED:
        return
    _LOADED = True
    for ep in _entry_points():
        why = None
        try:
            obj = ep.load()
            if callable(obj) and not isinstance(obj, LogFormat):
                obj = obj()
        except Exception as exc:  # a broken plug-in must name itself, not stop the rest
            obj, why = None, f"cannot load {ep.value} ({exc})"
        if why is None and not isinstance(obj, LogFormat):
            why = f"{ep.value} is a {type(obj).__name__}, not a replay.ingest.LogFormat"
        elif why is None and obj.name != ep.name:
            why = f"{ep.value} is the format {obj.name!r}, not {ep.name!r}"
        elif why is None and obj.name in FORMATS:
            why = f"{obj.name!r} is a built-in log format"
        if why is not None:
            logging.getLogger("rimu").warning(
                f"log reader entry point {ep.name!r} ({ENTRY_POINT_GROUP}) skipped: {why}")
            continue
        _FORMATS[obj.name] = obj


def log_formats() -> tuple[LogFormat, ...]:
    """Every format: the built-in ones in :data:`BUILTIN` order, then third parties'."""
    _load()
    return tuple(_FORMATS.values())


def get_format(name: str) -> LogFormat:
    """The format of that name.

    Raises
    ------
    ConfigError
        No format of that name.
    """
    formats = {f.name: f for f in log_formats()}
    if name not in formats:
        raise ConfigError(f"unknown format {name!r}; expected one of "
                          f"{', '.join(('auto', *formats))}")
    return formats[name]


def format_names() -> tuple[str, ...]:
    """The ``--format`` choices: ``auto``, the built-in formats, then those registered and
    those of the entry points (named without importing the plug-ins, so ``--help`` stays
    light)."""
    names = dict.fromkeys(FORMATS)
    names.update(dict.fromkeys(_FORMATS))
    names.update(dict.fromkeys(ep.name for ep in _entry_points()))
    return tuple(names)


def format_help() -> str:
    """The ``--format`` help: the formats with their suffixes and extras."""
    parts = []
    for f in _FORMATS.values():
        said = [*f.suffixes, *([f"rimu[{f.extra}]"] if f.extra else [])]
        parts.append(f"{f.name} ({', '.join(said)})" if said else f.name)
    others = [n for n in format_names() if n != "auto" and n not in _FORMATS]
    return ("log format (default auto: from the content, else the suffix): "
            + ", ".join(parts + others))
