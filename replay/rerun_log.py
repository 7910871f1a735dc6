"""rerun recordings of a monitoring run (rerun-sdk 0.41 API), batch-logged with ``send_columns``.

Entities, all on one timeline ``"time"`` (duration, seconds of flight time)::

    sensors/raw              raw outputs, one series per sensor (raw units)
    sensors/compensated      y_i = SF_i·u_i − b_i, °/s (gyro) or m/s² (accel)
    sensors/health           1 healthy, 0 isolated, per sensor
    parity                   parity vector components (NaN-padded when sensors are out)
    detector/scale_<w>       statistic and threshold of the window of w samples
    detector/cusum           statistic and threshold of the CUSUM (when the monitor has one)
    omega/estimate           ω̂ (x, y, z), °/s
    omega/truth              true body rates (°/s), when the flight has them
    omega/error              ω̂ − ω (°/s), when the flight has truth
    integrity/protection_level_dps
    events                   one TextLog per monitor event (WARN detected, ERROR isolated,
                             WARN health, INFO readmitted)

:func:`record` logs all of it with one ``send_columns`` per entity (never ``rr.log`` per
sample) and writes it with ``save`` (headless) and/or ``spawn`` (viewer), with a blueprint
laying out raw | compensated, ω̂ vs truth, detector statistics | parity, health | events.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from fdi.calfile import Calibration
from fdi.units import DPS

__all__ = ["ENTITIES", "blueprint", "record"]

ENTITIES = ("sensors/raw", "sensors/compensated", "sensors/health", "parity", "omega/estimate",
            "integrity/protection_level_dps", "events")
"""Entities every recording holds (plus ``detector/*`` and, with truth, ``omega/truth``)."""

_LEVEL = {"detected": "WARN", "isolated": "ERROR", "health": "WARN", "readmitted": "INFO"}


def blueprint(has_truth: bool) -> rrb.Blueprint:
    """The default layout of a rimu recording."""
    omega_views = [rrb.TimeSeriesView(origin="/omega", name="ω̂ vs truth (°/s)")]
    if has_truth:
        omega_views.append(rrb.TimeSeriesView(origin="/omega/error", name="ω̂ − ω (°/s)"))
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                rrb.TimeSeriesView(origin="/sensors/raw", name="raw outputs"),
                rrb.TimeSeriesView(origin="/sensors/compensated", name="compensated"),
            ),
            rrb.Horizontal(*omega_views,
                           rrb.TimeSeriesView(origin="/integrity",
                                              name="protection level (°/s)")),
            rrb.Horizontal(
                rrb.TimeSeriesView(origin="/detector", name="statistic vs threshold"),
                rrb.TimeSeriesView(origin="/parity", name="parity"),
            ),
            rrb.Horizontal(
                rrb.TimeSeriesView(origin="/sensors/health", name="sensor health"),
                rrb.TextLogView(origin="/events", name="events"),
            ),
            row_shares=[3, 3, 3, 2],
        ),
        collapse_panels=True,
    )


def _series(rec: rr.RecordingStream, path: str, t: np.ndarray, values: np.ndarray,
            names: list[str]) -> None:
    v = np.asarray(values, dtype=np.float64)
    if v.ndim == 1:
        v = v[:, None]
    rec.log(path, rr.SeriesLines(names=names), static=True)
    rec.send_columns(path, indexes=[rr.TimeColumn("time", duration=t)],
                     columns=rr.Scalars.columns(scalars=v))


def record(result: Any, flight: Any, cal: Calibration, *, path: str | Path | None = None,
           spawn: bool = False, kind: str | None = None, thresholds: Any = None,
           application_id: str = "rimu") -> dict[str, float]:
    """Write a monitoring run as a rerun recording.

    Parameters
    ----------
    result : fdi.answer.BlockResult
        ``Monitor.run`` over the flight's samples.
    flight : replay.flight.Flight
    cal : Calibration
    path : path, optional
        ``.rrd`` file to write (headless).
    spawn : bool
        Also open the rerun viewer.
    kind : str, optional
        Defaults to the flight's.
    thresholds : fdi.settings.Thresholds, optional
        The monitor's thresholds: names the statistic columns (``scale_<w>``, ``cusum``).
    application_id : str

    Returns
    -------
    dict
        ``{"log_s": ..., "flush_s": ..., "rows": N}`` timings.
    """
    kind = kind or flight.kind
    s = cal.kind(kind)
    t = np.asarray(result.t, dtype=np.float64)
    has_truth = flight.omega_true is not None and len(flight.omega_true) == len(t)
    bp = blueprint(has_truth)
    rec = rr.RecordingStream(application_id)
    t0 = time.perf_counter()
    if path is not None:
        rec.save(str(path), default_blueprint=bp)
    if spawn:
        rec.spawn(default_blueprint=bp)
    names = list(flight.sensor_names)
    unit = DPS if kind == "gyro" else 1.0
    _series(rec, "sensors/raw", t, flight.raw, names)
    y = (flight.raw * s.scale_factors - s.biases) / unit
    _series(rec, "sensors/compensated", t, y, names)
    _series(rec, "sensors/health", t, np.asarray(result.healthy, float), names)
    par = getattr(result, "parity", None)
    if par is None:
        par = np.full((len(t), max(s.n - 3, 1)), np.nan)
    par = np.asarray(par, float)
    _series(rec, "parity", t, par, [f"p{j + 1}" for j in range(par.shape[1])])
    stats = np.asarray(result.statistics, float)
    thr = np.asarray(result.thresholds, float)
    scales = _scale_names(thresholds, stats.shape[1])
    for j, name in enumerate(scales):
        _series(rec, f"detector/{name}", t, np.column_stack([stats[:, j], thr[:, j]]),
                ["statistic", "threshold"])
    axes = ["x", "y", "z"]
    omega = np.asarray(result.omega, float) / unit
    _series(rec, "omega/estimate", t, omega, [f"ω̂{a}" for a in axes])
    if has_truth:
        tru = np.asarray(flight.omega_true, float) / unit
        _series(rec, "omega/truth", t, tru, [f"ω{a}" for a in axes])
        _series(rec, "omega/error", t, omega - tru, [f"δω{a}" for a in axes])
    _series(rec, "integrity/protection_level_dps", t,
            np.asarray(result.protection_level, float) / unit, ["protection level"])
    ev = list(result.events)
    if ev:
        et = np.array([float(e.t) for e in ev])
        text = [_event_text(e, names) for e in ev]
        lvl = [_LEVEL.get(e.type, "INFO") for e in ev]
        rec.send_columns("events", indexes=[rr.TimeColumn("time", duration=et)],
                         columns=rr.TextLog.columns(text=text, level=lvl))
    else:
        rec.send_columns("events", indexes=[rr.TimeColumn("time", duration=t[:1])],
                         columns=rr.TextLog.columns(text=["no events"], level=["INFO"]))
    t1 = time.perf_counter()
    rec.flush()
    if path is not None:
        rec.disconnect()
    t2 = time.perf_counter()
    return {"log_s": t1 - t0, "flush_s": t2 - t1, "rows": len(t)}


def _scale_names(thresholds: Any, K: int) -> list[str]:
    if thresholds is not None:
        names = [f"scale_{int(w)}" for w in thresholds.scales]
        if getattr(thresholds, "detector", "windows") != "windows":
            names.append("cusum")
        if len(names) == K:
            return names
    return [f"statistic_{j + 1}" for j in range(K)]


def _event_text(e: Any, names: list[str]) -> str:
    who = "—" if e.sensor is None else f"sensor {e.sensor} ({names[e.sensor - 1]})" \
        if 1 <= e.sensor <= len(names) else f"sensor {e.sensor}"
    txt = f"t={float(e.t):.3f}s {e.type} {who}: {e.reason}"
    st, th = float(e.statistic), float(e.threshold)
    if np.isfinite(st) and np.isfinite(th):
        txt += f" (statistic {st:.4g} / threshold {th:.4g})"
    if e.magnitude is not None and np.isfinite(e.magnitude):
        txt += f", magnitude {e.magnitude:.3g}"
    return txt
