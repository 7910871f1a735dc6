"""Held-out false alarms on measured recordings, with and without the residual tail model.

Each recording is split in time at ``fraction``; the calibration (in-flight alignment for
a flight, bias = mean for a static set) is fitted on one part, thresholds are made from it
for a target rate, and the monitor counts false-alarm episodes on the other part; then the
roles swap. "Before" are the thresholds of today's Gaussian model (the same calibration
without its tail model: Allan variance factors); "after" use the tail model
(:func:`fdi.tails.tail_variance_factors`).

Counting follows the monitor's envelope rule: on a flight the periods the in-flight
calibration leaves out (:func:`calibration.inflight.segments.find_segments`: shocks,
saturation, gaps, invalid samples) are not counted and the monitor restarts its windows
after each (one fresh monitor per kept run); the exposure is the kept time. Isolation is
off (persistence 2^30): one false alarm = one detection episode. Time offsets of the
in-flight calibration are applied first, as ``rimu monitor-file`` does. Rates carry exact
Poisson (Garwood) 95 % intervals.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from fdi.settings import MonitorSettings, Thresholds
from replay.flight_data import Flight

__all__ = ["THRESHOLD_KINDS", "count_alarms", "flight_holdout", "slice_flight",
           "static_holdout_tails", "thresholds_for"]

THRESHOLD_KINDS = ("tune", "default")
"""``tune``: :func:`thresholds.tune.tune` (upcrossing shares; ``simulate_hours`` of
correction); ``default``: :func:`fdi.detector.default_thresholds` (what the monitor uses
without a thresholds file: per-sample Bonferroni)."""


def slice_flight(flight: Flight, rows: slice) -> Flight:
    """The samples ``rows`` of a flight (aux channels with them)."""
    aux = flight.aux.slice(rows) if flight.aux is not None else None
    return replace(flight, t=flight.t[rows], raw=flight.raw[rows], valid=flight.valid[rows],
                   omega_true=None if flight.omega_true is None else flight.omega_true[rows],
                   aux=aux)


def without_tails(cal: Calibration) -> Calibration:
    """The calibration without its tail model (today's Gaussian white thresholds)."""
    return replace(cal, sets={k: replace(s, tails=None) for k, s in cal.sets.items()})


def thresholds_for(cal: Calibration, rate: float, how: str, *,
                   simulate_hours: float = 0.0) -> Thresholds:
    """Thresholds for ``rate`` false alarms per hour (``how``: :data:`THRESHOLD_KINDS`)."""
    if how == "tune":
        from thresholds.tune import tune

        return tune(cal, false_alarms_per_hour=rate, simulate_hours=simulate_hours).thresholds
    from fdi.detector import default_thresholds

    return default_thresholds(cal, false_alarms_per_hour=rate)


def _runs(keep: np.ndarray) -> list[tuple[int, int]]:
    d = np.diff(np.concatenate([[0], keep.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True))


def count_alarms(cal: Calibration, thr: Thresholds, t: np.ndarray, raw: np.ndarray,
                 valid: np.ndarray, keep: np.ndarray, fs: float) -> dict[str, Any]:
    """Detection episodes of the monitor over the kept runs (a fresh monitor per run).

    Returns ``{"alarms", "hours", "per_hour", "ci95_per_hour", "alarm_times_s",
    "time_in_alarm_fraction"}``.
    """
    from fdi.monitor import Monitor
    from thresholds.evaluate import poisson_interval

    n, busy, total, times = 0, 0, 0, []
    for a, b in _runs(keep):
        if b - a < 2:
            continue
        mon = Monitor(cal, thr, settings=MonitorSettings(persistence=1 << 30))
        res = mon.run(t[a:b], raw[a:b], valid[a:b])
        ev = [e for e in res.events if e.type == "detected"]
        n += len(ev)
        times += [float(e.t) for e in ev]
        with np.errstate(invalid="ignore"):
            busy += int(np.any(res.statistics > res.thresholds, axis=1).sum())
        total += b - a
    hours = total / fs / 3600.0
    lo, hi = poisson_interval(n, hours)
    return {"alarms": n, "hours": hours, "per_hour": n / hours if hours > 0 else math.nan,
            "ci95_per_hour": [lo, hi], "alarm_times_s": times,
            "time_in_alarm_fraction": busy / total if total else math.nan}


def _verdict(rec: dict[str, Any], target: float) -> dict[str, Any]:
    """Resolvable: 3× the target would give at least 3 expected alarms in the exposure (a
    count of 0 then refutes it at 95 %). Within 3×: the interval's lower end ≤ 3 × target."""
    expected = target * rec["hours"]
    rec["expected_at_target"] = expected
    rec["resolvable"] = bool(3.0 * expected >= 3.0)
    rec["within_3x"] = bool(rec["ci95_per_hour"][0] <= 3.0 * target)
    return rec


def flight_holdout(flight: Flight, *, targets: tuple[float, ...] = (1.0, 10.0, 100.0),
                   fraction: float = 0.5, kinds: tuple[str, ...] = ("tune",),
                   simulate_hours: float = 0.0, jitter: bool = True) -> dict[str, Any]:
    """Both ways of a time split of a flight (module docstring).

    ``jitter``: the in-flight calibration carries the timing jitter and its tail model is
    relative to the monitor's threshold inflation (False: neither, as before the jitter
    term; :func:`calibration.inflight.calfile.calibration_from_fit`).

    Returns
    -------
    dict
        ``{"split_s", "ways": [{"fit": "first"|"second", "left_out", "kept_s",
        "tail_model": [...], "results": {kind: {target: {"before", "after"}}}}]}``.
    """
    from calibration.inflight.calfile import calibration_from_fit
    from calibration.inflight.fit import fit_inflight
    from calibration.inflight.segments import find_segments, keep_mask
    from calibration.inflight.timing import apply_time_offsets

    k = int(flight.t.shape[0] * fraction)
    parts = {"first": slice(0, k), "second": slice(k, flight.t.shape[0])}
    out: dict[str, Any] = {"source": flight.source, "samples": int(flight.t.shape[0]),
                           "split_s": float(flight.t[k] - flight.t[0]), "ways": []}
    for fit_name, count_name in (("first", "second"), ("second", "first")):
        fpart = slice_flight(flight, parts[fit_name])
        cpart = slice_flight(flight, parts[count_name])
        cal = calibration_from_fit(fit_inflight(fpart), fpart, jitter=jitter)
        moved, _ = apply_time_offsets(cpart, cal)
        segs = find_segments(cpart)
        keep = keep_mask(cpart.t, segs)
        way: dict[str, Any] = {
            "fit": fit_name, "count": count_name,
            "left_out": [s.to_dict() for s in segs],
            "kept_s": float(keep.sum() / flight.sample_rate_hz),
            "timing_jitter_ms": [c.timing_jitter * 1e3 for c in cal.gyro.sensors],
            "tail_model": _model_summary(cal), "results": {}}
        way["results"] = _before_after(cal, kinds, targets, simulate_hours, moved.t,
                                       moved.raw, moved.valid, keep, flight.sample_rate_hz)
        out["ways"].append(way)
    return out


def _before_after(cal: Calibration, kinds: Any, targets: Any, simulate_hours: float,
                  t: np.ndarray, raw: np.ndarray, valid: np.ndarray, keep: np.ndarray,
                  fs: float) -> dict[str, Any]:
    """Per threshold kind and target: alarms counted on (t, raw) with the thresholds of the
    calibration without its tail model ("before") and with it ("after")."""
    results: dict[str, Any] = {}
    for how in kinds:
        res = {}
        for R in targets:
            rec = {}
            for label, c in (("before", without_tails(cal)), ("after", cal)):
                thr = thresholds_for(c, R, how, simulate_hours=simulate_hours)
                r = count_alarms(cal, thr, t, raw, valid, keep, fs)
                r["variance_factor"] = list(thr.variance_factor)
                r["noise_model"] = thr.noise_model
                r.update(_detectable(cal, thr))
                rec[label] = _verdict(r, R)
            res[str(R)] = rec
        results[how] = res
    return results


def _detectable(cal: Calibration, thr: Thresholds) -> dict[str, Any]:
    """Smallest step (deg/s) one full window detects with 99 % at rest, best scale and w = 1
    (:func:`thresholds.tune.detectable_sizes`, worst sensor)."""
    from thresholds.tune import detectable_sizes

    d = detectable_sizes(cal, thr, draws=500)
    best = min(d, key=lambda x: x.size_unit_value)
    return {"detectable_dps_scale1": d[0].size_unit_value,
            "detectable_dps_best": best.size_unit_value, "detectable_best_scale": best.scale}


def _model_summary(cal: Calibration) -> list[dict[str, Any]]:
    m = cal.gyro.tails
    if m is None:
        return []
    return [{"scale": s.scale, "gaussian": s.gaussian, "excess_kurtosis": s.excess_kurtosis,
             "variance_ratio": s.variance_ratio, "independent": s.independent,
             "gpd_shape": None if s.gpd is None else s.gpd.shape,
             "gpd_shape_sd": None if s.gpd is None else s.gpd.shape_sd,
             "gpd_shape_upper": None if s.gpd is None else s.gpd.shape_upper}
            for s in m.scales]


def static_holdout_tails(t: np.ndarray, y: np.ndarray, names: tuple[str, ...], *,
                         targets: tuple[float, ...] = (1.0, 10.0, 100.0),
                         fraction: float = 0.5, kinds: tuple[str, ...] = ("tune",),
                         simulate_hours: float = 0.0) -> dict[str, Any]:
    """Both ways of a time split of a static recording (N, n) rad/s (module docstring).

    The calibration of a part is :func:`studies.realnoise.static_calibration` (aligned
    triads, bias = mean, full covariance, Allan table) with the tail model of its residual
    (y − mean) added; the whole other part is counted (a bench has no envelope).
    """
    from calibration.tails import fit_tail_model
    from studies.realnoise import static_calibration

    t = np.asarray(t, float)
    y = np.asarray(y, float)
    fs = (t.size - 1) / float(t[-1] - t[0])
    k = int(t.size * fraction)
    parts = {"first": slice(0, k), "second": slice(k, t.size)}
    out: dict[str, Any] = {"samples": int(t.size), "sample_rate_hz": fs, "ways": []}
    for fit_name, count_name in (("first", "second"), ("second", "first")):
        yf = y[parts[fit_name]]
        cal = static_calibration(yf, fs, names)
        s = cal.gyro
        model = fit_tail_model(yf - yf.mean(axis=0), s.H, s.noise_covariance, fs,
                               source="static bench residual (y - mean)")
        cal = replace(cal, sets={"gyro": replace(s, tails=model)})
        tc, yc = t[parts[count_name]], y[parts[count_name]]
        valid = np.ones(yc.shape, bool)
        keep = np.ones(tc.size, bool)
        way: dict[str, Any] = {"fit": fit_name, "count": count_name,
                               "tail_model": _model_summary(cal), "results": {}}
        way["results"] = _before_after(cal, kinds, targets, simulate_hours, tc - tc[0], yc,
                                       valid, keep, fs)
        out["ways"].append(way)
    return out
