"""Physically implausible samples in logs without checksums, marked at ingest.

DataFlash (``.BIN``), ULog, MATLAB, CSV and R data files carry no checksum over their
samples: a flipped bit in a value is read as a value. What physics rules out is flagged:

- **beyond the range**: a magnitude above twice :data:`GYRO_RANGE_RADPS` (2000 °/s, the
  widest common MEMS gyro range) or twice :data:`ACCEL_RANGE_MPS2` (32 g): no sensor of
  that range outputs it (a saturated sensor clips at its range);
- **a one-sample spike**: a jump larger than the full range to one sample and back, while
  the samples either side agree within a quarter of the range: an angular rate (specific
  force) cannot leave and regain its value by more than the sensor's full range within one
  sample period, where a flipped exponent bit does exactly that.

Rates beyond any gyro's range (:data:`replay.ingest.align.MAX_RATE_DPS`, 100,000 °/s:
a wrong unit, or 1e38 from a flipped top exponent bit) are left to the time base, which
refuses them (drops and counts them with ``--salvage``).

A flagged axis value is set to NaN (the monitor then treats that sensor's sample as
missing, never as a measurement), counted per IMU and quantity, and reported with the
first times. A flipped low bit (a mantissa bit: a few percent of the value) stays
physically plausible and cannot be told from a measurement without a checksum.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from fdi.units import DPS
from replay.ingest.stream import ImuStream, LogRead

__all__ = ["ACCEL_RANGE_MPS2", "GYRO_RANGE_RADPS", "implausible", "mark_implausible"]

GYRO_RANGE_RADPS = 2000.0 * DPS
"""Full range of the widest common MEMS gyro (2000 °/s), rad/s."""
ACCEL_RANGE_MPS2 = 32.0 * 9.80665
"""Full range of the widest common MEMS accelerometer (32 g), m/s²."""
_SHOWN = 5
"""Times listed per IMU and quantity in the report."""


def implausible(x: np.ndarray, full_range: float) -> np.ndarray:
    """Where the samples of ``x`` are physically implausible (module docstring).

    Parameters
    ----------
    x : ndarray, shape (N, 3)
        One quantity of one IMU, in time order (SI units).
    full_range : float
        The sensor's full range (same unit).

    Returns
    -------
    ndarray of bool, shape (N, 3)
    """
    x = np.asarray(x, float)
    with np.errstate(invalid="ignore", over="ignore"):
        bad = np.isfinite(x) & (np.abs(x) > 2.0 * full_range)
        if x.shape[0] >= 3:
            a, m, b = x[:-2], x[1:-1], x[2:]
            spike = ((np.abs(m - a) > full_range) & (np.abs(m - b) > full_range)
                     & (np.abs(b - a) < 0.25 * full_range))
            bad[1:-1] |= spike
    return bad


def mark_implausible(read: LogRead) -> LogRead:
    """``read`` with its implausible gyro and accelerometer values set to NaN; the counts
    and first times go to ``read.meta["implausible"]`` and one warning per IMU to
    ``read.meta["warnings"]``."""
    streams: list[ImuStream] = []
    found: dict[str, Any] = {}
    warnings: list[str] = []
    for s in read.streams:
        ch: dict[str, Any] = {}
        kw: dict[str, np.ndarray] = {}
        for name, arr, rng in (("gyro", s.gyro, GYRO_RANGE_RADPS),
                               ("accel", s.accel, ACCEL_RANGE_MPS2)):
            if arr is None or arr.shape[0] == 0:
                continue
            bad = implausible(arr, rng)
            if name == "gyro":
                # rates beyond any gyro's range are the time base's check (refused, or
                # dropped with --salvage: replay.ingest.align.MAX_RATE_DPS), not a mark
                from replay.ingest.align import MAX_RATE_DPS

                with np.errstate(invalid="ignore"):
                    bad &= ~np.any(np.abs(arr) > MAX_RATE_DPS * DPS, axis=1)[:, None]
            if bad.any():
                rows = np.flatnonzero(bad.any(axis=1))
                kw[name] = np.where(bad, np.nan, arr)
                ch[name] = {"samples": int(rows.size), "values": int(bad.sum()),
                            "first_t_s": [float(s.t[k]) for k in rows[:_SHOWN]]}
        if ch:
            found[s.name] = ch
            parts = ", ".join(f"{v['samples']} {k} sample(s)" for k, v in ch.items())
            first = min(v["first_t_s"][0] for v in ch.values())
            warnings.append(f"{s.name} ({s.source}): {parts} physically implausible (beyond "
                            f"twice the full range, or a one-sample spike larger than it; "
                            f"the format has no checksum) set to NaN, first at t={first:.3f} s")
            s = replace(s, **kw)
        streams.append(s)
    if not found:
        return read
    meta = dict(read.meta)
    meta["implausible"] = found
    meta["warnings"] = [*meta.get("warnings", []), *warnings]
    return replace(read, streams=tuple(streams), meta=meta)
