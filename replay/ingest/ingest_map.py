"""The ``rimu.ingest-map/1`` TOML map: which columns of a table are which IMU, in what unit.

Example (a CSV with a time column in ms and two IMUs)::

    schema = "rimu.ingest-map/1"
    format = "csv"                          # optional: csv, mat or rda
    object = "adis_16405_imu1"              # optional: R object / MATLAB variable

    [time]
    column = "time_ms"                      # or: rate_hz = 100.0 (and t0_s = 0.0)
    unit = "ms"                             # s, ms, us, ns

    [[imus]]
    name = "imu1"                           # optional (default imu1, imu2, ...)
    gyro = ["imu1_gyr_x_rps", "imu1_gyr_y_rps", "imu1_gyr_z_rps"]
    gyro_unit = "rad/s"                     # rad/s, deg/s, deg/h
    accel = ["imu1_acc_x_mps2", "imu1_acc_y_mps2", "imu1_acc_z_mps2"]   # optional
    accel_unit = "m/s^2"                    # m/s^2, g, mg
    temperature = "imu1_temp_c"             # optional, degC
    time = "t1"                             # optional: this IMU's own time column

A column is named as the table names it: a CSV header cell, an R column name, a MATLAB
variable or struct field (``imu1_raw.wb``); ``name[j]`` is column j (0-based) of a
two-dimensional one, and ``gyro`` / ``accel`` may also name one (N, 3) array.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from fdi.fileio import Fields
from fdi.units import INPUT_UNITS, TIME_UNITS

__all__ = ["INGEST_MAP_SCHEMA", "ImuColumns", "IngestMap", "load_ingest_map"]

INGEST_MAP_SCHEMA = "rimu.ingest-map/1"
GYRO_UNITS = ("rad/s", "deg/s", "deg/h")
ACCEL_UNITS = ("m/s^2", "g", "mg")


@dataclass(frozen=True)
class ImuColumns:
    """Where one IMU's channels are in the table.

    Attributes
    ----------
    name : str
    gyro : tuple of str
        Three column names, or one naming an (N, 3) array.
    gyro_factor : float
        SI per unit of the gyro columns.
    accel : tuple of str
        Empty when not mapped.
    accel_factor : float
    temperature : str or None
    time : str or None
        This IMU's own time column (None: the map's ``[time]``).
    """

    name: str
    gyro: tuple[str, ...]
    gyro_factor: float
    accel: tuple[str, ...] = ()
    accel_factor: float = 1.0
    temperature: str | None = None
    time: str | None = None


@dataclass(frozen=True)
class IngestMap:
    """A loaded ``rimu.ingest-map/1`` file.

    Attributes
    ----------
    path : str
    format : str or None
    object : str or None
    time_column : str or None
    time_factor : float
        Seconds per unit of the time columns.
    rate_hz : float or None
        Used when there is no time column: t = t0_s + k / rate_hz.
    t0_s : float
    imus : tuple of ImuColumns
    """

    path: str
    format: str | None
    object: str | None
    time_column: str | None
    time_factor: float
    rate_hz: float | None
    t0_s: float
    imus: tuple[ImuColumns, ...]


def _columns(f: Fields, key: str, required: bool) -> tuple[str, ...]:
    if key not in f and not required:
        f.accept(key)
        return ()
    v = f.get(key)
    if isinstance(v, str) and v.strip():
        return (v,)
    if isinstance(v, list) and len(v) == 3 and all(isinstance(x, str) and x for x in v):
        return tuple(v)
    raise f.error(key, f"expected three column names or one (N, 3) array name, got {v!r}")


def load_ingest_map(path: str | Path) -> IngestMap:
    """Read and check a ``rimu.ingest-map/1`` file.

    Raises
    ------
    FileFormatError
        Naming the file, the TOML line and the field.
    """
    f = Fields.from_toml(path, INGEST_MAP_SCHEMA)
    fmt = f.choice("format", ("csv", "mat", "rda"), None)
    obj = f.string("object", None)
    tf = f.mapping("time", {})
    col = tf.string("column", None)
    unit = tf.choice("unit", tuple(TIME_UNITS), "s")
    rate = tf.number("rate_hz", None, positive=True)
    t0 = tf.number("t0_s", 0.0)
    tf.finish()
    imus = []
    for k, t in enumerate(f.tables("imus"), start=1):
        name = t.string("name", f"imu{k}")
        gyro = _columns(t, "gyro", True)
        gu = t.choice("gyro_unit", GYRO_UNITS)
        acc = _columns(t, "accel", False)
        au = t.choice("accel_unit", ACCEL_UNITS, "m/s^2")
        temp = t.string("temperature", None)
        t.choice("temperature_unit", ("degC",), "degC")
        own = t.string("time", None)
        t.finish()
        if own is None and col is None and rate is None:
            raise tf.error(None, "give [time] column = ... or rate_hz = ..., or a time "
                                 f"column for every IMU ({name} has none)")
        imus.append(ImuColumns(name, gyro, INPUT_UNITS[gu], acc, INPUT_UNITS[au], temp, own))
    names = [i.name for i in imus]
    if len(set(names)) != len(names):
        raise f.error("imus", f"IMU names repeat: {names}")
    f.finish()
    return IngestMap(str(path), fmt, obj, col, TIME_UNITS[unit], rate, t0, tuple(imus))
