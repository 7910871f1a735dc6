"""The :class:`Flight` record: samples of one sensor set in flight, with channels beside it.

A flight holds the *monitored* sensors (``raw``, one column per sensing axis, all of one
``kind``) and, optionally,

- ``imu``: the IMU group of each monitored sensor (``"imu1"``, ``"imu2"``, ...) when the set
  is made of several three-axis IMUs (sensor names like ``imu1.x``);
- ``aux``: channels kept beside the monitored sensors on the same time base and not
  monitored: accelerometers (m/s²) and temperatures (°C) of each IMU, or gyros when the
  monitored kind is ``accel`` (:class:`AuxChannels`).

Simulation lives in :mod:`replay.flight_sim`, the folder format in :mod:`replay.flight_io`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from fdi.errors import ConfigError
from replay.faults import Fault
from replay.log_events import LogEvent

__all__ = ["AUX_KINDS", "AUX_UNITS", "FLIGHT_TRUTH_SCHEMA", "AuxChannels", "Flight",
           "concat_flights", "flight_rows"]

FLIGHT_TRUTH_SCHEMA = "rimu.flight-truth/1"
"""Schema of a flight's truth record (simulated or fault-injected flights)."""

AUX_KINDS = ("accel", "gyro", "temperature")
"""Kinds of channel a flight may keep beside its monitored sensors."""

AUX_UNITS = {"accel": "m/s^2", "gyro": "rad/s", "temperature": "degC"}
"""The unit each auxiliary kind is stored in (SI; temperatures in °C, as logged)."""


@dataclass(frozen=True, eq=False)
class AuxChannels:
    """Channels kept beside a flight's monitored sensors, on the flight's time base.

    Attributes
    ----------
    kinds : tuple of str
        Per channel: ``"accel"``, ``"gyro"`` or ``"temperature"`` (:data:`AUX_KINDS`).
    names : tuple of str
        Per channel, unique within its kind: ``"imu1.x"`` for an axis, ``"imu1"`` for a
        temperature.
    imu : tuple of str
        Per channel, the IMU it belongs to (``""`` when none).
    values : ndarray, shape (N, m)
        In :data:`AUX_UNITS` of each channel's kind; NaN where ``valid`` is False.
    valid : ndarray of bool, shape (N, m)
        False where the channel has no sample.
    """

    kinds: tuple[str, ...]
    names: tuple[str, ...]
    imu: tuple[str, ...]
    values: np.ndarray
    valid: np.ndarray

    def __post_init__(self) -> None:
        m = len(self.kinds)
        if len(self.names) != m or len(self.imu) != m:
            raise ConfigError(f"aux channels: {m} kinds, {len(self.names)} names, "
                              f"{len(self.imu)} imu groups (must be equal)")
        bad = [k for k in self.kinds if k not in AUX_KINDS]
        if bad:
            raise ConfigError(f"aux channel kind {bad[0]!r} is not one of {AUX_KINDS}")
        if self.values.ndim != 2 or self.values.shape[1] != m \
                or self.valid.shape != self.values.shape:
            raise ConfigError(f"aux channels: values {self.values.shape} and valid "
                              f"{self.valid.shape} must both be (N, {m})")
        keys = list(zip(self.kinds, self.names, strict=True))
        if len(set(keys)) != m:
            raise ConfigError("aux channels: a (kind, name) pair appears twice")

    @property
    def m(self) -> int:
        """Number of channels."""
        return len(self.kinds)

    @property
    def columns(self) -> tuple[str, ...]:
        """Column names in a flight folder: ``"<kind>:<name>"``."""
        return tuple(f"{k}:{n}" for k, n in zip(self.kinds, self.names, strict=True))

    def select(self, kind: str) -> AuxChannels:
        """The channels of one kind (possibly none)."""
        j = [i for i, k in enumerate(self.kinds) if k == kind]
        return AuxChannels(tuple(self.kinds[i] for i in j), tuple(self.names[i] for i in j),
                           tuple(self.imu[i] for i in j), self.values[:, j], self.valid[:, j])

    def slice(self, rows: slice | np.ndarray) -> AuxChannels:
        """The same channels on a subset of the samples."""
        return replace(self, values=self.values[rows], valid=self.valid[rows])


@dataclass(frozen=True, eq=False)
class Flight:
    """Samples of one sensor set in flight.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Sample times (s).
    raw : ndarray, shape (N, n)
        Raw outputs (sensor units); NaN where ``valid`` is False.
    valid : ndarray of bool, shape (N, n)
        False where a sensor sent no sample.
    sample_rate_hz : float
    sensor_names : tuple of str
    raw_unit : str
    omega_true : ndarray, shape (N, 3) or None
        True body rates (rad/s), when known.
    faults : tuple of Fault
        Injected faults, when known.
    truth : dict
        The JSON-able truth record (``rimu.flight-truth/1`` without the rates), or empty.
    source : str
        Where the flight came from (path or ``"<simulated>"``).
    kind : str
        ``"gyro"`` or ``"accel"``.
    imu : tuple of str
        The IMU group of each monitored sensor (``("imu1", "imu1", "imu1", "imu2", ...)``),
        or ``()`` when the set is not grouped into IMUs.
    aux : AuxChannels or None
        Accelerometers, temperatures (and gyros of an accelerometer flight) kept beside the
        monitored sensors on the same time base.
    events : tuple of LogEvent
        What the log declared (crash checks, estimator flags, messages) on the flight's
        time base (:mod:`replay.log_events`); those with ``envelope`` set are declared out
        of the operating envelope.
    """

    t: np.ndarray
    raw: np.ndarray
    valid: np.ndarray
    sample_rate_hz: float
    sensor_names: tuple[str, ...]
    raw_unit: str = "raw"
    omega_true: np.ndarray | None = None
    faults: tuple[Fault, ...] = ()
    truth: dict[str, Any] = field(default_factory=dict)
    source: str = "<memory>"
    kind: str = "gyro"
    imu: tuple[str, ...] = ()
    aux: AuxChannels | None = None
    events: tuple[LogEvent, ...] = ()

    @property
    def n(self) -> int:
        """Number of sensors."""
        return self.raw.shape[1]

    @property
    def time_base(self) -> Any:
        """Gaps, duplicate time stamps and empty rows (:class:`replay.time_base.TimeBase`)."""
        from replay.time_base import time_base

        return time_base(self.t, self.raw, self.sample_rate_hz)

    @property
    def duration_s(self) -> float:
        """Time span covered (s): N / sample rate."""
        return self.t.shape[0] / self.sample_rate_hz if self.sample_rate_hz > 0 else 0.0

    def imu_groups(self) -> dict[str, list[int]]:
        """Monitored-sensor indices of each IMU group, in order of first appearance."""
        out: dict[str, list[int]] = {}
        for i, g in enumerate(self.imu):
            out.setdefault(g, []).append(i)
        return out

    def imu_triads(self, what: str) -> dict[str, list[int]]:
        """:meth:`imu_groups`, checked to be two or more groups of three gyros (what
        ``what``, e.g. "static calibration", needs).

        Raises
        ------
        ConfigError
            Another kind of sensor, or not two or more triads (manifest 'imu').
        """
        if self.kind != "gyro":
            raise ConfigError(f"{self.source}: {what} needs gyros, the flight monitors "
                              f"{self.kind}")
        g = self.imu_groups()
        if len(g) < 2 or any(len(v) != 3 for v in g.values()):
            raise ConfigError(f"{self.source}: {what} needs two or more IMU groups of three "
                              f"gyros (manifest 'imu')")
        return g


def flight_rows(f: Flight, rows: slice) -> Flight:
    """The flight's samples ``rows`` (views), truth and auxiliary channels with them."""
    return replace(f, t=f.t[rows], raw=f.raw[rows], valid=f.valid[rows],
                   omega_true=None if f.omega_true is None else f.omega_true[rows],
                   aux=None if f.aux is None else f.aux.slice(rows))


def concat_flights(pieces: Sequence[Flight]) -> Flight:
    """Join consecutive flight pieces (same sensors) into one flight."""
    if not pieces:
        raise ConfigError("no flight pieces to join")
    first = pieces[0]
    has_truth = all(p.omega_true is not None for p in pieces)
    aux = None
    if first.aux is not None:
        if any(p.aux is None or p.aux.columns != first.aux.columns for p in pieces):
            raise ConfigError("flight pieces keep different aux channels")
        aux = replace(first.aux, values=np.concatenate([p.aux.values for p in pieces]),
                      valid=np.concatenate([p.aux.valid for p in pieces]))
    return replace(first,
                   t=np.concatenate([p.t for p in pieces]),
                   raw=np.concatenate([p.raw for p in pieces]),
                   valid=np.concatenate([p.valid for p in pieces]),
                   omega_true=(np.concatenate([p.omega_true for p in pieces])
                               if has_truth else None),
                   aux=aux, events=tuple(dict.fromkeys(e for p in pieces for e in p.events)))
