"""Channel maps: which CAN message and signal is sensor i (``rimu.channel_map/1`` TOML).

A channel map ties a DBC (the shipped ``rimu_imu.dbc`` or any user DBC) to the sensors of a
calibration, in calibration order. Example (three J1939 IMUs sending Angular Rate
Information, PGN 61482, from source addresses 0x80, 0x81, 0x82 become nine sensors; shipped
as ``replay/dbc/j1939_ari_3imu.toml``)::

    schema = "rimu.channel_map/1"
    kind = "gyro"
    dbc = "j1939_ari.dbc"        # relative to this file; --dbc overrides it
    j1939 = true                 # match frames on (PGN, source address); check 'not available'
    time_tolerance_s = 0.004     # frames closer than this belong to one sample

    [[sensors]]
    name = "imu1_pitch"
    message = "ARI"              # DBC message name
    signal = "PitchRate"         # DBC signal name
    unit = "deg/s"               # unit of the decoded value = the calibration's raw unit
    axis_nominal = [0.0, 1.0, 0.0]
    source_address = 0x80        # J1939 only
    # optional per sensor: channel = 0 (bus filter), counter_signal, crc_signal,
    # sample_counter_signal, status_signal (0 = OK)

The decoded physical value (``raw·scale + offset`` of the DBC signal, in ``unit``) is what
the monitor receives as the sensor's raw output, so the calibration must express that sensor's
raw output in the same unit (for a J1939 IMU in °/s: scale factor ≈ 1 (deg/s)/raw).
``axis_nominal`` must agree with the calibration's nominal axis (within 1°): this is the check
that sensor i of the map really is sensor i of the calibration.

CRC signals are CRC-8 SAE J1850 (:mod:`replay.crc`) in the payload's last byte, over all the
bytes before it. Rolling counters increase by one (mod 2^bits) per frame of a message.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fdi.calfile import Calibration
from fdi.errors import ConfigError
from fdi.fileio import Fields
from fdi.units import INPUT_UNITS, RAW_UNITS
from replay.frames import DEFAULT_DBC, imu_message_name

__all__ = [
    "CHANNEL_MAP_SCHEMA",
    "EXAMPLE_J1939_MAP",
    "ChannelMap",
    "SensorChannel",
    "check_against_calibration",
    "default_channel_map",
    "load_channel_map",
]

CHANNEL_MAP_SCHEMA = "rimu.channel_map/1"
EXAMPLE_J1939_MAP = Path(__file__).with_name("dbc") / "j1939_ari_3imu.toml"
"""Shipped example: three J1939 ARI gyros (PGN 61482) from source addresses 0x80..0x82."""


@dataclass(frozen=True)
class SensorChannel:
    """Where sensor i's value is on the bus.

    Attributes
    ----------
    name : str
    message : str
        DBC message name.
    signal : str
        DBC signal carrying the sensor's output.
    unit : str
        Unit of the decoded value.
    axis_nominal : ndarray, shape (3,) or None
    source_address : int or None
        J1939 source address (matched with the PGN of ``message``).
    channel : int or str or None
        Only frames from this bus channel (None: any).
    counter_signal, crc_signal, sample_counter_signal, status_signal : str or None
    """

    name: str
    message: str
    signal: str
    unit: str = "raw"
    axis_nominal: np.ndarray | None = None
    source_address: int | None = None
    channel: int | str | None = None
    counter_signal: str | None = None
    crc_signal: str | None = None
    sample_counter_signal: str | None = None
    status_signal: str | None = None


@dataclass(frozen=True)
class ChannelMap:
    """A channel map (see the module docstring).

    Attributes
    ----------
    sensors : tuple of SensorChannel
        In calibration order.
    kind : str
    dbc : Path or None
        The DBC the map was written for (None: the shipped DBC).
    j1939 : bool
    time_tolerance_s : float or None
        Assembly tolerance; None: 0.4 sample periods.
    max_counter_delta : int
        Largest rolling-counter step accepted (1 = no lost frame tolerated; frames lost
        in between make steps of 2, 3, ...).
    source : str
    """

    sensors: tuple[SensorChannel, ...]
    kind: str = "gyro"
    dbc: Path | None = None
    j1939: bool = False
    time_tolerance_s: float | None = None
    max_counter_delta: int = 3
    source: str = "<default>"

    @property
    def n(self) -> int:
        """Number of sensors."""
        return len(self.sensors)

    @property
    def uses_sample_counter(self) -> bool:
        """True when every sensor carries a sample counter (assembly by counter)."""
        return all(s.sample_counter_signal for s in self.sensors)


def default_channel_map(n: int, kind: str = "gyro", *,
                        axes: np.ndarray | None = None,
                        names: tuple[str, ...] | None = None) -> ChannelMap:
    """The map of the shipped DBC: sensor i is ``RIMU_<KIND>_ii``, signal RAW.

    Counter, CRC, sample counter and status are all checked.
    """
    sensors = []
    for i in range(1, n + 1):
        sensors.append(SensorChannel(
            name=names[i - 1] if names else f"{kind}{i}",
            message=imu_message_name(kind, i), signal="RAW", unit="raw",
            axis_nominal=None if axes is None else np.asarray(axes[i - 1], float),
            counter_signal="COUNTER", crc_signal="CRC", sample_counter_signal="SAMPLE",
            status_signal="STATUS"))
    return ChannelMap(tuple(sensors), kind=kind, dbc=DEFAULT_DBC, max_counter_delta=3,
                      source="<shipped rimu_imu.dbc>")


def load_channel_map(path: str | Path) -> ChannelMap:
    """Read and validate a ``rimu.channel_map/1`` TOML file.

    Raises
    ------
    FileFormatError
        Missing file, bad TOML, wrong schema, missing, malformed or unknown field (named,
        with its line).
    """
    p = Path(path)
    r = Fields.from_toml(p, CHANNEL_MAP_SCHEMA)
    kind = r.choice("kind", ("gyro", "accel"), "gyro")
    j1939 = r.boolean("j1939", False)
    dbc = r.string("dbc", None)
    tol = r.number("time_tolerance_s", None, positive=True)
    cmap = ChannelMap(
        tuple(_sensor_channel(e, f"{kind}{k}", j1939)
              for k, e in enumerate(r.tables("sensors"), start=1)), kind=kind,
        dbc=None if dbc is None else (p.parent / dbc), j1939=j1939,
        time_tolerance_s=tol, max_counter_delta=r.integer("max_counter_delta", 3, lo=1),
        source=str(p))
    r.finish()
    return cmap


def _sensor_channel(e: Fields, default_name: str, j1939: bool) -> SensorChannel:
    """One ``[[sensors]]`` table."""
    unit = e.string("unit", "raw")
    if unit not in RAW_UNITS and unit not in INPUT_UNITS:
        known = ", ".join(sorted(RAW_UNITS | set(INPUT_UNITS)))
        raise e.error("unit", f"unknown unit {unit!r}; expected one of {known}")
    axis = e.array("axis_nominal", (3,), None)
    if axis is not None:
        if np.linalg.norm(axis) == 0:
            raise e.error("axis_nominal", "expected 3 finite numbers, not all zero")
        axis = axis / np.linalg.norm(axis)
    sa = e.integer("source_address", None, lo=0, hi=0xFF)
    if j1939 and sa is None:
        raise e.error("source_address", "a J1939 map needs each sensor's source address")
    ch = e.get("channel", None)
    if ch is not None and (isinstance(ch, bool) or not isinstance(ch, int | str)):
        raise e.error("channel", "expected a channel number or name")
    sc = SensorChannel(
        name=e.string("name", default_name), message=e.string("message"),
        signal=e.string("signal"), unit=unit, axis_nominal=axis, source_address=sa,
        channel=ch, counter_signal=e.string("counter_signal", None),
        crc_signal=e.string("crc_signal", None),
        sample_counter_signal=e.string("sample_counter_signal", None),
        status_signal=e.string("status_signal", None))
    e.finish()
    return sc


def check_against_calibration(cmap: ChannelMap, cal: Calibration) -> None:
    """Check that the map's sensors are the calibration's (count, nominal axes within 1°).

    Raises
    ------
    ConfigError
        Naming the first sensor that does not fit.
    """
    s = cal.kind(cmap.kind)
    if s.n != cmap.n:
        raise ConfigError(f"channel map {cmap.source} has {cmap.n} {cmap.kind} sensors, the "
                          f"calibration {s.n}")
    for i, (ch, sc) in enumerate(zip(cmap.sensors, s.sensors, strict=True)):
        if ch.axis_nominal is None:
            continue
        c = float(np.clip(np.dot(ch.axis_nominal, sc.axis_nominal), -1.0, 1.0))
        ang = math.degrees(math.acos(c))
        if ang > 1.0:
            raise ConfigError(f"channel map {cmap.source}: sensor {i + 1} ({ch.name}) has "
                              f"nominal axis {ch.axis_nominal.round(4).tolist()}, the "
                              f"calibration's sensor {i + 1} ({sc.name}) "
                              f"{sc.axis_nominal.round(4).tolist()} ({ang:.1f}° apart)")
