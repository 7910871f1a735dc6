"""Apply the time offsets of an in-flight calibration to a recorded flight.

The in-flight fit (:mod:`calibration.inflight.fit`) models IMU ``j`` as
``y_j(t) = A_j · y_ref(t + τ_j) + c_j``: IMU ``j``'s sample at t matches the reference's at
``t + τ_j``, so IMU ``j`` sees the motion ``|τ_j|`` late when ``τ_j < 0`` (the sign of
every offset rimu prints). An offset belongs to the flight it was fitted on (the lag
between two IMUs' samples depends on the logger's scheduling): the calibration records
that flight's identity (:func:`flight_identity`) and :func:`other_flight_warning` says when
it is applied to another.

The monitor compares the IMUs sample by sample, so an uncorrected lag leaves
``τ_j · dω/dt`` in the parity residual (alarms in manoeuvres). This module moves each IMU
onto the reference's timing by sampling its record at ``t - τ_j`` (linear interpolation
between its own samples), before the monitor sees it. The IMU's auxiliary channels (its
accelerometers ``accel:<imu>.x/y/z`` and its temperature, :class:`AuxChannels` whose ``imu``
is the group) are moved with it, the same way, so that the inputs of the calibration's
effect terms (:func:`replay.effect_inputs.flight_effect_inputs`) stay on the samples they
belong to; channels of no IMU (``imu == ""``) are left as they are.

Times in s, rates in the flight's raw unit; arrays shaped (N, n) as in :class:`Flight`.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from replay.flight_data import Flight

__all__ = ["apply_time_offsets", "flight_identity", "moved_aux_channels", "other_flight_warning",
           "time_offsets_s"]


def time_offsets_s(cal: Calibration) -> dict[str, float]:
    """The fitted time offset τ (s) of every IMU group an in-flight calibration records
    (empty for a turntable calibration)."""
    imus = cal.extra.get("inflight", {}).get("imus", {})
    return {g: 1e-3 * float(rec["time_offset_ms"]) for g, rec in imus.items()
            if isinstance(rec, dict) and "time_offset_ms" in rec}


def _resample(t: np.ndarray, ts: np.ndarray, inside: np.ndarray, right: np.ndarray,
              x: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One column sampled at ``ts`` (linear interpolation between its valid samples) and
    its validity: both neighbours valid and ``ts`` within the record; NaN elsewhere."""
    ok = ok & np.isfinite(x)
    both = ok[right - 1] & ok[right] & inside
    out = np.interp(ts, t[ok], x[ok]) if ok.sum() >= 2 else np.array(x, float, copy=True)
    out[~both] = np.nan
    return out, both


def apply_time_offsets(flight: Flight, cal: Calibration) -> tuple[Flight, dict[str, Any]]:
    """``flight`` with each IMU group resampled at ``t - τ`` (its calibration's offset).

    A sample whose shifted time falls outside the group's record, or next to one of its
    invalid samples, is marked invalid (the monitor treats it as missing). The group's
    auxiliary channels (``flight.aux`` columns whose ``imu`` is the group) are resampled the
    same way (invalid, NaN, where the monitored columns would be).

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
    aux = flight.aux
    a_val = a_ok = None
    if aux is not None and aux.m:
        a_val = np.array(aux.values, dtype=float, copy=True)
        a_ok = np.array(aux.valid, dtype=bool, copy=True)
    applied: dict[str, float] = {}
    for g, tau in offsets.items():
        cols = [k for k, h in enumerate(groups) if h == g]
        if not cols or tau == 0.0:
            continue
        ts = t - tau
        inside = (ts >= t[0]) & (ts <= t[-1])
        right = np.clip(np.searchsorted(t, ts), 1, t.shape[0] - 1)
        for k in cols:
            raw[:, k], valid[:, k] = _resample(t, ts, inside, right, flight.raw[:, k],
                                               flight.valid[:, k])
        if a_val is not None:
            for j in (j for j, h in enumerate(aux.imu) if h == g):
                a_val[:, j], a_ok[:, j] = _resample(t, ts, inside, right, aux.values[:, j],
                                                    aux.valid[:, j])
        applied[g] = 1e3 * tau
    if not applied:
        return flight, {}
    if a_val is not None:
        aux = replace(aux, values=a_val, valid=a_ok)
    return replace(flight, raw=raw, valid=valid, aux=aux), applied


def moved_aux_channels(flight: Flight, applied: dict[str, Any]) -> list[str]:
    """The auxiliary channels (``kind:name``) :func:`apply_time_offsets` moved with the
    groups of ``applied``."""
    aux = flight.aux
    if aux is None:
        return []
    return [f"{k}:{nm}" for k, nm, g in zip(aux.kinds, aux.names, aux.imu, strict=True)
            if g and g in applied]


def flight_identity(flight: Flight) -> dict[str, object]:
    """What identifies a flight: its source log (file name), sample count, first and last
    time (s) and a fingerprint of its samples (sha256 of the times and rates, rounded to
    1e-9, first 16 hex digits)."""
    import hashlib
    from pathlib import PurePath

    t = np.asarray(flight.t, float)
    h = hashlib.sha256()
    h.update(np.round(t, 9).tobytes())
    h.update(np.round(np.nan_to_num(np.asarray(flight.raw, float)), 9).tobytes())
    return {"source": PurePath(str(flight.source)).name, "samples": int(t.shape[0]),
            "t0_s": float(t[0]) if t.size else 0.0, "t1_s": float(t[-1]) if t.size else 0.0,
            "fingerprint": h.hexdigest()[:16]}


def other_flight_warning(cal: Calibration, flight: Flight) -> str | None:
    """A warning when ``cal``'s time offsets were fitted on another flight than ``flight``
    (None when they were fitted on this one, when the calibration has no offsets, or
    when it does not record its flight)."""
    inflight = cal.extra.get("inflight", {})
    known = inflight.get("flight") if isinstance(inflight, dict) else None
    if not time_offsets_s(cal) or not isinstance(known, dict) or "fingerprint" not in known:
        return None
    here = flight_identity(flight)
    if here["fingerprint"] == known["fingerprint"]:
        return None
    return (f"the calibration's time offsets were fitted on another flight "
            f"({known.get('source', '?')}, {known.get('samples', '?')} samples) than this "
            f"one ({here['source']}, {here['samples']} samples): an offset belongs to its "
            f"flight, so what is left here may be the difference between the two")
