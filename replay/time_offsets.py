"""The time offsets of an in-flight calibration, applied wherever the monitor runs.

The in-flight fit (:mod:`calibration.inflight.fit`) models IMU ``j`` as
``y_j(t) = A_j · y_ref(t + τ_j) + c_j``: IMU ``j`` sees the motion ``-τ_j`` late when
``τ_j < 0``. The monitor compares the IMUs sample by sample, so an uncorrected lag leaves
``τ_j · dω/dt`` in the parity residual (alarms in manoeuvres). One timing model moves each
IMU onto the reference's timing by sampling its record at ``t - τ_j`` (linear interpolation
between its own two samples around that time) before the monitor sees it:

- a sample whose shifted time falls outside the record, or next to one of the IMU's
  invalid samples, is marked invalid (the monitor treats it as missing);
- the IMU's auxiliary channels (its accelerometers and temperature, whose ``imu`` is the
  group) are moved with it, the same way; channels of no IMU are left as they are.

Two implementations of that one model:

- :func:`apply_time_offsets` moves a whole recorded flight (vectorised);
- :class:`StreamAligner` does the same causally on a stream handed over in pieces (a CAN
  log read in blocks, a live bus): it keeps the few samples before (for ``τ > 0``) and
  holds back the samples after (for ``τ < 0``) that the interpolation needs. A sample is
  handed on once a sample at least ``max(-τ_j, 0)`` later has arrived (or at the end of
  the stream), so the monitor's answers come at most ``max(-τ_j, 0)`` plus one sample
  period later than without offsets (:attr:`StreamAligner.delay_s`); offsets beyond
  :data:`MAX_TIME_OFFSET_S` are refused. Its samples equal :func:`apply_time_offsets`'
  on the concatenated pieces, bit for bit (the same interpolation on the same two
  samples), whatever the pieces' sizes.

An IMU's group is ``Flight.imu`` where the flight records it, else the part of the sensor
name before its last dot (``imu2.x`` → ``imu2``), which is how ingest and the simulator name
the sensors of an IMU set and the in-flight calibration names its IMUs.

Times in s, rates in the flight's raw unit; arrays shaped (N, n) as in :class:`Flight`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from fdi.errors import ConfigError
from replay.flight_data import Flight, flight_rows

__all__ = ["MAX_TIME_OFFSET_S", "StreamAligner", "apply_time_offsets", "flight_identity",
           "imu_groups", "moved_aux_channels", "time_offsets_s"]

MAX_TIME_OFFSET_S = 1.0
"""Largest |τ| applied (s); a calibration with a larger offset is refused (a lag of a
second between two IMUs of one vehicle is a broken time base, not a calibration)."""


def time_offsets_s(cal: Calibration) -> dict[str, float]:
    """The fitted time offset τ (s) of every IMU group an in-flight calibration records
    (empty for a turntable calibration)."""
    return cal.extras.time_offsets_s()


def imu_groups(sensor_names: Sequence[str], imu: Sequence[str] = ()) -> tuple[str, ...]:
    """The IMU group of each sensor: ``imu`` when given, else the name before its last dot
    (``""`` for a name without one)."""
    if imu:
        return tuple(imu)
    return tuple(nm.rpartition(".")[0] for nm in sensor_names)


def _resample(t: np.ndarray, ts: np.ndarray, inside: np.ndarray, right: np.ndarray,
              x: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One column sampled at ``ts`` (linear interpolation between its valid samples) and
    its validity: both neighbours valid and ``ts`` within the record; NaN elsewhere."""
    ok = ok & np.isfinite(x)
    both = ok[right - 1] & ok[right] & inside
    out = np.interp(ts, t[ok], x[ok]) if ok.sum() >= 2 else np.full(ts.shape, np.nan)
    out[~both] = np.nan
    return out, both


def _checked(offsets: dict[str, float], source: str) -> dict[str, float]:
    bad = {g: tau for g, tau in offsets.items()
           if not (np.isfinite(tau) and abs(tau) <= MAX_TIME_OFFSET_S)}
    if bad:
        g, tau = next(iter(bad.items()))
        raise ConfigError(f"{source}: time offset of {g} is {1e3 * tau:g} ms; at most "
                          f"{1e3 * MAX_TIME_OFFSET_S:g} ms is applied (is the time base "
                          "right?)")
    return offsets


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

    Raises
    ------
    ConfigError
        An offset beyond :data:`MAX_TIME_OFFSET_S`.
    """
    offsets = _checked(time_offsets_s(cal), f"calibration of {cal.configuration}")
    groups = imu_groups(flight.sensor_names, getattr(flight, "imu", ()))
    if not offsets or not any(groups) or flight.t.shape[0] < 2:
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


class StreamAligner:
    """:func:`apply_time_offsets` on a stream of flight pieces, causally (module docstring).

    Parameters
    ----------
    cal : Calibration
        Its in-flight time offsets (:func:`time_offsets_s`).
    groups : sequence of str
        IMU group of each monitored sensor (:func:`imu_groups`).
    aux_groups : sequence of str, optional
        IMU group of each auxiliary column of the pieces (``""``: not moved); default the
        pieces' own ``aux.imu``.

    Attributes
    ----------
    applied : dict
        ``{group: τ in ms}`` of the groups moved (empty: the aligner passes pieces through
        unchanged and holds nothing back).
    delay_s : float
        ``max(-τ, 0)`` over the groups moved: a sample is handed on once a sample this much
        later has arrived (the answers lag by at most this plus one sample period).

    Raises
    ------
    ConfigError
        An offset beyond :data:`MAX_TIME_OFFSET_S`.
    """

    def __init__(self, cal: Calibration, groups: Sequence[str],
                 aux_groups: Sequence[str] | None = None) -> None:
        offsets = _checked(time_offsets_s(cal), f"calibration of {cal.configuration}")
        self.groups = tuple(groups)
        self.aux_groups = None if aux_groups is None else tuple(aux_groups)
        self.offsets = {g: tau for g, tau in offsets.items()
                        if tau != 0.0 and g in self.groups}
        self.applied = {g: 1e3 * tau for g, tau in self.offsets.items()}
        taus = list(self.offsets.values())
        self.delay_s = max([0.0, *(-x for x in taus)])
        self._back_s = max([0.0, *taus])
        self._buf: Flight | None = None     # kept rows: history, then rows not yet handed on
        self._next = 0                      # first row of _buf not yet handed on
        self._t_first: float | None = None

    @property
    def active(self) -> bool:
        """Whether any group is moved."""
        return bool(self.offsets)

    def push(self, piece: Flight) -> Flight | None:
        """Take the next piece; return the samples now aligned (None when none yet)."""
        if not self.active:
            return piece
        if piece.t.shape[0] == 0:
            return None
        if self._t_first is None:
            self._t_first = float(piece.t[0])
        buf = piece if self._buf is None else _concat(self._buf, piece)
        t = np.asarray(buf.t, float)
        t_last = float(t[-1])
        stop = int(np.searchsorted(t, t_last - self.delay_s, side="right"))
        return self._emit(buf, stop, t_last)

    def flush(self) -> Flight | None:
        """The samples still held back (end of the stream)."""
        if not self.active or self._buf is None:
            return None
        buf = self._buf
        return self._emit(buf, buf.t.shape[0], float(buf.t[-1]))

    def _emit(self, buf: Flight, stop: int, t_last: float) -> Flight | None:
        start = self._next
        if stop <= start:
            self._buf, self._next = buf, start
            return None
        out = self._align(buf, start, stop, t_last)
        # keep the rows the next samples may interpolate from: from the last one before
        # (next sample's time − the largest positive offset)
        t = np.asarray(buf.t, float)
        keep = max(int(np.searchsorted(t, t[stop] - self._back_s)) - 1, 0) \
            if stop < t.shape[0] else max(int(np.searchsorted(t, t_last - self._back_s)) - 1,
                                          0)
        keep = min(keep, stop)
        self._buf = flight_rows(buf, slice(keep, None))
        self._next = stop - keep
        return out

    def _align(self, buf: Flight, start: int, stop: int, t_last: float) -> Flight:
        t = np.asarray(buf.t, float)
        rows = slice(start, stop)
        raw = np.array(buf.raw[rows], dtype=float, copy=True)
        valid = np.array(buf.valid[rows], dtype=bool, copy=True)
        aux = buf.aux
        a_val = a_ok = None
        a_groups = (self.aux_groups if self.aux_groups is not None
                    else (aux.imu if aux is not None else ()))
        if aux is not None and aux.m:
            a_val = np.array(aux.values[rows], dtype=float, copy=True)
            a_ok = np.array(aux.valid[rows], dtype=bool, copy=True)
        for g, tau in self.offsets.items():
            ts = t[rows] - tau
            inside = (ts >= self._t_first) & (ts <= t_last)
            right = np.clip(np.searchsorted(t, ts), 1, t.shape[0] - 1)
            for k in (k for k, h in enumerate(self.groups) if h == g):
                raw[:, k], valid[:, k] = _resample(t, ts, inside, right, buf.raw[:, k],
                                                   buf.valid[:, k])
            if a_val is not None:
                for j in (j for j, h in enumerate(a_groups) if h == g):
                    a_val[:, j], a_ok[:, j] = _resample(t, ts, inside, right,
                                                        aux.values[:, j], aux.valid[:, j])
        piece = flight_rows(buf, rows)
        new_aux = piece.aux
        if a_val is not None:
            new_aux = replace(piece.aux, values=a_val, valid=a_ok)
        return replace(piece, raw=raw, valid=valid, aux=new_aux)


def _concat(a: Flight, b: Flight) -> Flight:
    """Two consecutive pieces of one stream as one."""
    aux = None
    if a.aux is not None and b.aux is not None:
        aux = replace(b.aux, values=np.concatenate([a.aux.values, b.aux.values]),
                      valid=np.concatenate([a.aux.valid, b.aux.valid]))
    tru = None
    if a.omega_true is not None and b.omega_true is not None:
        tru = np.concatenate([a.omega_true, b.omega_true])
    return replace(b, t=np.concatenate([a.t, b.t]), raw=np.concatenate([a.raw, b.raw]),
                   valid=np.concatenate([a.valid, b.valid]), omega_true=tru, aux=aux)


def flight_identity(flight: Flight) -> dict[str, object]:
    """What identifies a flight: its source log (file name), sample count, first and last
    time (s), a fingerprint of its samples (sha256 of the times and rates, rounded to
    1e-9, first 16 hex digits) and the firmware its log names (``""`` when none,
    :func:`replay.firmware.firmware_of`)."""
    import hashlib
    from pathlib import PurePath

    from replay.firmware import firmware_of

    t = np.asarray(flight.t, float)
    h = hashlib.sha256()
    h.update(np.round(t, 9).tobytes())
    h.update(np.round(np.nan_to_num(np.asarray(flight.raw, float)), 9).tobytes())
    return {"source": PurePath(str(flight.source)).name, "samples": int(t.shape[0]),
            "t0_s": float(t[0]) if t.size else 0.0, "t1_s": float(t[-1]) if t.size else 0.0,
            "fingerprint": h.hexdigest()[:16],
            "firmware": firmware_of(getattr(flight, "events", ()) or ())}
