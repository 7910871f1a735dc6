"""Choose the reader of a log: by ``--format`` or, with ``auto``, by content and suffix.

The formats and their readers are the entries of :mod:`replay.ingest.registry` (built-in
and third parties'); this module only dispatches to them.
"""

from __future__ import annotations

from pathlib import Path

from fdi.errors import ConfigError
from replay.ingest.registry import FORMATS, get_format, log_formats
from replay.ingest.stream import LogRead

__all__ = ["FORMATS", "detect_format", "merge_reads", "read_any"]


def detect_format(path: str | Path) -> str:
    """The format of a log from its first bytes (each format's sniffer, in registry
    order), else its suffix.

    Raises
    ------
    ConfigError
        When neither says.
    """
    p = Path(path)
    formats = log_formats()
    for f in formats:
        if f.sniff(p):
            return f.name
    suffix = p.suffix.lower()
    for f in formats:
        if suffix in f.suffixes:
            return f.name
    raise ConfigError(f"{p}: cannot tell the log format (suffix {suffix!r}); give --format "
                      f"one of {', '.join(f.name for f in formats)}")


def _and(names: list[str]) -> str:
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"


def read_any(path: str | Path, fmt: str = "auto", *, map_path: str | Path | None = None,
             salvage: bool = False, px4_topic: str = "auto") -> LogRead:
    """Read one log with the reader of its format.

    Parameters
    ----------
    path : str or Path
    fmt : str
        ``auto`` or the name of a registered format
        (:func:`replay.ingest.registry.format_names`).
    map_path : str or Path, optional
        ``rimu.ingest-map/1`` TOML (needed for CSV and R data; optional for .mat), for the
        formats that take one.
    salvage : bool
        Keep the samples before a damage instead of failing.
    px4_topic : str
        For ULog files: ``auto``, ``sensor_gyro`` or ``vehicle_imu``
        (:func:`replay.ingest.px4.read_px4`).
    """
    if fmt != "auto":
        get_format(fmt)                                 # an unknown name is refused first
    if fmt == "auto":
        fmt = detect_format(path)
    if not Path(path).exists():
        from fdi.errors import FileFormatError
        raise FileFormatError(str(path), "cannot read (no such file)")
    from replay.ingest.plausible import mark_implausible

    entry = get_format(fmt)
    if map_path is not None and "map_path" not in entry.options:
        takes = [f.name for f in log_formats() if "map_path" in f.options]
        raise ConfigError(f"--map is for {_and(takes)} logs, not {fmt}")
    # no format here has a checksum over its samples: implausible values are marked
    return mark_implausible(entry.read(path, salvage=salvage, map_path=map_path,
                                       px4_topic=px4_topic))


def merge_reads(reads: list[LogRead]) -> LogRead:
    """Several logs recorded together (one IMU per file) as one: IMUs renumbered in order.

    The damage of the first damaged file is kept (each file was already cut at its own).
    """
    from dataclasses import replace

    if len(reads) == 1:
        return reads[0]
    streams = []
    for r in reads:
        for s in r.streams:
            streams.append(replace(s, name=f"imu{len(streams) + 1}",
                                   source=f"{Path(r.path).name}:{s.source}"))
    fmts = sorted({r.format for r in reads})
    damage = next((r.damage for r in reads if r.damage is not None), None)
    return LogRead(" + ".join(r.path for r in reads), "+".join(fmts), tuple(streams), damage,
                   {"files": [{"path": r.path, "format": r.format, **r.meta} for r in reads]},
                   events=tuple(sorted((e for r in reads for e in r.events),
                                       key=lambda e: e.t_s)))
