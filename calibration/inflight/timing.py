"""Apply the time offsets of an in-flight calibration to a recorded flight.

The in-flight fit (:mod:`calibration.inflight.fit`) models IMU ``j`` as
``y_j(t) = A_j · y_ref(t + τ_j) + c_j``: IMU ``j`` sees the motion ``-τ_j`` late when
``τ_j < 0``. The monitor compares the IMUs sample by sample, so an uncorrected lag leaves
``τ_j · dω/dt`` in the parity residual (alarms in manoeuvres). This module moves each IMU
onto the reference's timing by sampling its record at ``t - τ_j`` (linear interpolation
between its own samples), before the monitor sees it.

Times in s, rates in the flight's raw unit; arrays shaped (N, n) as in :class:`Flight`.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from replay.flight_data import Flight

__all__ = ["apply_time_offsets", "time_offsets_s"]


def time_offsets_s(cal: Calibration) -> dict[str, float]:
    """The fitted time offset τ (s) of every IMU group an in-flight calibration records
    (empty for a turntable calibration)."""
    imus = cal.extra.get("inflight", {}).get("imus", {})
    return {g: 1e-3 * float(rec["time_offset_ms"]) for g, rec in imus.items()
            if isinstance(rec, dict) and "time_offset_ms" in rec}


def apply_time_offsets(flight: Flight, cal: Calibration) -> tuple[Flight, dict[str, Any]]:
    """``flight`` with each IMU group resampled at ``t - τ`` (its calibration's offset).

    A sample whose shifted time falls outside the group's record, or next to one of its
    invalid samples, is marked invalid (the monitor treats it as missing).

    Returns
    -------
    flight : Flight
        A new flight (the input is not modified); unchanged when there is nothing to do.
    applied : dict
        ``{group: τ in ms}`` for the groups moved.
    """
    offsets = time_offsets_s(cal)
    groups = getattr(flight, "imu", None) or ()
    if not offsets or not groups or flight.t.shape[0] < 2:
        return flight, {}
    t = np.asarray(flight.t, float)
    raw = np.array(flight.raw, dtype=float, copy=True)
    valid = np.array(flight.valid, dtype=bool, copy=True)
    applied: dict[str, float] = {}
    for g, tau in offsets.items():
        cols = [k for k, h in enumerate(groups) if h == g]
        if not cols or tau == 0.0:
            continue
        ts = t - tau
        inside = (ts >= t[0]) & (ts <= t[-1])
        right = np.clip(np.searchsorted(t, ts), 1, t.shape[0] - 1)
        for k in cols:
            ok = flight.valid[:, k] & np.isfinite(flight.raw[:, k])
            both = ok[right - 1] & ok[right] & inside
            if ok.sum() >= 2:
                raw[:, k] = np.interp(ts, t[ok], flight.raw[ok, k])
            valid[:, k] = both
            raw[~both, k] = np.nan
        applied[g] = 1e3 * tau
    if not applied:
        return flight, {}
    return replace(flight, raw=raw, valid=valid), applied
