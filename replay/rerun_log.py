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
    integrity/unverified     1 where the rate of a body axis (x, y, z) is not verified (a
                             detection whose sensors cannot be told apart), else 0
    integrity/envelope       the operating-envelope code (0: inside; fdi.envelope bits)
    events                   one TextLog per monitor event (WARN detected, ERROR isolated,
                             WARN disagree, WARN health, INFO readmitted, INFO envelope)

:class:`Recorder` logs it piece by piece (one ``send_columns`` per entity and piece, never
``rr.log`` per sample; a long replay streams its pieces to the file) and :func:`record` in one
piece, and writes it with ``save`` (headless) and/or ``spawn`` (viewer), with a blueprint
laying out raw | compensated, ω̂ vs truth, detector statistics | parity, health | events.
"""

from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from fdi.calfile import Calibration
from fdi.units import DPS

__all__ = ["ENTITIES", "Recorder", "blueprint", "record"]

ENTITIES = ("sensors/raw", "sensors/compensated", "sensors/health", "parity", "omega/estimate",
            "integrity/protection_level_dps", "events")
"""Entities every recording holds (plus ``detector/*`` and, with truth, ``omega/truth``)."""

_LEVEL = {"detected": "WARN", "isolated": "ERROR", "health": "WARN", "readmitted": "INFO",
          "disagree": "WARN", "envelope": "INFO"}


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


class Recorder:
    """A rerun recording written piece by piece (bounded memory on long runs).

    Parameters
    ----------
    cal : Calibration
    sensor_names : sequence of str
    kind : str
    has_truth : bool
        Whether pieces come with true rates (adds ``omega/truth`` and ``omega/error``).
    path : path, optional
        ``.rrd`` file to write (headless).
    spawn : bool
        Also open the rerun viewer.
    thresholds : fdi.settings.Thresholds, optional
        Names the statistic columns.
    application_id : str
    """

    def __init__(self, cal: Calibration, sensor_names: Any, kind: str = "gyro", *,
                 has_truth: bool = False, path: str | Path | None = None, spawn: bool = False,
                 thresholds: Any = None, application_id: str = "rimu") -> None:
        self.s = cal.kind(kind)
        self.kind = kind
        self.names = list(sensor_names)
        self.has_truth = has_truth
        self.thresholds = thresholds
        self.path = path
        self.rows = 0
        self.log_s = 0.0
        self._events = 0
        self._t_first: float | None = None
        self._static_done = False
        self._closed = False
        bp = blueprint(has_truth)
        t0 = time.perf_counter()
        self.rec = rr.RecordingStream(application_id)
        if path is not None:
            self.rec.save(str(path), default_blueprint=bp)
        if spawn:
            self.rec.spawn(default_blueprint=bp)
        self.log_s += time.perf_counter() - t0

    def _series(self, path: str, t: np.ndarray, values: np.ndarray, names: list[str]) -> None:
        v = np.asarray(values, dtype=np.float64)
        if v.ndim == 1:
            v = v[:, None]
        if not self._static_done:
            self.rec.log(path, rr.SeriesLines(names=names), static=True)
        self.rec.send_columns(path, indexes=[rr.TimeColumn("time", duration=t)],
                              columns=rr.Scalars.columns(scalars=v))

    def log(self, result: Any, flight: Any) -> None:
        """Log one piece: the answers ``result`` for the samples of ``flight``."""
        t = np.asarray(result.t, dtype=np.float64)
        if t.size == 0:
            return
        t0 = time.perf_counter()
        if self._t_first is None:
            self._t_first = float(t[0])
        unit = DPS if self.kind == "gyro" else 1.0
        self._log_sensors(t, result, flight, unit)
        self._log_detector(t, result)
        self._log_omega(t, result, flight, unit)
        self._log_integrity(t, result, unit)
        self._static_done = True
        self._log_events(result)
        self.rows += int(t.size)
        self.log_s += time.perf_counter() - t0

    def _log_sensors(self, t: np.ndarray, result: Any, flight: Any, unit: float) -> None:
        """Raw, compensated and health series per sensor, and the parity vector.

        Parameters
        ----------
        t : ndarray
            Sample times (s).
        result : BlockResult
        flight : Flight
        unit : float
            SI per displayed unit (deg/s for gyros).
        """
        s, names = self.s, self.names
        raw = np.asarray(flight.raw, float)
        self._series("sensors/raw", t, raw, names)
        self._series("sensors/compensated", t, (raw * s.scale_factors - s.biases) / unit, names)
        self._series("sensors/health", t, np.asarray(result.healthy, float), names)
        par = getattr(result, "parity", None)
        if par is None or np.asarray(par).shape[0] != t.size:
            par = np.full((t.size, max(s.n - 3, 1)), np.nan)
        par = np.asarray(par, float)
        self._series("parity", t, par, [f"p{j + 1}" for j in range(par.shape[1])])

    def _log_detector(self, t: np.ndarray, result: Any) -> None:
        """Each detector statistic beside its threshold.

        Parameters
        ----------
        t : ndarray
        result : BlockResult
        """
        stats = np.asarray(result.statistics, float)
        thr = np.asarray(result.thresholds, float)
        for j, name in enumerate(_scale_names(self.thresholds, stats.shape[1])):
            self._series(f"detector/{name}", t, np.column_stack([stats[:, j], thr[:, j]]),
                         ["statistic", "threshold"])

    def _log_omega(self, t: np.ndarray, result: Any, flight: Any, unit: float) -> None:
        """The estimated rate, and with the truth, the true rate and the error.

        Parameters
        ----------
        t : ndarray
        result : BlockResult
        flight : Flight
        unit : float
        """
        axes = ["x", "y", "z"]
        omega = np.asarray(result.omega, float) / unit
        self._series("omega/estimate", t, omega, [f"ω̂{a}" for a in axes])
        tru = getattr(flight, "omega_true", None)
        if self.has_truth and tru is not None and len(tru) == t.size:
            tru = np.asarray(tru, float) / unit
            self._series("omega/truth", t, tru, [f"ω{a}" for a in axes])
            self._series("omega/error", t, omega - tru, [f"δω{a}" for a in axes])

    def _log_integrity(self, t: np.ndarray, result: Any, unit: float) -> None:
        """Protection level, and where the answer carries them, the unverified axes and the
        envelope code.

        Parameters
        ----------
        t : ndarray
        result : BlockResult
        unit : float
        """
        axes = ["x", "y", "z"]
        self._series("integrity/protection_level_dps", t,
                     np.asarray(result.protection_level, float) / unit, ["protection level"])
        unv = getattr(result, "unverified", None)
        if unv is not None and np.shape(unv) == (t.size, 3):
            self._series("integrity/unverified", t, np.asarray(unv, float),
                         [f"unverified {a}" for a in axes])
        env = getattr(result, "envelope", None)
        if env is not None and np.shape(env) == (t.size,):
            self._series("integrity/envelope", t, np.asarray(env, float)[:, None],
                         ["out of envelope (code)"])

    def _log_events(self, result: Any) -> None:
        """The piece's events as a text log.

        Parameters
        ----------
        result : BlockResult
        """
        ev = list(result.events)
        if not ev:
            return
        et = np.array([float(e.t) for e in ev])
        self.rec.send_columns(
            "events", indexes=[rr.TimeColumn("time", duration=et)],
            columns=rr.TextLog.columns(text=[_event_text(e, self.names) for e in ev],
                                       level=[_LEVEL.get(e.type, "INFO") for e in ev]))
        self._events += len(ev)

    def abort(self) -> None:
        """Stop recording without finishing (after an error); harmless after :meth:`close`."""
        if not self._closed:
            self._closed = True
            with contextlib.suppress(Exception):
                self.rec.disconnect()

    def close(self) -> dict[str, float]:
        """Flush and close; returns ``{"log_s", "flush_s", "rows"}``."""
        self._closed = True
        if self._events == 0:
            tf = np.array([self._t_first if self._t_first is not None else 0.0])
            self.rec.send_columns("events", indexes=[rr.TimeColumn("time", duration=tf)],
                                  columns=rr.TextLog.columns(text=["no events"],
                                                             level=["INFO"]))
        t1 = time.perf_counter()
        self.rec.flush()
        if self.path is not None:
            self.rec.disconnect()
        return {"log_s": self.log_s, "flush_s": time.perf_counter() - t1, "rows": self.rows}


def record(result: Any, flight: Any, cal: Calibration, *, path: str | Path | None = None,
           spawn: bool = False, kind: str | None = None, thresholds: Any = None,
           application_id: str = "rimu") -> dict[str, float]:
    """Write a monitoring run as a rerun recording (one :class:`Recorder` piece).

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
    has_truth = flight.omega_true is not None and len(flight.omega_true) == len(result.t)
    rec = Recorder(cal, flight.sensor_names, kind, has_truth=has_truth, path=path,
                   spawn=spawn, thresholds=thresholds, application_id=application_id)
    rec.log(result, flight)
    return rec.close()


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
