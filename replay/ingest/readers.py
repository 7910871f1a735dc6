"""Choose the reader of a log: by ``--format`` or, with ``auto``, by content and suffix."""

from __future__ import annotations

from pathlib import Path

from fdi.errors import ConfigError
from replay.ingest.stream import LogRead

__all__ = ["FORMATS", "detect_format", "merge_reads", "read_any"]

FORMATS = ("auto", "ardupilot", "px4", "mat", "csv", "rda")
"""Values of ``rimu ingest --format``."""


def detect_format(path: str | Path) -> str:
    """The format of a log from its first bytes, else its suffix.

    Raises
    ------
    ConfigError
        When neither says.
    """
    from replay.ingest.ardupilot import looks_like_dataflash
    from replay.ingest.px4 import looks_like_ulog

    p = Path(path)
    if looks_like_dataflash(p):
        return "ardupilot"
    if looks_like_ulog(p):
        return "px4"
    suffix = p.suffix.lower()
    by_suffix = {".bin": "ardupilot", ".ulg": "px4", ".mat": "mat", ".csv": "csv",
                 ".rda": "rda", ".rdata": "rda"}
    if suffix in by_suffix:
        return by_suffix[suffix]
    raise ConfigError(f"{p}: cannot tell the log format (suffix {suffix!r}); give --format "
                      f"one of {', '.join(FORMATS[1:])}")


def read_any(path: str | Path, fmt: str = "auto", *, map_path: str | Path | None = None,
             salvage: bool = False, px4_topic: str = "auto") -> LogRead:
    """Read one log with the reader of its format.

    Parameters
    ----------
    path : str or Path
    fmt : str
        One of :data:`FORMATS`.
    map_path : str or Path, optional
        ``rimu.ingest-map/1`` TOML (needed for CSV and R data; optional for .mat).
    salvage : bool
        Keep the samples before a damage instead of failing.
    px4_topic : str
        For ULog files: ``auto``, ``sensor_gyro`` or ``vehicle_imu``
        (:func:`replay.ingest.px4.read_px4`).
    """
    if fmt not in FORMATS:
        raise ConfigError(f"unknown format {fmt!r}; expected one of {', '.join(FORMATS)}")
    if fmt == "auto":
        fmt = detect_format(path)
    if not Path(path).exists():
        from fdi.errors import FileFormatError
        raise FileFormatError(str(path), "cannot read (no such file)")
    from replay.ingest.plausible import mark_implausible

    # no format here has a checksum over its samples: implausible values are marked
    if fmt in ("ardupilot", "px4"):
        if map_path is not None:
            raise ConfigError(f"--map is for mat, csv and rda logs, not {fmt}")
        if fmt == "ardupilot":
            from replay.ingest.ardupilot import read_ardupilot
            return mark_implausible(read_ardupilot(path, salvage=salvage))
        from replay.ingest.px4 import read_px4
        return mark_implausible(read_px4(path, salvage=salvage, topic=px4_topic))
    from replay.ingest.tabular import read_tabular
    return mark_implausible(read_tabular(path, fmt, map_path=map_path, salvage=salvage))


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
