"""Helpers of the ingest tests: where the shared data is, and small logs written here.

The DataFlash writer packs FMT and IMU messages with ``struct`` (pymavlink has no
DataFlash writer); the ULog writer builds pyulog objects and uses pyulog's own
``write_ulog``.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np
import pytest

_ROOT = Path(__file__).resolve().parents[3]


def shared_data() -> Path:
    """``../shared/data`` beside the repository (``RIMU_SHARED_DATA`` overrides)."""
    env = os.environ.get("RIMU_SHARED_DATA")
    return Path(env) if env else _ROOT / ".." / "shared" / "data"


def data_file(folder: str, name: str) -> Path:
    """A file of the shared data, or skip the test saying what is missing."""
    p = shared_data() / folder / name
    if not p.is_file():
        pytest.skip(f"real data {folder}/{name} not found under {shared_data()} "
                    f"(set RIMU_SHARED_DATA or put ../shared/data beside the repository)")
    return p


# -- DataFlash -------------------------------------------------------------------------
_STRUCT = {"B": "B", "I": "I", "Q": "Q", "f": "f", "h": "h", "H": "H", "i": "i",
           "n": "4s", "N": "16s", "Z": "64s"}


def _fmt_msg(mtype: int, name: str, fmt: str, columns: str) -> bytes:
    length = 3 + struct.calcsize("<" + "".join(_STRUCT[c] for c in fmt))
    return b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", mtype, length, name.encode(),
                                         fmt.encode(), columns.encode())


def _msg(mtype: int, fmt: str, values: list) -> bytes:
    return b"\xa3\x95" + bytes([mtype]) + struct.pack(
        "<" + "".join(_STRUCT[c] for c in fmt), *values)


def write_dataflash(path: Path, t_ms: np.ndarray, gyros: list[np.ndarray],
                    accels: list[np.ndarray], *, instance_field: bool = False,
                    temps: list[np.ndarray] | None = None) -> list[int]:
    """Write a DataFlash log with one IMU message per IMU (``IMU``, ``IMU2``) or, with
    ``instance_field``, one ``IMU`` message with field ``I`` (and ``T`` temperature, time
    in µs). Returns the byte offset at which each sample row (all IMUs) ends."""
    out = bytearray()
    if instance_field:
        fmt, cols = "QB" + "f" * 7, "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,T"
        out += _fmt_msg(0x81, "IMU", fmt, cols)
    else:
        fmt, cols = "Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"
        for k in range(len(gyros)):
            out += _fmt_msg(0x81 + k, "IMU" if k == 0 else f"IMU{k + 1}", fmt, cols)
    out += _fmt_msg(0x90, "PARM", "Nf", "Name,Value")
    out += _msg(0x90, "Nf", [b"INS_GYROFFS_X", 0.0])
    ends = []
    for j, t in enumerate(t_ms):
        for k, (g, a) in enumerate(zip(gyros, accels, strict=True)):
            if instance_field:
                temp = temps[k][j] if temps is not None else 0.0
                out += _msg(0x81, fmt, [int(t * 1000), k, *g[j], *a[j], temp])
            else:
                out += _msg(0x81 + k, fmt, [int(t), *g[j], *a[j]])
        ends.append(len(out))
    path.write_bytes(bytes(out))
    return ends


def small_imu_data(n: int = 200, k: int = 2, seed: int = 0
                   ) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
    """Times (ms, 20 ms steps) and float32-exact gyro (rad/s) / accel (m/s²) per IMU."""
    rng = np.random.default_rng(seed)
    t = 1000 + 20 * np.arange(n)
    gyros = [rng.normal(0, 0.3, (n, 3)).astype(np.float32).astype(float) for _ in range(k)]
    down = np.array([0.0, 0.0, -9.81])
    accels = [(rng.normal(0, 0.2, (n, 3)) + down).astype(np.float32).astype(float)
              for _ in range(k)]
    return t, gyros, accels


# -- ULog ------------------------------------------------------------------------------
_GYRO_FMT = ("sensor_gyro:uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;"
             "float x;float y;float z;float temperature;uint32_t error_count;")
_ACCEL_FMT = ("sensor_accel:uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;"
              "float x;float y;float z;float temperature;uint32_t error_count;")


def write_ulog(path: Path, t_us: list[np.ndarray], gyros: list[np.ndarray],
               accels: list[np.ndarray], temps: list[np.ndarray],
               device_ids: list[int]) -> None:
    """Write a ULog file with ``sensor_gyro`` / ``sensor_accel`` instances 0..k-1 through
    pyulog's own objects and ``ULog.write_ulog``."""
    from pyulog import ULog

    u = ULog(None)
    u._start_timestamp = int(min(t[0] for t in t_us if t.size))   # an instance may be empty
    hdr = ULog._MessageHeader()
    for fmt in (_GYRO_FMT, _ACCEL_FMT):
        mf = ULog.MessageFormat(fmt.encode(), hdr)
        u._message_formats[mf.name] = mf
    msg_id = 0
    for name, values in (("sensor_gyro", gyros), ("sensor_accel", accels)):
        for k, (t, v, temp, dev) in enumerate(zip(t_us, values, temps, device_ids,
                                                  strict=True)):
            add = ULog._MessageAddLogged(struct.pack("<BH", k, msg_id) + name.encode(), hdr,
                                         u._message_formats)
            rec = np.zeros(t.size, add.dtype)
            rec["timestamp"] = t + 50
            rec["timestamp_sample"] = t
            rec["device_id"] = dev
            rec["x"], rec["y"], rec["z"] = v[:, 0], v[:, 1], v[:, 2]
            rec["temperature"] = temp
            add.buffer = bytearray(rec.tobytes())
            u._data_list.append(ULog.Data(add))
            msg_id += 1
    u.write_ulog(str(path))


_VIMU_FMT = ("vehicle_imu:uint64_t timestamp;uint64_t timestamp_sample;"
             "uint32_t accel_device_id;uint32_t gyro_device_id;float[3] delta_angle;"
             "float[3] delta_velocity;uint16_t delta_angle_dt;uint16_t delta_velocity_dt;")


def write_vehicle_imu_ulog(path: Path, t_us: np.ndarray, rates: list[np.ndarray],
                           forces: list[np.ndarray], dt_us: int) -> None:
    """A ULog with only ``vehicle_imu`` instances: delta angle = rate·dt, delta
    velocity = force·dt over ``dt_us`` (pyulog objects, ``write_ulog``)."""
    from pyulog import ULog

    u = ULog(None)
    u._start_timestamp = int(t_us[0])
    hdr = ULog._MessageHeader()
    mf = ULog.MessageFormat(_VIMU_FMT.encode(), hdr)
    u._message_formats[mf.name] = mf
    for k, (w, f) in enumerate(zip(rates, forces, strict=True)):
        add = ULog._MessageAddLogged(struct.pack("<BH", k, k) + b"vehicle_imu", hdr,
                                     u._message_formats)
        rec = np.zeros(t_us.size, add.dtype)
        rec["timestamp"] = t_us + 100
        rec["timestamp_sample"] = t_us
        rec["gyro_device_id"] = 100 + k
        rec["accel_device_id"] = 200 + k
        for j in range(3):
            rec[f"delta_angle[{j}]"] = w[:, j] * dt_us * 1e-6
            rec[f"delta_velocity[{j}]"] = f[:, j] * dt_us * 1e-6
        rec["delta_angle_dt"] = dt_us
        rec["delta_velocity_dt"] = dt_us
        add.buffer = bytearray(rec.tobytes())
        u._data_list.append(ULog.Data(add))
    u.write_ulog(str(path))
