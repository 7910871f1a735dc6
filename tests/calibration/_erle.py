"""Test helper: an erle PXF ArduCopter log (two IMUs) as a Flight, read with pymavlink.

Used only for the findings on the real flights when ``rimu ingest`` is not available;
the data stay in ``../shared/data`` (no licence stated: never copied into the repository).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from replay.flight_data import AuxChannels, Flight

SHARED = Path(os.environ.get("RIMU_SHARED_DATA",
                             Path(__file__).resolve().parents[2] / ".." / "shared" / "data"))
"""``../shared/data`` beside the repository (``RIMU_SHARED_DATA`` overrides it)."""
DATA = SHARED / "erle_pxf_dual_imu"
FLIGHTS = {"83": "pxf_copter_31-3-2015_83.BIN", "41": "pxf_copter_22-12-2014_41.BIN"}


def read_erle(name: str) -> Flight:
    """IMU and IMU2 of one erle log on their common TimeMS stamps (rad/s, m/s²)."""
    from pymavlink import DFReader

    path = DATA / FLIGHTS[name]
    r = DFReader.DFReader_binary(str(path))
    rows: dict[str, dict[int, list[float]]] = {"IMU": {}, "IMU2": {}}
    while True:
        m = r.recv_match(type=["IMU", "IMU2"])
        if m is None:
            break
        rows[m.get_type()][int(m.TimeMS)] = [m.GyrX, m.GyrY, m.GyrZ, m.AccX, m.AccY, m.AccZ]
    common = sorted(set(rows["IMU"]) & set(rows["IMU2"]))
    a = np.array([rows["IMU"][k] + rows["IMU2"][k] for k in common], float)
    t = np.array(common, float) / 1e3
    gyro = np.hstack([a[:, 0:3], a[:, 6:9]])
    acc = np.hstack([a[:, 3:6], a[:, 9:12]])
    names = tuple(f"imu{j}.{x}" for j in (1, 2) for x in "xyz")
    groups = tuple(f"imu{j}" for j in (1, 2) for _ in "xyz")
    aux = AuxChannels(("accel",) * 6, names, groups, acc, np.ones(acc.shape, bool))
    return Flight(t=t, raw=gyro, valid=np.ones(gyro.shape, bool), sample_rate_hz=50.0,
                  sensor_names=names, raw_unit="rad/s", source=str(path), kind="gyro",
                  imu=groups, aux=aux)
