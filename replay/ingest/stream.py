"""The record every reader returns: one stream per IMU, and what went wrong in the file.

A reader turns a log into :class:`LogRead`: one :class:`ImuStream` per IMU (sample times in
seconds, gyro in rad/s, accelerometer in m/s², temperature in °C, all in the frame the log
stores them in), the format it read, and :class:`Damage` when the file is truncated or
corrupt. :mod:`replay.ingest.align` puts the streams on one time base.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from fdi.errors import ConfigError, FileFormatError
from replay.log_events import LogEvent

__all__ = ["Damage", "ImuStream", "LogRead"]


@dataclass(frozen=True, eq=False)
class ImuStream:
    """Samples of one IMU as the log holds them.

    Attributes
    ----------
    name : str
        ``"imu1"``, ``"imu2"``, ... (the order of the log's instances).
    t : ndarray, shape (N,)
        Sample times (s), on the log's clock.
    gyro : ndarray, shape (N, 3)
        Angular rate (rad/s).
    accel : ndarray, shape (N, 3) or None
        Specific force (m/s²), when logged.
    temperature : ndarray, shape (N,) or None
        Sensor temperature (°C), when logged.
    source : str
        Where in the log the samples come from (``"IMU2"``, ``"sensor_gyro[1]"``, a column).
    device_id : int or None
        Hardware id the log gives the sensor (PX4 ``device_id``), when known.
    error_count : ndarray, shape (N,) or None
        The driver's error counter per sample, when logged.
    notes : tuple of str
        What the reader decided about this stream (dropped channels, assumed units).
    """

    name: str
    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray | None = None
    temperature: np.ndarray | None = None
    source: str = ""
    device_id: int | None = None
    error_count: np.ndarray | None = None
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        n = self.t.shape[0]
        if self.t.ndim != 1 or self.gyro.shape != (n, 3):
            raise ConfigError(f"{self.name}: t {self.t.shape} and gyro {self.gyro.shape} "
                              f"must be (N,) and (N, 3)")
        if self.accel is not None and self.accel.shape != (n, 3):
            raise ConfigError(f"{self.name}: accel {self.accel.shape} must be ({n}, 3)")
        for nm in ("temperature", "error_count"):
            a = getattr(self, nm)
            if a is not None and a.shape != (n,):
                raise ConfigError(f"{self.name}: {nm} {a.shape} must be ({n},)")

    @property
    def size(self) -> int:
        """Number of samples."""
        return int(self.t.shape[0])

    def take(self, rows: slice | np.ndarray) -> ImuStream:
        """The same stream on a subset of its samples."""
        def cut(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[rows]
        return replace(self, t=self.t[rows], gyro=self.gyro[rows], accel=cut(self.accel),
                       temperature=cut(self.temperature),
                       error_count=cut(self.error_count))


@dataclass(frozen=True)
class Damage:
    """Where a log stops being readable.

    Attributes
    ----------
    path : str
    message : str
        What is wrong (``"file ends inside a GPS message (needs 4 more bytes)"``).
    offset : int or None
        Byte offset of the damage, when the format has one.
    line : int or None
        1-based line (text formats).
    samples_before : int
        IMU samples (all IMUs) read before the damage.
    stretches : tuple of dict
        Every damaged stretch when the reader resynchronises after damage (``--salvage``):
        ``start``/``end`` (byte range, end exclusive, or ``line`` for text), ``bytes``,
        ``what``, and what was lost there (``lost``: IMU samples per stream, or lines).
        Empty when the reader keeps only the samples before the first damage.
    samples_after : int
        IMU samples (all IMUs) read after the first damage (resynchronised).
    """

    path: str
    message: str
    offset: int | None = None
    line: int | None = None
    samples_before: int = 0
    stretches: tuple[dict[str, Any], ...] = ()
    samples_after: int = 0

    def error(self) -> FileFormatError:
        """The one-line error for this damage (mentions ``--salvage``)."""
        where = f" at byte offset {self.offset}" if self.offset is not None else ""
        if self.stretches:
            n = len(self.stretches)
            keep = (f"; --salvage keeps the {self.samples_before + self.samples_after} IMU "
                    f"samples outside the {n} damaged stretch{'es' if n > 1 else ''}")
        else:
            keep = (f"; --salvage keeps the {self.samples_before} IMU samples before it"
                    if self.samples_before else "; no IMU sample precedes it")
        return FileFormatError(self.path, f"{self.message}{where}{keep}", line=self.line)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (for the ingest report)."""
        return {"message": self.message, "offset": self.offset, "line": self.line,
                "samples_before": self.samples_before, "samples_after": self.samples_after,
                "stretches": [dict(x) for x in self.stretches]}


@dataclass(frozen=True, eq=False)
class LogRead:
    """What a reader got from one log.

    Attributes
    ----------
    path : str
    format : str
        ``"ardupilot"``, ``"px4"``, ``"mat"``, ``"csv"``, ``"rda"``.
    streams : tuple of ImuStream
    damage : Damage or None
        Set when the file is truncated or corrupt; the streams then hold only the samples
        before the damage (a reader returns this only when asked to salvage).
    meta : dict
        Format-specific facts worth reporting (message counts, vehicle, rates).
    events : tuple of LogEvent
        What the log declares about itself (crash checks, estimator flags, messages), on
        the streams' clock (:mod:`replay.log_events`).
    """

    path: str
    format: str
    streams: tuple[ImuStream, ...]
    damage: Damage | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    events: tuple[LogEvent, ...] = ()
