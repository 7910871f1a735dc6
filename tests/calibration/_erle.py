"""Test helper: an erle PXF ArduCopter log (two IMUs) as a Flight, through ``rimu ingest``'s
reader (``replay.ingest``: pymavlink DataFlash reader, one time base).

The data stay in ``../shared/data`` (no licence stated: never copied into the repository).
"""

from __future__ import annotations

import os
from pathlib import Path

from replay.flight_data import Flight

SHARED = Path(os.environ.get("RIMU_SHARED_DATA",
                             Path(__file__).resolve().parents[2] / ".." / "shared" / "data"))
"""``../shared/data`` beside the repository (``RIMU_SHARED_DATA`` overrides it)."""
DATA = SHARED / "erle_pxf_dual_imu"
FLIGHTS = {"83": "pxf_copter_31-3-2015_83.BIN", "41": "pxf_copter_22-12-2014_41.BIN"}


def read_erle(name: str) -> Flight:
    """IMU and IMU2 of one erle log as ``rimu ingest`` reads them.

    Flight 83 ends inside a truncated RATE message; its IMU samples are all before the
    damage and are kept (``--salvage``).
    """
    from replay.ingest import align_streams, read_any

    flight, _ = align_streams(read_any(DATA / FLIGHTS[name], salvage=True))
    return flight
