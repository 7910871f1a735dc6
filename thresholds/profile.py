"""Detectable sizes for a flight's own profile, not at rest (``rimu tune --flight DIR``).

:func:`thresholds.tune.detectable_sizes` states the smallest step one full window detects
at rest. In flight the monitor raises every threshold with the calibration uncertainty at
the current rate and the timing jitter at the current angular acceleration (ρ,
:mod:`fdi.kernel`: ``T_w·(1 + w·β/f_w + κ/f_w·Σρ)``), so on erle flight 41 the thresholds
run a median 23× (p90 67×) above their floor at the longest window and a step of 1.4× the
at-rest size goes undetected for 17 s.

:func:`flight_detectable` runs the monitor chain of ``rimu monitor-file`` over a flight
(healthy as recorded: its thresholds are what they would be), reads per sample and scale
the threshold the monitor used, and solves for the step detected with 99 % probability
against it (:func:`thresholds.tune.detectable_at`, the same arithmetic as at rest, over
the same draws of the bias error). Per sample the detectable size is the best scale's;
its distribution over the samples inside the envelope (median, p90, max) is the flight's
profile. The sizes are solved on a log grid of threshold ratios per scale and
interpolated (monotone in the threshold).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from fdi.detector import chi2_threshold
from fdi.settings import Thresholds
from fdi.units import DPS

__all__ = ["GRID_POINTS", "FlightDetectable", "flight_detectable", "profile_lines"]

GRID_POINTS = 16
"""Threshold ratios solved per scale (log-spaced from the floor to the flight's largest)."""
_DRAWS = 1000


@dataclass(frozen=True)
class FlightDetectable:
    """Detectable sizes (99 %) over a flight, worst sensor.

    Attributes
    ----------
    source : str
    samples : int
        Samples inside the envelope with every window full.
    unit : str
    at_rest : tuple of float
        Per scale, at rest (the threshold's floor), in ``unit``.
    median, p90, max : tuple of float
        Per scale over the samples, in ``unit``.
    best_median, best_p90, best_max : float
        The best scale's size per sample, over the samples.
    ratio_median, ratio_p90 : tuple of float
        Per scale, the threshold over its floor.
    scales : tuple of int
    """

    source: str
    samples: int
    unit: str
    scales: tuple[int, ...]
    at_rest: tuple[float, ...]
    median: tuple[float, ...]
    p90: tuple[float, ...]
    max: tuple[float, ...]
    best_median: float
    best_p90: float
    best_max: float
    ratio_median: tuple[float, ...]
    ratio_p90: tuple[float, ...]
    notes: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


def flight_detectable(cal: Calibration, thresholds: Thresholds, flight: Any, *,
                      kind: str = "gyro") -> FlightDetectable:
    """The flight's profile of detectable sizes (module docstring).

    Parameters
    ----------
    cal : Calibration
    thresholds : Thresholds
    flight : replay.flight_data.Flight
        Monitored through :func:`replay.chain.chain_for_flight` with its defaults.
    kind : str

    Raises
    ------
    ConfigError
        A set without redundancy, or no sample inside the envelope with full windows.
    """
    from fdi.errors import ConfigError
    from replay.chain import ChainOptions, chain_for_flight
    from thresholds.tune import _parity_geometry, detectable_at

    s = cal.kind(kind)
    if s.n < 4:
        raise ConfigError(f"{s.n} {kind} sensors: no parity space, no detectable size")
    ch = chain_for_flight(flight, cal, ChainOptions(thresholds=thresholds, report=False))
    res = ch.feed_whole(flight)
    df, u2, beta, U, G = _parity_geometry(cal, kind)
    i = int(np.argmin(u2))
    g = np.random.default_rng(12345).multivariate_normal(np.zeros(df), G, size=_DRAWS,
                                                         method="eigh")
    conv = DPS if kind == "gyro" else 1.0
    Tm = np.asarray(res.thresholds, float)[:, : len(thresholds.scales)]
    env = getattr(res, "envelope", None)
    inside = np.ones(Tm.shape[0], bool) if env is None else np.asarray(env) == 0
    keep = inside & np.all(np.isfinite(Tm), axis=1)
    healthy = np.asarray(res.healthy, bool)
    keep &= healthy.all(axis=1)
    if not keep.any():
        raise ConfigError(f"{flight.source}: no sample inside the envelope with every window "
                          f"full: no detectable-size profile")
    sizes, rest, ratios = [], [], []
    for k, (w, a, f) in enumerate(zip(thresholds.scales, thresholds.alpha,
                                      thresholds.variance_factor, strict=True)):
        floor = chi2_threshold(a, df) * (1.0 + w * beta / f)
        r = np.maximum(Tm[keep, k] / floor, 1.0)
        grid = np.geomspace(1.0, max(float(r.max()), 1.0 + 1e-9), GRID_POINTS)
        b = np.array([detectable_at(floor * q, int(w), f, df, U[:, i], g, float(u2[i]))
                      for q in grid])
        sizes.append(np.exp(np.interp(np.log(r), np.log(grid), np.log(b))) / conv)
        rest.append(float(b[0]) / conv)
        ratios.append(r)
    S = np.stack(sizes, axis=1)
    best = S.min(axis=1)
    q = lambda a, p: float(np.percentile(a, p))  # noqa: E731
    return FlightDetectable(
        source=str(flight.source), samples=int(keep.sum()),
        unit="deg/s" if kind == "gyro" else "m/s^2", scales=tuple(thresholds.scales),
        at_rest=tuple(rest), median=tuple(q(c, 50) for c in S.T),
        p90=tuple(q(c, 90) for c in S.T), max=tuple(float(c.max()) for c in S.T),
        best_median=q(best, 50), best_p90=q(best, 90), best_max=float(best.max()),
        ratio_median=tuple(q(r, 50) for r in ratios), ratio_p90=tuple(q(r, 90) for r in ratios),
        notes={"worst_sensor": i + 1, "probability": 0.99,
               "turn_on": ch.turn_on.method if ch.turn_on is not None else None,
               "samples_total": int(Tm.shape[0]),
               "rule": "per sample, per scale: the step one full window detects with 99 % "
                       "against the threshold the monitor used there; the best scale's"})


def profile_lines(p: FlightDetectable) -> list[str]:
    """Lines for ``rimu tune --flight``."""
    out = [f"detectable sizes over {p.source} ({p.samples} samples inside the envelope, "
           f"worst sensor {p.notes['worst_sensor']}, 99 %):",
           f"{'scale':>6} {'at rest':>9} {'median':>9} {'p90':>9} {'max':>9} "
           f"{'thr/floor med':>13} {'p90':>7}"]
    for w, r0, m, p9, mx, rm, r9 in zip(p.scales, p.at_rest, p.median, p.p90, p.max,
                                        p.ratio_median, p.ratio_p90, strict=True):
        out.append(f"{w:6d} {r0:9.3g} {m:9.3g} {p9:9.3g} {mx:9.3g} {rm:13.3g} {r9:7.3g}")
    out.append(f"best window per sample: median {p.best_median:.3g} {p.unit}, p90 "
               f"{p.best_p90:.3g}, max {p.best_max:.3g} (at rest: {min(p.at_rest):.3g})")
    if not math.isfinite(p.best_max):
        out.append("some samples detect nothing (an infinite threshold)")
    return out

