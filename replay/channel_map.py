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

    [[auxiliary]]                # optional: inputs of the calibration's effect terms
    quantity = "specific_force"  # or "temperature"
    message = "ACC"
    signals = ["LongitudinalAcceleration", "LateralAcceleration", "VerticalAcceleration"]
    axes = [[1, 0, 0], [0, 1, 0], [0, 0, -1]]   # body axis of each signal (default x, y, z)
    unit = "m/s^2"               # or "g"; temperature: "degC" or "K"
    source_address = 0x80
    sensors = ["imu1_pitch", "imu1_roll", "imu1_yaw"]   # or "all" (the default)
    # optional: name, timeout_s, channel, counter_signal, crc_signal, status_signal

The decoded physical value (``raw·scale + offset`` of the DBC signal, in ``unit``) is what
the monitor receives as the sensor's raw output, so the calibration must express that sensor's
raw output in the same unit (for a J1939 IMU in °/s: scale factor ≈ 1 (deg/s)/raw).
``axis_nominal`` must agree with the calibration's nominal axis (within 1°): this is the check
that sensor i of the map really is sensor i of the calibration.

**Auxiliary channels** (``[[auxiliary]]``) are not monitored: they carry the run-time inputs
of the calibration's effect terms (:mod:`fdi.effects`), a temperature (°C or K) or the
specific force (m/s² or g, in the body frame). They never take part in the sample assembly
or its loss accounting; their latest value not later than each sample is held onto it
(:class:`replay.aux_hold.AuxHold`), NaN before the first and once older than ``timeout_s``
(default 5 s for a temperature, 0.1 s for a specific force). A specific-force entry gives
one signal with ``axis_nominal`` (one accelerometer axis) or up to three ``signals`` with
their ``axes`` (default x, y, z); the specific force of a sensor is the least-squares
solution over the axes that apply to it, which must span three dimensions. ``sensors``
names the monitored sensors an entry applies to; an entry naming a sensor explicitly
overrides one for ``"all"``; a sensor has at most one temperature. Older rimu versions
refuse ``[[auxiliary]]`` as an unknown key (never misread it), so the schema stays ``/1``.

CRC signals are CRC-8 SAE J1850 (:mod:`replay.crc`) in the payload's last byte, over all the
bytes before it. Rolling counters increase by one (mod 2^bits) per frame of a message.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from fdi.calfile import Calibration
from fdi.errors import ConfigError
from fdi.fileio import Fields
from fdi.units import G0, INPUT_UNITS, RAW_UNITS
from replay.frames import DEFAULT_DBC, imu_message_name

__all__ = [
    "AUX_QUANTITIES",
    "AUX_TIMEOUT_S",
    "AUX_UNITS",
    "CHANNEL_MAP_SCHEMA",
    "EXAMPLE_J1939_AUX_MAP",
    "EXAMPLE_J1939_MAP",
    "AuxChannel",
    "ChannelMap",
    "SensorChannel",
    "aux_assignment",
    "channel_map_toml",
    "check_against_calibration",
    "default_channel_map",
    "load_channel_map",
    "write_channel_map",
]

CHANNEL_MAP_SCHEMA = "rimu.channel_map/1"
EXAMPLE_J1939_MAP = Path(__file__).with_name("dbc") / "j1939_ari_3imu.toml"
"""Shipped example: three J1939 ARI gyros (PGN 61482) from source addresses 0x80..0x82."""
EXAMPLE_J1939_AUX_MAP = Path(__file__).with_name("dbc") / "j1939_ari_acc_3imu.toml"
"""Shipped example: the same nine gyros with each IMU's accelerations (ACC, PGN 61485) and
temperature (a proprietary-B message) as auxiliary channels."""

AUX_QUANTITIES = ("temperature", "specific_force")
"""Quantities an auxiliary channel can carry."""
AUX_UNITS: dict[str, dict[str, tuple[float, float]]] = {
    "temperature": {"degC": (1.0, 0.0), "K": (1.0, -273.15)},
    "specific_force": {"m/s^2": (1.0, 0.0), "g": (G0, 0.0)},
}
"""Units of each quantity: (factor, offset) to °C or m/s² (value·factor + offset)."""
AUX_TIMEOUT_S = {"temperature": 5.0, "specific_force": 0.1}
"""Default ``timeout_s``: a held value older than this is stale (NaN)."""


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


@dataclass(frozen=True, eq=False)
class AuxChannel:
    """An auxiliary channel: a run-time input of the effect terms, not monitored.

    Attributes
    ----------
    name : str
    quantity : str
        ``"temperature"`` or ``"specific_force"`` (:data:`AUX_QUANTITIES`).
    message : str
        DBC message name.
    signals : tuple of str
        One signal (a temperature, one accelerometer axis) or up to three (axes).
    unit : str
        Of the decoded values (:data:`AUX_UNITS`).
    axes : ndarray, shape (len(signals), 3) or None
        Specific force: the unit body-frame axis each signal measures.
    sensors : tuple of str or None
        Names of the monitored sensors it applies to (None: all).
    timeout_s : float
        A held value older than this is stale (NaN); default by quantity
        (:data:`AUX_TIMEOUT_S`).
    source_address : int or None
    channel : int or str or None
    counter_signal, crc_signal, status_signal : str or None
    """

    name: str
    quantity: str
    message: str
    signals: tuple[str, ...]
    unit: str
    axes: np.ndarray | None = None
    sensors: tuple[str, ...] | None = None
    timeout_s: float | None = None
    source_address: int | None = None
    channel: int | str | None = None
    counter_signal: str | None = None
    crc_signal: str | None = None
    status_signal: str | None = None

    def __post_init__(self) -> None:
        if self.quantity not in AUX_UNITS:
            raise ConfigError(f"auxiliary channel {self.name}: quantity {self.quantity!r} is "
                              f"not one of {AUX_QUANTITIES}")
        if self.unit not in AUX_UNITS[self.quantity]:
            raise ConfigError(f"auxiliary channel {self.name}: unit {self.unit!r} is not one "
                              f"of {tuple(AUX_UNITS[self.quantity])}")
        if self.quantity == "specific_force" and (
                self.axes is None or np.shape(self.axes) != (len(self.signals), 3)):
            raise ConfigError(f"auxiliary channel {self.name}: a specific force needs one "
                              "body axis per signal")
        if self.timeout_s is None:
            object.__setattr__(self, "timeout_s", AUX_TIMEOUT_S[self.quantity])

    @property
    def to_si(self) -> tuple[float, float]:
        """(factor, offset): decoded value · factor + offset is °C or m/s²."""
        return AUX_UNITS[self.quantity][self.unit]


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
        Assembly tolerance; None: :data:`replay.assemble.TIME_TOLERANCE_PERIODS` (0.4)
        sample periods.
    max_counter_delta : int
        Largest rolling-counter step accepted (1 = no lost frame tolerated; frames lost
        in between make steps of 2, 3, ...).
    source : str
    auxiliary : tuple of AuxChannel
        Run-time inputs of the effect terms (temperature, specific force), not monitored.
    """

    sensors: tuple[SensorChannel, ...]
    kind: str = "gyro"
    dbc: Path | None = None
    j1939: bool = False
    time_tolerance_s: float | None = None
    max_counter_delta: int = 3
    source: str = "<default>"
    auxiliary: tuple[AuxChannel, ...] = ()

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
                        names: tuple[str, ...] | None = None,
                        auxiliary: tuple[AuxChannel, ...] = ()) -> ChannelMap:
    """The map of the shipped DBC: sensor i is ``RIMU_<KIND>_ii``, signal RAW.

    Counter, CRC, sample counter and status are all checked. ``auxiliary``: auxiliary
    channels to add (e.g. those :func:`replay.can_write.write_flight_log` wrote).
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
                      source="<shipped rimu_imu.dbc>", auxiliary=tuple(auxiliary))


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
    names = [sc.name for sc in cmap.sensors]
    aux: list[AuxChannel] = []
    for k, e in enumerate(r.tables("auxiliary", []), start=1):
        a = _aux_channel(e, k, j1939, names)
        if a.name in {b.name for b in aux}:
            raise e.error("name", f"auxiliary name {a.name!r} used twice")
        aux.append(a)
    cmap = replace(cmap, auxiliary=tuple(aux))
    _check_assignment(cmap, r)
    r.finish()
    return cmap


def _aux_signals(e: Fields, q: str) -> tuple[str, ...]:
    """``signal`` or ``signals`` of an ``[[auxiliary]]`` table."""
    if "signals" not in e:
        return (e.string("signal"),)
    if "signal" in e:
        raise e.error("signal", "give 'signal' or 'signals', not both")
    sig = e.get("signals")
    most = 3 if q == "specific_force" else 1
    if (not isinstance(sig, list) or not 1 <= len(sig) <= most
            or not all(isinstance(x, str) and x.strip() for x in sig)):
        raise e.error("signals", f"expected a list of 1 to {most} signal names, got "
                      f"{sig!r}"[:200])
    return tuple(sig)


def _aux_axes(e: Fields, signals: tuple[str, ...]) -> np.ndarray:
    """Unit body axes of a specific-force table's signals, shape (len(signals), 3)."""
    if "signals" in e.doc:
        axes = e.array("axes", (len(signals), 3), None)
        if axes is None:
            if len(signals) != 3:
                raise e.error("axes", f"{len(signals)} signals: give their body axes "
                              "(axes = [[x, y, z], ...], one row per signal)")
            axes = np.eye(3)
        key = "axes"
    else:
        a = e.array("axis_nominal", (3,), None)
        if a is None:
            raise e.error("axis_nominal", "missing; a specific-force signal needs the "
                          "body axis it measures (axis_nominal = [x, y, z])")
        axes, key = a[None, :], "axis_nominal"
    norms = np.linalg.norm(axes, axis=1)
    if np.any(norms == 0):
        raise e.error(key, "expected axes of 3 finite numbers, not all zero")
    return axes / norms[:, None]


def _aux_sensors(e: Fields, sensor_names: list[str]) -> tuple[str, ...] | None:
    """``sensors`` of an ``[[auxiliary]]`` table (None: all)."""
    sensors_v = e.get("sensors", "all")
    if sensors_v == "all":
        return None
    if (not isinstance(sensors_v, list) or not sensors_v
            or not all(isinstance(x, str) for x in sensors_v)):
        raise e.error("sensors", f"expected \"all\" or a non-empty list of sensor names, "
                      f"got {sensors_v!r}"[:200])
    for x in sensors_v:
        if x not in sensor_names:
            raise e.error("sensors", f"unknown sensor {x!r}; the map's sensors are "
                          + ", ".join(sensor_names))
    if len(set(sensors_v)) != len(sensors_v):
        raise e.error("sensors", "a sensor is named twice")
    return tuple(sensors_v)


def _aux_channel(e: Fields, k: int, j1939: bool, sensor_names: list[str]) -> AuxChannel:
    """One ``[[auxiliary]]`` table."""
    q = e.choice("quantity", AUX_QUANTITIES)
    units = AUX_UNITS[q]
    unit = e.string("unit")
    if unit not in units:
        raise e.error("unit", f"unknown unit {unit!r} for a {q}; expected one of "
                      + ", ".join(repr(u) for u in units))
    message = e.string("message")
    signals = _aux_signals(e, q)
    axes = _aux_axes(e, signals) if q == "specific_force" else None
    sensors = _aux_sensors(e, sensor_names)
    sa = e.integer("source_address", None, lo=0, hi=0xFF)
    if j1939 and sa is None:
        raise e.error("source_address", "a J1939 map needs each auxiliary channel's source "
                      "address")
    ch = e.get("channel", None)
    if ch is not None and (isinstance(ch, bool) or not isinstance(ch, int | str)):
        raise e.error("channel", "expected a channel number or name")
    ac = AuxChannel(
        name=e.string("name", f"{q}{k}"), quantity=q, message=message, signals=signals,
        unit=unit, axes=axes, sensors=sensors,
        timeout_s=e.number("timeout_s", AUX_TIMEOUT_S[q], positive=True),
        source_address=sa, channel=ch, counter_signal=e.string("counter_signal", None),
        crc_signal=e.string("crc_signal", None), status_signal=e.string("status_signal", None))
    e.finish()
    return ac


def aux_assignment(cmap: ChannelMap) -> dict[str, list[tuple[int, ...]]]:
    """Which auxiliary entries give each sensor its inputs.

    Returns
    -------
    dict
        ``{"temperature": [...], "specific_force": [...]}``, one tuple of 0-based
        ``cmap.auxiliary`` indices per sensor (empty: no such input). Entries naming the
        sensor explicitly take precedence over entries for all sensors.
    """
    names = [sc.name for sc in cmap.sensors]
    out: dict[str, list[tuple[int, ...]]] = {}
    for q in AUX_QUANTITIES:
        per = []
        for nm in names:
            explicit = tuple(k for k, a in enumerate(cmap.auxiliary)
                             if a.quantity == q and a.sensors is not None and nm in a.sensors)
            every = tuple(k for k, a in enumerate(cmap.auxiliary)
                          if a.quantity == q and a.sensors is None)
            per.append(explicit or every)
        out[q] = per
    return out


def _check_assignment(cmap: ChannelMap, r: Fields) -> None:
    """At most one temperature per sensor; specific-force axes spanning three dimensions."""
    asg = aux_assignment(cmap)
    for i, sc in enumerate(cmap.sensors):
        temps = asg["temperature"][i]
        if len(temps) > 1:
            a, b = (cmap.auxiliary[k].name for k in temps[:2])
            raise r.error("auxiliary", f"sensor {sc.name} has two temperatures ({a} and {b}); "
                          "expected at most one")
        sf = asg["specific_force"][i]
        if sf:
            A = np.vstack([cmap.auxiliary[k].axes for k in sf])
            rank = int(np.linalg.matrix_rank(A, tol=1e-6))
            if rank < 3:
                names = ", ".join(cmap.auxiliary[k].name for k in sf)
                raise r.error("auxiliary", f"the specific-force axes of sensor {sc.name} "
                              f"({names}) span {rank} dimension(s); expected 3")


def _toml_value(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def channel_map_toml(cmap: ChannelMap, *, dbc: str | None = None) -> str:
    """A ``rimu.channel_map/1`` TOML text of ``cmap`` (:func:`load_channel_map` reads it
    back to the same map).

    Parameters
    ----------
    dbc : str, optional
        The ``dbc`` key to write (relative to where the map will be); default: the map's
        DBC as an absolute path (none for the shipped DBC).
    """
    lines = [f'schema = "{CHANNEL_MAP_SCHEMA}"', f'kind = "{cmap.kind}"']
    if dbc is None and cmap.dbc is not None and Path(cmap.dbc) != DEFAULT_DBC:
        dbc = str(Path(cmap.dbc).resolve())
    if dbc is not None:
        lines.append(f"dbc = {_toml_value(dbc)}")
    lines.append(f"j1939 = {_toml_value(cmap.j1939)}")
    if cmap.time_tolerance_s is not None:
        lines.append(f"time_tolerance_s = {cmap.time_tolerance_s!r}")
    lines.append(f"max_counter_delta = {cmap.max_counter_delta}")
    for sc in cmap.sensors:
        lines += ["", "[[sensors]]"]
        for key in ("name", "message", "signal", "unit", "axis_nominal", "source_address",
                    "channel", "counter_signal", "crc_signal", "sample_counter_signal",
                    "status_signal"):
            v = getattr(sc, key)
            if v is not None:
                lines.append(f"{key} = {_toml_value(v)}")
    for a in cmap.auxiliary:
        lines += ["", "[[auxiliary]]", f"name = {_toml_value(a.name)}",
                  f"quantity = {_toml_value(a.quantity)}", f"message = {_toml_value(a.message)}"]
        if a.quantity == "specific_force" and len(a.signals) == 1:
            lines += [f"signal = {_toml_value(a.signals[0])}",
                      f"axis_nominal = {_toml_value(a.axes[0])}"]
        elif a.quantity == "specific_force":
            lines += [f"signals = {_toml_value(list(a.signals))}",
                      f"axes = {_toml_value(a.axes)}"]
        else:
            lines.append(f"signal = {_toml_value(a.signals[0])}")
        lines += [f"unit = {_toml_value(a.unit)}",
                  f"sensors = {_toml_value('all' if a.sensors is None else list(a.sensors))}",
                  f"timeout_s = {a.timeout_s!r}"]
        for key in ("source_address", "channel", "counter_signal", "crc_signal",
                    "status_signal"):
            v = getattr(a, key)
            if v is not None:
                lines.append(f"{key} = {_toml_value(v)}")
    return "\n".join(lines) + "\n"


def write_channel_map(cmap: ChannelMap, path: str | Path, *, dbc: str | None = None) -> None:
    """Write ``cmap`` as a ``rimu.channel_map/1`` TOML file (see :func:`channel_map_toml`)."""
    Path(path).write_text(channel_map_toml(cmap, dbc=dbc), encoding="utf-8")


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
