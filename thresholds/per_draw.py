"""False-alarm rates per drawn calibration error: the rate of *your* calibration.

A user has one calibration, and its error against the true sensors is one draw from the
calibration's covariance (``input_error_cov``: misalignment and scale; ``bias_sd``). The
monitor inflates its thresholds in a manoeuvre by the calibration uncertainty at the
current rate (``κ/f_w·Σ_w ρ``, :mod:`fdi.windows`): that inflation is right on average over
draws, but one draw whose error points along the parity directions the flight excites
raises the healthy statistic more than the inflation allows, and its false-alarm rate sits
well above the average (issue 27: 33 to 162 alarms/h for one tuning at 60/h).

Here each of a set of fixed draws (:func:`draw_seeds`) is flown for a while with that
draw's true sensors (:func:`truth_for_draw`, :func:`replay.flight_sim.draw_true_model`),
and its alarm episodes are counted (:func:`episodes`): one false-alarm rate per draw
(:func:`draw_rates`, :class:`DrawRates`). ``rimu tune`` corrects its thresholds until the
mean over draws meets the target *and* the :data:`DRAW_QUANTILE` draw meets
:data:`DRAW_QUANTILE_FACTOR` × the target (:meth:`DrawRates.excess`).

The analytic term (:func:`rate_error_factor`)
----------------------------------------------
A calibration error δH (rows δ_i: the gain-normalised axis error of sensor i, drawn
``N(0, input_error_cov_i)``) moves the whitened parity of a sample at rate ω by
``m = U·δH·ω`` (U = A·V, the whitened parity columns). The monitor's inflation takes
``Cov m ≼ κ·ρ(ω)·I`` over draws (ρ = max_i ωᵀC_iω/Σ_ii, κ = λ_max(A·V·diag Σ·Vᵀ·Aᵀ):
:mod:`fdi.reconstruction`), i.e. a draw gives ``|m|² = c·κ·ρ`` with c of order one per
parity direction. One draw's worst direction over ω is

    c_max(δ) = max_ω |U·δH·ω|² / (κ·ρ(ω))

(evaluated on :data:`DIRECTIONS` unit directions), and it reaches 10-17 for the worst of
30 cone6 draws. Over a window the healthy statistic is then non-central,
``χ'²(df, c·x)`` with ``x = κ·Σ_w ρ/f_w``, against the threshold ``thr·(1 + q·x)``; its
exceedance grows like exp(√(c·x·thr)) while the threshold grows linearly, so the worst
draws alarm at moderate rates (x ≈ 0.03-1). The factor q makes a draw at the
:data:`DRAW_QUANTILE` quantile of c_max (over :data:`ERROR_DRAWS` draws of δ from the
covariance, fixed seed) exceed ``thr(1 + q·x)`` with at most :data:`EXCEEDANCE_FACTOR` ×
the per-sample α of the scale, at every x (:data:`X_GRID`): ``q = max_x q(x)``, solved with
``ncx2.sf``. It is carried by the thresholds (``rate_error_factor``,
:class:`fdi.settings.Thresholds`) and multiplies the monitor's rate term.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy import optimize, stats

from fdi.calfile import Calibration

__all__ = [
    "DIRECTIONS",
    "DRAW_QUANTILE",
    "DRAW_QUANTILE_FACTOR",
    "ERROR_DRAWS",
    "EXCEEDANCE_FACTOR",
    "X_GRID",
    "DrawRates",
    "RateErrorFactor",
    "alarm_episodes",
    "draw_rates",
    "draw_seeds",
    "episodes",
    "rate_error_factor",
    "truth_for_draw",
    "worst_direction_gains",
]

DRAW_QUANTILE = 0.95
"""Quantile over drawn calibration errors that ``rimu tune`` holds to
:data:`DRAW_QUANTILE_FACTOR` × its target."""
DRAW_QUANTILE_FACTOR = 2.0
"""Largest ratio of the :data:`DRAW_QUANTILE` draw's false-alarm rate to the target."""
ERROR_DRAWS = 4000
"""Draws of the calibration error δ for the quantile of c_max (no flights: matrices)."""
DIRECTIONS = 400
"""Unit rate directions (Fibonacci sphere) on which c_max is evaluated."""
EXCEEDANCE_FACTOR = 2.0
"""Largest per-sample exceedance of the quantile draw, in units of the scale's α."""
X_GRID = tuple(float(x) for x in np.geomspace(1e-3, 30.0, 46))
"""Rate terms x = κ·Σ_w ρ/f_w over which q(x) is maximised."""
_FLIGHT_S = 600.0
"""Longest simulated flight of one draw (s); a draw flies several."""


def draw_seeds(seed: int, draws: int) -> tuple[int, ...]:
    """``draws`` fixed seeds of calibration errors for a tuning seed (reproducible)."""
    ss = np.random.SeedSequence([int(seed), 27, 95])
    return tuple(int(x) for x in ss.generate_state(int(draws)))


def truth_for_draw(cal: Calibration, seed: int, kind: str = "gyro") -> Calibration:
    """A truth calibration whose sensors are one draw of the calibration's error
    (:func:`replay.flight_sim.draw_true_model`: axis, scale factor and bias)."""
    from replay.flight_sim import draw_true_model

    m = draw_true_model(cal, seed, kind=kind)
    s = cal.kind(kind)
    sens = tuple(replace(c, axis=np.asarray(a, float), scale_factor=float(sf), bias=float(b))
                 for c, a, sf, b in zip(s.sensors, m.axis, m.scale_factor, m.bias, strict=True))
    return replace(cal, sets={**cal.sets, kind: replace(s, sensors=sens)})


def alarm_episodes(events: Any) -> list[Any]:
    """The events that start an alarm episode of a healthy run, in time order: every
    ``detected`` and ``health`` event, and an ``isolated``/``disagree`` that no detection
    opened."""
    out, open_ = [], False
    for e in events:
        if e.type == "detected":
            out.append(e)
            open_ = True
        elif e.type == "health":
            out.append(e)
        elif e.type in ("isolated", "disagree"):
            if not open_:
                out.append(e)
            open_ = open_ and e.type == "disagree"
    return out


def episodes(events: Any) -> int:
    """How many alarm episodes a healthy run holds (:func:`alarm_episodes`)."""
    return len(alarm_episodes(events))


@dataclass(frozen=True)
class DrawRates:
    """Alarm episodes of healthy flights, per drawn calibration error.

    Attributes
    ----------
    seeds : tuple of int
        Seed of each draw (:func:`replay.flight_sim.draw_true_model`).
    alarms : tuple of int
        Alarm episodes counted per draw.
    hours : tuple of float
        Flight hours per draw.
    """

    seeds: tuple[int, ...]
    alarms: tuple[int, ...]
    hours: tuple[float, ...]

    @property
    def per_hour(self) -> np.ndarray:
        """Rate per draw (alarms/h), shape (draws,)."""
        return np.asarray(self.alarms, float) / np.asarray(self.hours, float)

    @property
    def mean(self) -> float:
        """Mean over draws of the per-draw rate (alarms/h)."""
        return float(np.mean(self.per_hour))

    def quantile(self, q: float = DRAW_QUANTILE) -> float:
        """The q quantile over draws of the per-draw rate (linear interpolation of the
        measured rates: Poisson noise included)."""
        return float(np.quantile(self.per_hour, q))

    def true_quantile(self, q: float = DRAW_QUANTILE) -> float:
        """The q quantile of the draws' *true* rates, the counts' Poisson noise removed.

        Counts k_d ~ Poisson(r_d·T_d) with the true rates r_d spread over draws: a gamma
        distribution of r (the counts then negative binomial) with the mean m and the
        variance ``s² = var(r̂) − mean(r̂_d/T_d)`` of the measured rates r̂ (method of
        moments: the Poisson variance of r̂_d is r_d/T_d). Without spread left (s² ≤ 0)
        the quantile is the mean. Short flights per draw would otherwise read their
        Poisson noise as spread (12 alarms per draw: sd 29 %).
        """
        r = self.per_hour
        m = float(np.mean(r))
        if r.size < 2 or m <= 0:
            return m
        s2 = float(np.var(r, ddof=1) - np.mean(r / np.asarray(self.hours, float)))
        if s2 <= 0:
            return m
        return float(stats.gamma.ppf(q, m * m / s2, scale=s2 / m))

    def excess(self, target: float, q: float = DRAW_QUANTILE,
               factor: float = DRAW_QUANTILE_FACTOR) -> float:
        """``max(mean/target, true_quantile_q/(factor·target))``: 1 when the worse of the two
        meets its bound; the correction step of ``rimu tune``. No alarm at all counts the
        95 % Poisson upper bound of the pooled count (3.0 alarms) as the mean."""
        if sum(self.alarms) == 0:
            return -math.log(0.05) / float(np.sum(self.hours)) / target
        return max(self.mean / target, self.true_quantile(q) / (factor * target))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (per-draw rates, mean, quantile)."""
        return {"draws": len(self.seeds), "seeds": list(self.seeds),
                "alarms": list(self.alarms), "hours": list(self.hours),
                "per_hour": self.per_hour.tolist(), "mean_per_hour": self.mean,
                "quantile": DRAW_QUANTILE, "quantile_per_hour": self.quantile(),
                "true_quantile_per_hour": self.true_quantile(),
                "max_per_hour": float(np.max(self.per_hour))}


def draw_rates(cal: Calibration, thresholds: Any, seeds: tuple[int, ...], *,
               hours: float, max_rate_dps: float = 300.0, kind: str = "gyro",
               seed: int = 0, bar: Any = None) -> DrawRates:
    """Per draw: alarm episodes over ``hours`` of healthy flights with that draw's sensors.

    Each draw flies ``ceil(hours/600 s)`` flights of equal length (each its own motion
    and noise, streams keyed on ``seed``, the draw and the flight), monitored with the
    default :class:`fdi.settings.MonitorSettings`; manoeuvres reach ``max_rate_dps`` (°/s)
    on each axis. ``bar``: a progress bar advanced by the flight hours.
    """
    from fdi.monitor import Monitor
    from replay.flight_sim import simulate_flight

    nf = max(1, math.ceil(hours * 3600.0 / _FLIGHT_S - 1e-9))
    flight_s = max(hours * 3600.0 / nf, 1.0)
    alarms, hrs = [], []
    for d in seeds:
        truth = truth_for_draw(cal, d, kind)
        count = 0
        for j in range(nf):
            fs = int(np.random.SeedSequence([int(seed), int(d), j]).generate_state(1)[0])
            fl = simulate_flight(cal, flight_s, seed=fs, truth=truth,
                                 max_rate_dps=max_rate_dps, kind=kind)
            count += episodes(Monitor(cal, thresholds, kind=kind).run(fl.t, fl.raw,
                                                                       fl.valid).events)
            if bar is not None:
                bar.update(flight_s / 3600.0)
        alarms.append(count)
        hrs.append(nf * flight_s / 3600.0)
    return DrawRates(tuple(int(d) for d in seeds), tuple(alarms), tuple(hrs))


def _directions(k: int = DIRECTIONS) -> np.ndarray:
    """k unit vectors spread over the sphere (Fibonacci lattice), shape (k, 3)."""
    i = np.arange(k) + 0.5
    z = 1.0 - 2.0 * i / k
    r = np.sqrt(1.0 - z * z)
    phi = math.pi * (1.0 + math.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def worst_direction_gains(cal: Calibration, kind: str = "gyro", *, draws: int = ERROR_DRAWS,
                          seed: int = 0) -> np.ndarray:
    """c_max(δ) of ``draws`` calibration errors drawn from the covariance (module
    docstring), shape (draws,); empty when the set has no parity or no axis error."""
    from fdi.parity import parity_matrix
    from fdi.reconstruction import _whitening

    s = cal.kind(kind)
    n = s.n
    Sig = np.asarray(s.noise_covariance, float)
    V = parity_matrix(s.H, np.ones(n, bool))
    df = n - 3
    if df < 1:
        return np.zeros(0)
    _, U, kappa, _ = _whitening(V[:df], Sig, tuple(range(n)), np.zeros(n))
    C = np.array([np.asarray(c.input_error_cov, float) for c in s.sensors])   # (n, 3, 3)
    W = _directions()
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.max(np.einsum("kj,ijl,kl->ki", W, C, W) / np.diag(Sig)[None, :], axis=1)
    if not np.all(np.isfinite(rho)) or not np.any(rho > 0) or not kappa > 0:
        return np.zeros(0)
    rng = np.random.default_rng([int(seed), 27, 4])
    L = np.array([np.linalg.cholesky(c + 1e-30 * np.eye(3)) if np.all(np.linalg.eigvalsh(c)
                  > 0) else _psd_sqrt(c) for c in C])
    out = np.empty(int(draws))
    for d in range(int(draws)):
        dH = np.einsum("ijk,ik->ij", L, rng.standard_normal((n, 3)))         # (n, 3)
        m = (U @ dH) @ W.T                                                  # (df, k)
        out[d] = float(np.max(np.sum(m * m, axis=0) / (kappa * rho)))
    return out


def _psd_sqrt(c: np.ndarray) -> np.ndarray:
    w, v = np.linalg.eigh(0.5 * (c + c.T))
    return v * np.sqrt(np.clip(w, 0.0, None))


@dataclass(frozen=True)
class RateErrorFactor:
    """The analytic rate-error factor q and what it rests on.

    Attributes
    ----------
    factor : float
        q ≥ 1 (:attr:`fdi.settings.Thresholds.rate_error_factor`).
    gain_quantile : float
        The :data:`DRAW_QUANTILE` quantile of c_max over the drawn errors.
    gain_mean : float
        Its mean.
    draws : int
    worst_x : float
        The rate term x at which q(x) is largest.
    """

    factor: float
    gain_quantile: float
    gain_mean: float
    draws: int
    worst_x: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record (for the tuning file)."""
        return {"factor": self.factor, "quantile": DRAW_QUANTILE,
                "worst_direction_gain_quantile": self.gain_quantile,
                "worst_direction_gain_mean": self.gain_mean, "error_draws": self.draws,
                "exceedance_factor": EXCEEDANCE_FACTOR, "worst_rate_term": self.worst_x,
                "rule": "q = max_x q(x): ncx2.sf(thr*(1 + q*x), df, c_q*x) = "
                        "exceedance_factor*chi2.sf(thr, df), c_q the quantile of "
                        "c_max = max_w |U dH w|^2/(kappa*rho(w)) over drawn errors dH"}


def rate_error_factor(cal: Calibration, threshold: float, kind: str = "gyro", *,
                      draws: int = ERROR_DRAWS, seed: int = 0) -> RateErrorFactor:
    """q for the calibration's covariance at the χ² threshold ``threshold`` of the full
    set (module docstring); 1 where the set has no parity or no axis error."""
    g = worst_direction_gains(cal, kind, draws=draws, seed=seed)
    if g.size == 0:
        return RateErrorFactor(1.0, 0.0, 0.0, 0, math.nan)
    cq = float(np.quantile(g, DRAW_QUANTILE))
    df = cal.kind(kind).n - 3
    thr = float(threshold)
    la = math.log(EXCEEDANCE_FACTOR) + float(stats.chi2.logsf(thr, df))
    best, worst_x = 1.0, math.nan
    for x in X_GRID:
        def f(q: float, x: float = x) -> float:
            return float(stats.ncx2.logsf(thr * (1.0 + q * x), df, cq * x)) - la
        if f(best) <= 0:
            continue
        hi = 2.0 * best
        while f(hi) > 0:
            hi *= 2.0
        best, worst_x = float(optimize.brentq(f, best, hi, xtol=1e-6)), x
    return RateErrorFactor(best, cq, float(np.mean(g)), int(g.size), worst_x)
