"""Evidence on measured data: held-out false alarms, runs from the start, injected faults.

What a vehicle would see, computed from real recordings with the library calls the command
line makes (``rimu ingest`` → ``rimu calibrate in-flight`` → ``rimu tune`` →
``rimu monitor-file``), so that one call recomputes every number of
``docs/field-results.md`` (``studies/make_field_results.py``) and the slow test
``tests/thresholds/test_field_results.py``:

- :func:`holdout_flight`, :func:`holdout_static_set` (the static set through
  ``rimu calibrate static``; :func:`holdout_static` is the bench calibration of
  :mod:`studies.realnoise` that ``docs/drift.md`` compares): split a recording in time,
  calibrate and tune on one part at several targets, count alarm episodes on the other
  part outside the out-of-envelope periods, both ways round; per target the expected
  count, the observed count with its exact Poisson interval, and whether the length
  resolves the target;
- :func:`from_start`: calibrate on the whole flight and monitor it from the first sample, as
  a user does: events, excluded sensors, time in alarm, protection level;
- :func:`inject_flight`: steps and ramps injected into each sensor of a real flight
  (:func:`replay.scenario.apply_faults`, sizes in SI through the calibration's scale
  factors) at onsets in calm stretches; detection delay, missed detections, wrong
  exclusions, "disagree" events and unverified axes, beside the detectable size
  ``rimu tune`` states (:func:`thresholds.tune.detectable_sizes`).

Definitions (the test asserts against these)
--------------------------------------------
- An *alarm episode* starts at a ``detected`` or ``health`` event, or at an ``isolated`` /
  ``disagree`` event that no ``detected`` event opened (:func:`alarm_episodes`).
- *Out of envelope*: the answer's ``envelope`` code when the monitor gives one
  (``BlockResult.envelope``, issue 17); until then the shock and saturation segments of
  :func:`calibration.inflight.segments.find_segments` (gaps and invalid samples are not an
  envelope condition). :func:`envelope_codes` says which source was used.
- *Time in alarm*: the share of samples in which some window statistic is above its
  threshold; what the target implies is the thresholds' own per-sample budget Σ_w α_w.
- A target is *resolved* by an exposure T (h) when a clean run would show the rate is below
  3× the target at 95 %: the Poisson upper limit for zero alarms, −ln(0.05)/T, is at most
  3·R, i.e. R·T ≥ −ln(0.05)/3 ≈ 1.0 expected alarm (:data:`RESOLVE_EXPECTED`).
- *Flying time*: from the first to the last sample where the first IMU turns faster than
  0.1 rad/s above its at-rest median (the rule of the in-flight segments), gaps excluded.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from fdi.units import DPS
from replay.faults import Fault
from replay.flight_data import Flight
from thresholds.per_draw import alarm_episodes

__all__ = [
    "ALARM_EVENTS",
    "FIELD_SCHEMA",
    "FLIGHTS",
    "RESOLVE_EXPECTED",
    "TARGETS_PER_HOUR",
    "alarm_episodes",
    "envelope_codes",
    "field_results",
    "flying_mask",
    "from_start",
    "holdout_flight",
    "holdout_static",
    "holdout_static_set",
    "inflight_calibration",
    "inject_flight",
    "load_erle",
    "load_static_set",
    "rate_row",
    "run_monitor",
    "split_flight",
]

FIELD_SCHEMA = "rimu.field-results/1"
TARGETS_PER_HOUR = (1.0, 10.0, 100.0, 1000.0)
"""False-alarm targets (episodes per hour) tuned and counted."""
RESOLVE_EXPECTED = -math.log(0.05) / 3.0
"""Expected alarms from which a recording resolves its target (module docstring)."""
ALARM_EVENTS = ("detected", "isolated", "health", "disagree")
"""Event types that raise an alarm (``disagree``: issue 17's undecided isolation)."""
EXCLUDING_EVENTS = ("isolated", "health")
"""Event types that take a sensor out of the set."""
FLIGHTS = {"41": "pxf_copter_22-12-2014_41.BIN", "83": "pxf_copter_31-3-2015_83.BIN"}
"""The two ArduCopter flights (files of ``erle_pxf_dual_imu``)."""
STEPS_DPS = (2.0, 5.0, 10.0)
RAMP_DPS_PER_S = 0.5
FAULT_S = 10.0
"""Length of an injected fault, and the time within which it must be detected (s)."""
LOCAL_START_S = 10.0
"""The second set of injected runs starts the monitor this long before the onset (s)."""

_SHOCK, _SATURATION = 1, 2           # contract bit codes of fdi.envelope (issue 17)
_SEGMENT_CODES = {"shock": _SHOCK, "take-off": _SHOCK, "crash": _SHOCK,
                  "saturation": _SATURATION}


# --------------------------------------------------------------------------- inputs
def load_erle(path: str | Path) -> Flight:
    """A DataFlash log as ``rimu ingest LOG --salvage`` makes it (no folder written)."""
    from replay.ingest import align_streams, read_any
    from replay.ingest.readers import merge_reads

    read = merge_reads([read_any(path, "auto", salvage=True)])
    flight, _ = align_streams(read)
    return flight


def _part(flight: Flight, sl: slice) -> Flight:
    """The samples ``sl`` of a flight (its auxiliary channels with them)."""
    aux = flight.aux.slice(sl) if flight.aux is not None else None
    om = flight.omega_true[sl] if flight.omega_true is not None else None
    return replace(flight, t=flight.t[sl], raw=flight.raw[sl], valid=flight.valid[sl],
                   omega_true=om, aux=aux)


def split_flight(flight: Flight, fraction: float = 0.5) -> tuple[Flight, Flight]:
    """The flight cut at the sample that leaves ``fraction`` of its samples in the first part."""
    k = round(flight.t.shape[0] * fraction)
    return _part(flight, slice(0, k)), _part(flight, slice(k, None))


def inflight_calibration(flight: Flight) -> Calibration:
    """``rimu calibrate in-flight`` with its defaults."""
    from calibration.inflight import calibration_from_fit, fit_inflight

    return calibration_from_fit(fit_inflight(flight), flight)


def flying_mask(flight: Flight, cal: Calibration) -> np.ndarray:
    """(N,) True from the first to the last sample where the vehicle turns (docstring)."""
    s = cal.kind(flight.kind)
    w = np.nan_to_num(flight.raw[:, :3] * s.scale_factors[:3] - s.biases[:3])
    r = np.linalg.norm(w, axis=1)
    moving = r > np.median(r[: max(1, r.shape[0] // 20)]) + 0.1
    out = np.zeros(r.shape[0], bool)
    if moving.any():
        idx = np.flatnonzero(moving)
        out[idx[0]: idx[-1] + 1] = True
    return out


def envelope_codes(flight: Flight, cal: Calibration) -> tuple[np.ndarray, str]:
    """(N,) out-of-envelope codes (0 = inside) of a flight, and where they came from.

    ``replay``'s ``flight_envelope`` when it exists (issue 17), else the shock and
    saturation segments of the in-flight calibration (module docstring).
    """
    for mod in ("replay.envelope", "fdi.envelope"):
        try:
            fe = __import__(mod, fromlist=["flight_envelope"]).flight_envelope
        except (ImportError, AttributeError):
            continue
        return np.asarray(fe(flight, cal), dtype=np.int64), f"{mod}.flight_envelope"
    from calibration.inflight.segments import find_segments

    codes = np.zeros(flight.t.shape[0], np.int64)
    for g in find_segments(flight):
        bit = _SEGMENT_CODES.get(g.reason, 0)
        if bit:
            codes[(flight.t >= g.t0_s) & (flight.t <= g.t1_s)] |= bit
    return codes, "calibration.inflight.segments.find_segments (shock, saturation)"


# --------------------------------------------------------------------------- monitor
def run_monitor(flight: Flight, cal: Calibration, thresholds: Any,
                envelope: np.ndarray | None = None) -> Any:
    """``rimu monitor-file`` in the library: the monitoring chain
    (:func:`replay.chain.chain_for_flight`: time offsets, effect compensation, the operating
    envelope decided online from the moved samples, the monitor). ``envelope`` is not used:
    the chain decides it as the command does (kept for the callers' signature)."""
    from replay.chain import ChainOptions, chain_for_flight

    chain = chain_for_flight(flight, cal, ChainOptions(thresholds=thresholds, report=False))
    return chain.feed_whole(flight)


def _answer_envelope(result: Any, fallback: np.ndarray) -> np.ndarray:
    """The answer's own envelope codes when it carries them, else ``fallback``."""
    env = getattr(result, "envelope", None)
    return fallback if env is None else np.asarray(env, dtype=np.int64)


def _index(t: np.ndarray, te: float) -> int:
    return int(min(np.searchsorted(t, te - 1e-9), t.shape[0] - 1))


def _time_in_alarm(result: Any, keep: np.ndarray | None = None) -> float:
    with np.errstate(invalid="ignore"):
        over = np.any(result.statistics > result.thresholds, axis=1)
    if keep is not None:
        over = over[keep]
    return float(over.mean()) if over.size else math.nan


def rate_row(count: int, hours: float, target: float) -> dict[str, Any]:
    """Observed against expected alarms: Poisson (Garwood) 95 % interval, resolution."""
    from thresholds.evaluate import poisson_interval

    lo, hi = poisson_interval(count, hours)
    expected = target * hours
    return {"target_per_hour": target, "hours": hours, "expected": expected,
            "observed": int(count), "per_hour": count / hours if hours > 0 else math.nan,
            "ci95_per_hour": [lo, hi],
            "ratio_to_target": count / expected if expected > 0 else math.nan,
            "resolved": bool(expected >= RESOLVE_EXPECTED)}


def _count(result: Any, fallback_env: np.ndarray, fs: float, target: float,
           thresholds: Any) -> dict[str, Any]:
    env = _answer_envelope(result, fallback_env)
    inside = env == 0
    t = np.asarray(result.t, float)
    eps = alarm_episodes(result.events)
    out_env = [e for e in eps if inside[_index(t, e.t)]]
    row = rate_row(len(out_env), float(inside.sum()) / fs / 3600.0, target)
    row.update({
        "episodes_in_envelope": len(eps) - len(out_env),
        "episode_times_s": [float(e.t) for e in out_env],
        "excluded": sorted({e.sensor for e in result.events
                            if e.type in EXCLUDING_EVENTS and e.sensor is not None}),
        "isolations_claimed": sum(e.type == "isolated" for e in result.events),
        "time_in_alarm": _time_in_alarm(result, inside),
        "time_in_alarm_implied": float(np.sum(thresholds.alpha)),
        "envelope_fraction": float(1.0 - inside.mean()) if inside.size else math.nan})
    return row


def _accepted(targets: Sequence[float], fs: float
              ) -> tuple[list[float], list[dict[str, Any]]]:
    """The targets ``rimu tune`` accepts at ``fs``, and the refused ones with the reason
    (alarms that would merge: :func:`thresholds.tune.max_false_alarms_per_hour`)."""
    from thresholds.tune import max_false_alarms_per_hour

    top = max_false_alarms_per_hour(fs)
    ok = [float(R) for R in targets if R <= top]
    refused = [{"target_per_hour": float(R), "max_per_hour": top,
                "reason": f"refused by rimu tune: at {fs:.3g} Hz one alarm's shortest "
                          f"episode would take more than a tenth of the mean time between "
                          f"alarms above {top:.3g}/h"} for R in targets if R > top]
    return ok, refused


def _tune(cal: Calibration, target: float, kind: str = "gyro") -> Any:
    from thresholds.tune import tune

    return tune(cal, false_alarms_per_hour=target, kind=kind)


# --------------------------------------------------------------------------- held out
def holdout_flight(flight: Flight, targets: Sequence[float] = TARGETS_PER_HOUR, *,
                   progress: Callable[[], None] | None = None) -> dict[str, Any]:
    """Calibrate and tune on one half, count alarm episodes on the other, both ways round."""
    first, second = split_flight(flight)
    rows, env_src = [], ""
    targets, refused = _accepted(targets, flight.sample_rate_hz)
    for name, fit_part, test_part in (("tune first half, count second", first, second),
                                      ("tune second half, count first", second, first)):
        cal = inflight_calibration(fit_part)
        codes, env_src = envelope_codes(test_part, cal)
        for R in targets:
            thr = _tune(cal, R).thresholds
            res = run_monitor(test_part, cal, thr, codes)
            row = _count(res, codes, flight.sample_rate_hz, R, thr)
            row["direction"] = name
            rows.append(row)
            if progress:
                progress()
    return {"rows": rows, "envelope_source": env_src, "refused": refused,
            "split_at_s": float(second.t[0]), "samples": int(flight.t.shape[0])}


def _static_rows(cal: Calibration, targets: Sequence[float], direction: str, fs: float,
                 n: int, progress: Callable[[], None] | None,
                 monitor: Callable[[Calibration, Any], Any]) -> list[dict[str, Any]]:
    """One held-out row per target: thresholds tuned on ``cal``, ``monitor(cal, thr)`` over
    the other part (``n`` samples), alarms counted with the detectable size and variance
    factors beside."""
    rows = []
    for R in targets:
        tu = _tune(cal, R)
        thr = tu.thresholds
        row = _count(monitor(cal, thr), np.zeros(n, np.int64), fs, R, thr)
        row["direction"] = direction
        row["detectable_dps"] = float(min(d.size_unit_value for d in tu.detectable))
        row["variance_factor"] = list(thr.variance_factor)
        rows.append(row)
        if progress:
            progress()
    return rows


def holdout_static(t: np.ndarray, y: np.ndarray, names: tuple[str, ...],
                   targets: Sequence[float] = TARGETS_PER_HOUR, *,
                   progress: Callable[[], None] | None = None, tails: bool = True,
                   drift: bool = True) -> dict[str, Any]:
    """The static set: static calibration (:func:`studies.realnoise.static_calibration`,
    with the MPU9250's datasheet tolerances for what rest cannot observe, the bias
    uncertainty of a later stretch, the residual's tail model and its parity drift model)
    of one half, thresholds tuned on it (the drift over the default horizon, the half's
    own length), the monitor (isolation on) over the other half. ``tails`` and ``drift``
    False: the calibration before ``docs/drift.md`` (for the comparison there)."""
    from fdi.monitor import Monitor
    from studies.realnoise import (
        MPU9250_CROSS_AXIS,
        MPU9250_SCALE_FACTOR_TOLERANCE,
        static_calibration,
    )

    def calibrate(part: np.ndarray) -> Calibration:
        """At rest: scale factors and axes stated by the datasheet's tolerances, the bias
        uncertainty of a later stretch (drift included), the residual's tail model and
        the drift model of its parity (``tune`` then covers the drift over a horizon of
        the part's length: the other half)."""
        return static_calibration(part, fs, names, drift_bias_sd=True, bias_prediction=True,
                                  scale_factor_tolerance=MPU9250_SCALE_FACTOR_TOLERANCE,
                                  cross_axis=MPU9250_CROSS_AXIS, tails=tails, drift=drift)

    t = np.asarray(t, float) - float(t[0])
    fs = (t.size - 1) / float(t[-1] - t[0])
    k = t.size // 2
    rows = []
    for name, a, b in (("tune first half, count second", slice(0, k), slice(k, None)),
                       ("tune second half, count first", slice(k, None), slice(0, k))):
        cal = calibrate(y[a])
        rows += _static_rows(cal, targets, name, fs, t[b].size, progress,
                             lambda c, thr, b=b: Monitor(c, thr).run(t[b], y[b]))
    cal = calibrate(y)
    thr = _tune(cal, 1.0).thresholds
    res = Monitor(cal, thr).run(t, y)
    whole = _count(res, np.zeros(t.size, np.int64), fs, 1.0, thr)
    return {"rows": rows, "whole_record_1_per_hour": whole, "sample_rate_hz": fs,
            "samples": int(t.size), "duration_s": float(t[-1] - t[0]),
            "envelope_source": "none (static bench recording)"}


def load_static_set(folder: str | Path) -> Flight:
    """The 4×MPU9250 recording as ``rimu ingest imu1_raw.mat … imu4_raw.mat`` makes it (gyro
    and accelerometer triads of each IMU, one time base; no folder written)."""
    from replay.ingest import align_streams, read_any
    from replay.ingest.readers import merge_reads

    folder = Path(folder)
    read = merge_reads([read_any(folder / f"imu{k}_raw.mat", "auto", salvage=False)
                        for k in range(1, 5)])
    flight, _ = align_streams(read)
    return flight


def holdout_static_set(flight: Flight, targets: Sequence[float] = TARGETS_PER_HOUR, *,
                       progress: Callable[[], None] | None = None) -> dict[str, Any]:
    """The static set through the product's chain: ``rimu calibrate static`` of one half
    (:func:`calibration.inflight.static.calibrate_static`: alignment from gravity and the
    shared motion, the residual's tail and parity drift models, the range its samples
    covered), thresholds tuned on it, ``rimu monitor-file`` (:func:`run_monitor`: the
    envelope decided online, isolation on) over the other half, both ways round; then the
    whole record calibrated on itself at 1/h."""
    from calibration.inflight.static import calibrate_static

    first, second = split_flight(flight)
    fs = flight.sample_rate_hz
    rows = []
    targets, refused = _accepted(targets, fs)
    for name, fit_part, test_part in (("tune first half, count second", first, second),
                                      ("tune second half, count first", second, first)):
        cal = calibrate_static(fit_part)
        rows += _static_rows(cal, targets, name, fs, test_part.t.size, progress,
                             lambda c, thr, p=test_part: run_monitor(p, c, thr))
    cal = calibrate_static(flight)
    thr = _tune(cal, 1.0).thresholds
    res = run_monitor(flight, cal, thr)
    whole = _count(res, np.zeros(flight.t.size, np.int64), fs, 1.0, thr)
    return {"rows": rows, "whole_record_1_per_hour": whole, "sample_rate_hz": fs,
            "refused": refused,
            "samples": int(flight.t.size), "duration_s": float(flight.t[-1] - flight.t[0]),
            "calibration": "rimu calibrate static (calibration.inflight.static)",
            "envelope_source": "the monitoring chain (replay.chain), online"}


# --------------------------------------------------------------------------- from start
def _pl_median_dps(result: Any) -> float | None:
    pl = np.asarray(result.protection_level, float)
    pl = pl[np.isfinite(pl)]
    return float(np.median(pl) / DPS) if pl.size else None


def from_start(flight: Flight, cal: Calibration, thresholds: Any, label: str
               ) -> dict[str, Any]:
    """One run from the first sample: events, exclusions, time in alarm, protection level."""
    codes, src = envelope_codes(flight, cal)
    res = run_monitor(flight, cal, thresholds, codes)
    env = _answer_envelope(res, codes)
    fly = flying_mask(flight, cal)
    fs = flight.sample_rate_hz
    exposure_h = float((env == 0).sum()) / fs / 3600.0
    eps = alarm_episodes(res.events)
    t = np.asarray(res.t, float)
    unv = getattr(res, "unverified", None)
    return {
        "thresholds": label, "false_alarms_per_hour": thresholds.false_alarms_per_hour,
        "samples": int(t.size), "data_s": t.size / fs,
        "events": len(res.events),
        "event_list": [e.to_dict() | ({"sensors": list(e.sensors)}
                                      if getattr(e, "sensors", None) else {})
                       for e in res.events],
        "episodes": len(eps),
        "episodes_outside_envelope": int(sum(env[_index(t, e.t)] == 0 for e in eps)),
        "exposure_outside_envelope_h": exposure_h,
        "excluded": sorted({e.sensor for e in res.events
                            if e.type in EXCLUDING_EVENTS and e.sensor is not None}),
        "isolations_claimed": sum(e.type == "isolated" for e in res.events),
        "disagree_events": sum(e.type == "disagree" for e in res.events),
        "time_in_alarm": _time_in_alarm(res),
        "protection_level_median_dps": _pl_median_dps(res),
        "flying_s": float(fly.sum()) / fs,
        "envelope_s_in_flight": float(((env != 0) & fly).sum()) / fs,
        "envelope_fraction_of_flying": (float(((env != 0) & fly).sum() / fly.sum())
                                        if fly.any() else math.nan),
        "envelope_reasons": _reasons(env),
        "envelope_source": src if getattr(res, "envelope", None) is None
        else "the monitor's answer (BlockResult.envelope)",
        "unverified_available": unv is not None,
        "series": {"t": t, "ratio": _ratio(res), "envelope": env,
                   "episodes": [float(e.t) for e in eps]},
    }


def _reasons(env: np.ndarray) -> dict[str, int]:
    """Samples per envelope reason (:func:`fdi.envelope.reason_names`)."""
    from fdi.envelope import reason_names

    out: dict[str, int] = {}
    for c in np.unique(env[env != 0]):
        for r in reason_names(int(c)):
            out[r] = out.get(r, 0) + int((env == c).sum())
    return out


def _ratio(res: Any) -> np.ndarray:
    """Largest statistic/threshold over the scales per sample (NaN while windows fill)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.asarray(res.statistics, float) / np.asarray(res.thresholds, float)
        r = np.where(np.isfinite(r), r, -np.inf).max(axis=1)
    return np.where(np.isfinite(r), r, np.nan)


# --------------------------------------------------------------------------- injection
def calm_onsets(flight: Flight, cal: Calibration, env: np.ndarray, *, count: int = 3,
                length_s: float = FAULT_S, lead_s: float = LOCAL_START_S) -> list[float]:
    """Onsets of calm stretches in flight: from ``lead_s`` before the onset to ``length_s``
    after it in flight, inside the envelope and without a gap; the ``count`` stretches with
    the least specific-force variation, ``length_s`` apart.

    Chosen from the data only (never from the monitor's output).
    """
    t, fs = flight.t, flight.sample_rate_hz
    fly = flying_mask(flight, cal)
    acc = flight.aux.select("accel") if flight.aux is not None else None
    if acc is not None and acc.m >= 3:
        mag = np.linalg.norm(np.nan_to_num(acc.values[:, :3]), axis=1)
    else:
        mag = np.linalg.norm(np.nan_to_num(flight.raw[:, :3]), axis=1)
    cands: list[tuple[float, float]] = []
    gap = np.concatenate([[False], np.diff(t) > 2.0 / fs])
    for k in range(0, t.size, int(fs)):
        t0 = t[k]
        if t0 - t[0] < lead_s:
            continue
        w = (t >= t0 - lead_s) & (t < t0 + length_s)
        if t0 + length_s > t[-1] or not fly[w].all() or env[w].any() or gap[w][1:].any():
            continue
        cands.append((float(np.std(mag[w])), float(t0)))
    out: list[float] = []
    for _, t0 in sorted(cands):
        if all(abs(t0 - o) >= length_s for o in out):
            out.append(t0)
        if len(out) == count:
            break
    return sorted(out)


def _faults(n: int, onset: float) -> list[tuple[str, float, Fault]]:
    out = []
    for i in range(1, n + 1):
        for b in STEPS_DPS:
            out.append((f"step {b:g} deg/s", b, Fault("step", i, b * DPS, onset, FAULT_S,
                                                      f"step:{i}:{b:g}dps:{onset:g}")))
        out.append((f"ramp {RAMP_DPS_PER_S:g} deg/s/s", RAMP_DPS_PER_S,
                    Fault("ramp", i, RAMP_DPS_PER_S * DPS, onset, FAULT_S,
                          f"ramp:{i}:{RAMP_DPS_PER_S:g}dps/s:{onset:g}")))
    return out


def inject_flight(flight: Flight, cal: Calibration, thresholds: Any, detectable: Sequence[Any],
                  *, onsets: Sequence[float] | None = None, start_before_s: float | None = None,
                  progress: Callable[[], None] | None = None) -> dict[str, Any]:
    """Steps of 2, 5, 10 °/s and a 0.5 °/s/s ramp on every sensor at calm onsets; one row
    per injected fault.

    Each run starts at the first sample of the flight, or with ``start_before_s`` that long
    before the onset (a monitor started in the calm stretch: its isolation logic without
    what happened earlier in the flight). The same stretch is monitored without the fault;
    its alarms are false alarms and do not count as detections.
    """
    from replay.scenario import apply_faults

    codes, src = envelope_codes(flight, cal)
    if onsets is None:
        onsets = calm_onsets(flight, cal, codes)
    s = cal.kind(flight.kind)
    groups = flight.imu
    det_dps = float(min(d.size_unit_value for d in detectable))
    rows = []
    for onset in onsets:
        k0 = 0 if start_before_s is None else int(np.searchsorted(flight.t,
                                                                  onset - start_before_s))
        clean = run_monitor(_part(flight, slice(k0, None)), cal, thresholds, codes[k0:])
        known = {(e.t, e.type, e.sensor) for e in clean.events}
        for label, size, f in _faults(flight.n, onset):
            raw, valid = apply_faults(flight.t, flight.raw, flight.valid, [f], cal,
                                      kind=flight.kind)
            run = _part(replace(flight, raw=raw, valid=valid), slice(k0, None))
            res = run_monitor(run, cal, thresholds, codes[k0:])
            rows.append(_outcome(res, f, label, size, det_dps, s.H, groups, known))
            if progress:
                progress()
    return {"rows": rows, "onsets_s": list(onsets), "detectable_dps": det_dps,
            "detectable_by_scale": [{"scale": d.scale, "window_s": d.window_s,
                                     "size_dps": d.size_unit_value} for d in detectable],
            "envelope_source": src,
            "start": "first sample of the log" if start_before_s is None
            else f"{start_before_s:g} s before the onset"}


def _outcome(res: Any, f: Fault, label: str, size: float, det_dps: float, H: np.ndarray,
             groups: tuple[str, ...], known: set[tuple[float, str, int | None]]
             ) -> dict[str, Any]:
    """One faulted run against the clean run of the same stretch: an alarm the clean run
    also raised (same sample, type and sensor: a false alarm) does not count as detection."""
    t = np.asarray(res.t, float)
    i = f.sensor
    window = [e for e in res.events if e.type in ALARM_EVENTS
              and f.onset - 1e-9 <= e.t < f.onset + FAULT_S]
    after = [e for e in window if (e.t, e.type, e.sensor) not in known]
    first = after[0] if after else None
    excl = [e for e in res.events if e.type in EXCLUDING_EVENTS and e.sensor is not None]
    wrong = sorted({e.sensor for e in excl if e.sensor != i})
    wrong_after = sorted({e.sensor for e in excl if e.sensor != i and e.t >= f.onset - 1e-9})
    first_iso = next((e for e in excl if e.t >= f.onset - 1e-9), None)
    g = groups[i - 1] if groups else ""
    unv = getattr(res, "unverified", None)
    unverified = None
    if unv is not None and first is not None:
        axis = int(np.argmax(np.abs(H[i - 1])))
        k0, k1 = _index(t, first.t), _index(t, f.onset + FAULT_S)
        unverified = bool(np.asarray(unv)[k0:k1, axis].all())
    # the size the fault has reached by the end of its window (a ramp grows)
    reached = size if f.kind == "step" else size * FAULT_S
    return {"fault": label, "kind": f.kind, "size_dps": size, "sensor": i, "imu": g,
            "onset_s": f.onset, "reaches_dps": reached,
            "at_or_above_detectable": bool(reached >= det_dps),
            "detected": first is not None,
            "delay_s": None if first is None else float(first.t - f.onset),
            "first_event": None if first is None else first.type,
            "false_alarm_in_window": len(window) > len(after),
            "wrong_exclusions": wrong, "wrong_exclusions_after_onset": wrong_after,
            "first_exclusion": None if first_iso is None else first_iso.sensor,
            "first_exclusion_healthy": first_iso is not None and first_iso.sensor != i,
            "first_exclusion_other_imu": (first_iso is not None and bool(groups)
                                          and groups[first_iso.sensor - 1] != g),
            "isolations_claimed": sum(e.type == "isolated" for e in res.events),
            "disagree": any(e.type == "disagree" and e.t >= f.onset - 1e-9
                            for e in res.events),
            "unverified_from_first_alarm": unverified}


# --------------------------------------------------------------------------- all
def field_results(data: str | Path, *, targets: Sequence[float] = TARGETS_PER_HOUR,
                  progress: bool = True) -> dict[str, Any]:
    """Everything of ``docs/field-results.md`` from ``data`` (the shared data folder).

    Returns a JSON-ready dictionary (``"schema": "rimu.field-results/1"``) with per-flight
    series for the plots under ``"_series"`` (arrays, dropped when written) and the time
    each piece took under ``"timing_s"``.
    """
    from tqdm.auto import tqdm

    from replay.threshold_choice import select

    data = Path(data)
    out: dict[str, Any] = {"schema": FIELD_SCHEMA, "targets_per_hour": list(targets),
                           "flights": {}, "timing_s": {}, "_series": {}}
    n_inj = 2 * 2 * 6 * 4 * 3          # flights, starts, sensors, faults, onsets
    bar = tqdm(total=2 * 2 * len(targets) + n_inj + 2 * len(targets), disable=not progress,
               desc="field results", unit="run")
    tick = bar.update
    for name, fname in FLIGHTS.items():
        rec: dict[str, Any] = {}
        t0 = time.perf_counter()
        flight = load_erle(data / "erle_pxf_dual_imu" / fname)
        cal = inflight_calibration(flight)
        rec["samples"] = int(flight.t.shape[0])
        rec["data_s"] = flight.duration_s
        t1 = time.perf_counter()
        rec["holdout"] = holdout_flight(flight, targets, progress=tick)
        t2 = time.perf_counter()
        tu = _tune(cal, 1.0)
        default = select(cal, kind=flight.kind).thresholds
        runs = [from_start(flight, cal, default, "default (monitor-file, 1e-3/h)"),
                from_start(flight, cal, tu.thresholds, "rimu tune 1/h")]
        out["_series"][name] = runs[1].pop("series")
        runs[0].pop("series")
        rec["from_start"] = runs
        t3 = time.perf_counter()
        rec["injection"] = inject_flight(flight, cal, tu.thresholds, tu.detectable,
                                         progress=tick)
        rec["injection_local"] = inject_flight(flight, cal, tu.thresholds, tu.detectable,
                                               start_before_s=LOCAL_START_S, progress=tick)
        t4 = time.perf_counter()
        out["timing_s"][f"flight {name}"] = {"load_and_calibrate": t1 - t0,
                                            "holdout": t2 - t1, "from_start": t3 - t2,
                                            "injection": t4 - t3}
        out["flights"][name] = rec
    t0 = time.perf_counter()
    mpu = data / "multi_imu_4x_mpu9250"
    out["static_4x_mpu9250"] = holdout_static_set(load_static_set(mpu), targets,
                                                  progress=tick)
    out["timing_s"]["4x mpu9250"] = time.perf_counter() - t0
    bar.close()
    from studies.field_claims import summarise

    out["summary"] = summarise(out)
    return out
