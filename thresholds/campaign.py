"""One simulated run of an evaluation campaign: a flight, the monitor, what it found.

A run is fully described by a :class:`RunSpec` (seed, fault kind, size, sensor, onset);
:func:`run_one` is a pure function of the calibration, the thresholds and the spec, so a
campaign gives the same numbers run by run whether it runs serially or on a Dask cluster.

What a run records (:class:`RunResult`):

- the *first alarm* of the full healthy set (any monitor event: detected, isolated,
  health). Before the onset it is a false alarm, and the time until it (or until the onset)
  is the run's *exposure*: the false-alarm rate of the full set is
  ``false alarms / exposure`` (the maximum-likelihood rate of a Poisson process observed
  until its first event; later alarms would be those of a reduced set);
- the first event at or after the onset (detection and delay), and the first sensor the
  monitor excludes after the onset (isolation);
- the first passage of ``max_k D_k/T_k`` above ``c`` for the threshold multipliers ``c ≤ 1``
  of the ROC (:data:`ROC_MULTIPLIERS`): every trace before the first event is the
  unaltered full-set trace, and a passage of ``c ≤ 1`` cannot come after that event;
- for *sweep* runs (steps at rest, isolation off) whether each scale's statistic exceeds
  its threshold at the first sample whose window lies wholly in the fault: the
  single-window detection probability that ``rimu tune`` predicts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from fdi.monitor import Monitor
from fdi.settings import MonitorSettings, Thresholds
from replay.faults import Fault
from replay.flight_sim import simulate_flight

__all__ = ["ROC_MULTIPLIERS", "RunResult", "RunSpec", "corpus_one", "run_one"]

ROC_MULTIPLIERS = (1.0, 0.95, 0.9, 0.85, 0.8, 0.75, 0.7, 0.65, 0.6)
"""Threshold multipliers of the ROC (1: the operating point; lower: more sensitive)."""

_NO_ISOLATION = MonitorSettings(persistence=1 << 30)


@dataclass(frozen=True)
class RunSpec:
    """One simulated flight.

    Attributes
    ----------
    index : int
        Run number in the campaign (results are ordered by it).
    seed : int
        Seed of the flight (true model, noise, motion).
    fault : str
        ``"healthy"``, a fault kind of :mod:`replay.faults`, or ``"sweep"`` (a step at
        rest with isolation off, for the detectable sizes).
    size : float
        Fault size in SI (see :class:`replay.faults.Fault`); 0 where unused.
    size_label : float
        The size in the unit of the sweep (σ for step/spike/sweep, σ/s for ramp,
        multiplier for noise, fraction for scale).
    sensor : int
        1-based faulty sensor (0 for healthy runs).
    onset_s, duration_s : float
    max_rate_dps : float
        Largest body rate of the manoeuvres.
    """

    index: int
    seed: int
    fault: str
    size: float
    size_label: float
    sensor: int
    onset_s: float
    duration_s: float
    max_rate_dps: float = 300.0


@dataclass(frozen=True)
class RunResult:
    """What one run found (times in s from the flight start).

    Attributes
    ----------
    spec : RunSpec
    exposure_s : float
        Healthy-set time observed for false alarms (until the first alarm or the onset).
    false_alarm : bool
        The first alarm came before the onset.
    detected : bool
        An event at or after the onset.
    delay_s : float
        Its delay (NaN if none).
    isolated : int
        First sensor excluded at or after the onset (1-based; 0: none).
    roc_first : tuple of float
        Per ROC multiplier, the time of the first passage (inf: none).
    window_hit : tuple of float
        Sweep runs: per scale, 1.0 if the first wholly-faulty window exceeded its
        threshold, 0.0 if not, NaN if it was not evaluated.
    roc_detect : tuple of float
        Per ROC multiplier, the time of the first passage at or after the onset (inf:
        none), whatever passed before it: the ROC's detection.
    baselines : tuple of replay.baselines.compare.BaselineRun
        The autopilot rules asked for (``rimu evaluate --baseline``) on the same samples.
    isolated_imu : int
        The IMU (0-based) of :attr:`isolated` when the set is made of IMUs and baselines
        were asked for (−1: none or unknown): rimu's isolation read as the baselines'.
    faulted_imu : int
        The IMU (0-based) of the faulted sensor, when baselines were asked for (−1: none).
    """

    spec: RunSpec
    exposure_s: float
    false_alarm: bool
    detected: bool
    delay_s: float
    isolated: int
    roc_first: tuple[float, ...]
    window_hit: tuple[float, ...] = ()
    roc_detect: tuple[float, ...] = ()
    baselines: tuple[Any, ...] = ()
    isolated_imu: int = -1
    faulted_imu: int = -1


def _fault(spec: RunSpec) -> tuple[Fault, ...]:
    if spec.fault == "healthy":
        return ()
    kind = "step" if spec.fault == "sweep" else spec.fault
    return (Fault(kind, spec.sensor, spec.size, spec.onset_s, None,
                  f"{kind}:{spec.sensor}:{spec.size_label:g}:{spec.onset_s:g}"),)


def _with_baselines(base: RunResult, flight: Any, cal: Calibration, spec: RunSpec,
                    onset_s: float, baselines: tuple[str, ...]) -> RunResult:
    """``base`` with the autopilot rules' answers on the same samples."""
    from dataclasses import replace

    from replay.baselines.compare import baseline_run, run_baselines

    tri, res = run_baselines(flight, baselines, cal)
    sensor = spec.sensor if spec.fault != "healthy" else 0
    runs = tuple(baseline_run(r, tri, onset_s=onset_s, duration_s=float(spec.duration_s),
                              sensor=sensor) for r in res.values())
    imu = tri.imu_of_sensor(base.isolated) if base.isolated else -1
    return replace(base, baselines=runs, isolated_imu=imu,
                   faulted_imu=tri.imu_of_sensor(sensor) if sensor else -1)


def run_one(cal: Calibration, thresholds: Thresholds, spec: RunSpec, *,
            kind: str = "gyro", baselines: tuple[str, ...] = ()) -> RunResult:
    """Simulate one flight, run the monitor on it, and summarise (deterministic);
    ``baselines``: autopilot rules (:data:`replay.baselines.BASELINES`) run on the same
    samples (not on sweep runs)."""
    flight = simulate_flight(cal, spec.duration_s, seed=spec.seed, faults=_fault(spec),
                             max_rate_dps=spec.max_rate_dps, kind=kind)
    sweep = spec.fault == "sweep"
    mon = Monitor(cal, thresholds, kind=kind, settings=_NO_ISOLATION if sweep else None)
    res = mon.run(flight.t, flight.raw, flight.valid)
    base = _summary(spec, res, float(spec.duration_s))
    if not sweep:
        if baselines:
            onset = spec.onset_s if spec.fault != "healthy" else math.inf
            base = _with_baselines(base, flight, cal, spec, onset, baselines)
        return base
    t = res.t
    hits: tuple[float, ...] = ()
    if sweep:
        k0 = math.ceil(spec.onset_s * flight.sample_rate_hz - 1e-9)
        h = []
        for k, w in enumerate(thresholds.scales):
            row = k0 + int(w) - 1
            if row >= t.shape[0] or not math.isfinite(res.statistics[row, k]):
                h.append(math.nan)
            else:
                h.append(float(res.statistics[row, k] > res.thresholds[row, k]))
        hits = tuple(h)
    return RunResult(spec, base.exposure_s, base.false_alarm, base.detected, base.delay_s,
                     base.isolated, base.roc_first, hits, base.roc_detect)


def _summary(spec: RunSpec, res: Any, duration_s: float) -> RunResult:
    """First alarm, exposure, detection, isolation and ROC passages of one monitor run."""
    onset = spec.onset_s if spec.fault != "healthy" else math.inf
    t = res.t
    first = res.events[0].t if res.events else math.inf
    false_alarm = first < onset - 1e-12
    exposure = min(first, onset, duration_s)
    after = [e for e in res.events if e.t >= onset - 1e-12]
    detected = bool(after)
    delay = after[0].t - onset if after else math.nan
    isolated = 0
    for e in after:
        if e.type in ("isolated", "health") and e.sensor is not None:
            isolated = int(e.sensor)
            break
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = res.statistics / res.thresholds
    ratio = np.where(np.isnan(ratio), -np.inf, ratio)
    r = ratio.max(axis=1) if ratio.shape[1] else np.full(t.shape, -np.inf)
    roc, roc_det = [], []
    later = t >= onset - 1e-12
    for c in ROC_MULTIPLIERS:
        idx = np.flatnonzero(r > c)
        roc.append(float(t[idx[0]]) if idx.size else math.inf)
        idx = np.flatnonzero((r > c) & later)
        roc_det.append(float(t[idx[0]]) if idx.size else math.inf)
    return RunResult(spec, float(exposure), bool(false_alarm), detected, float(delay),
                     isolated, tuple(roc), roc_detect=tuple(roc_det))


def corpus_one(cal: Calibration, thresholds: Thresholds, index: int, path: str, *,
               kind: str = "gyro", baselines: tuple[str, ...] = ()) -> RunResult:
    """One recorded flight folder (``rimu.flight/1``) through the monitor.

    The flight's truth record, when it has one, gives the fault (the first of its faults):
    alarms before its onset are false alarms. Without truth the flight counts as healthy.
    Never raises for a bad folder: the error is kept in ``RunSpec.fault`` as
    ``"error: ..."`` and the run contributes no exposure.
    """
    from fdi.errors import RimuError
    from replay.flight import load_flight_dir

    try:
        flight = load_flight_dir(path)
    except RimuError as exc:
        spec = RunSpec(index, 0, f"error: {exc}", 0.0, 0.0, 0, math.inf, 0.0, 0.0)
        return RunResult(spec, 0.0, False, False, math.nan, 0, tuple(
            math.inf for _ in ROC_MULTIPLIERS))
    f0 = flight.faults[0] if flight.faults else None
    dur = float(flight.t[-1] - flight.t[0]) if flight.t.size else 0.0
    t0 = float(flight.t[0]) if flight.t.size else 0.0
    spec = RunSpec(index, 0, f0.kind if f0 else "healthy", f0.size if f0 else 0.0,
                   f0.size if f0 else 0.0, f0.sensor if f0 else 0,
                   (f0.onset - t0) if f0 else math.inf, dur, math.nan)
    mon = Monitor(cal, thresholds, kind=kind)
    res = mon.run(flight.t - t0, flight.raw, flight.valid)
    base = _summary(spec, res, dur)
    if baselines:
        from dataclasses import replace

        shifted = replace(flight, t=flight.t - t0)
        base = _with_baselines(base, shifted, cal, spec, spec.onset_s, baselines)
    return base
