"""Threshold tuning for a false-alarm rate that holds (``rimu tune``).

Why the per-sample budget of :func:`thresholds.compute_thresholds` is conservative
-------------------------------------------------------------------------------------
It charges every window scale ``alpha = rate/(3600·fs·K)`` *per sample*. A false alarm,
though, is an *episode*: the monitor emits one event when a statistic first crosses its
threshold and stays in the detection state until every statistic has been below
``clear_ratio`` times its threshold for ``clear_samples`` samples (or isolates; the
hysteresis of :class:`fdi.settings.MonitorSettings`, whose defaults the correction flights
below run with). Three things make episodes rarer than exceedance samples:

1. a w-sample running mean that exceeds its threshold tends to stay above it for many
   samples: the share of exceedance samples that start an upcrossing is 0.26 at w = 128
   (df = 3), 0.83 at w = 8, 1 at w = 1 (computed exactly below);
2. the dyadic scales share samples (means over w and 2w are correlated 0.71), so one
   excursion of the noise crosses several scales at once;
3. the hysteresis merges upcrossings that come within one detection episode.

On healthy simulated cone6 flights the per-sample budget gave 25 false alarms per hour for
a target of 60 (factor 2.4 low) and 84 for a target of 3600.

The tuning here
---------------
- per scale, the probability of an *upcrossing* is computed exactly for white noise: the
  windows at t−1 and t share a sum A of w−1 samples, and given A the two statistics are
  independent non-central χ² (df = m − 3, λ = |A|²), so
  ``P(D_{t−1} ≤ T < D_t) = E_A[p(|A|)(1 − p(|A|))]`` with ``p = ncx2.sf(w·T, df, |A|²)``,
  a one-dimensional integral over ``|A|²/(w−1) ~ χ²(df)``; each scale gets an equal share
  of the episode rate (items 1);
- the remaining effects (2, 3, and the calibration-uncertainty inflation of the thresholds
  during manoeuvres) are measured: healthy flights of this calibration are simulated
  (:mod:`replay.flight_sim`, manoeuvres inside the calibration's validated rate range and
  at most 300 °/s: :func:`correction_max_rate_dps`; a set calibrated at rest is corrected
  at rest), the false-alarm episodes counted, and the per-scale shares scaled
  (``correction``); twice, the second time at the corrected level. Below
  :data:`MIN_SIMULATED_RATE` per hour the correction is measured at that rate and carried
  over (stated in the assumptions).

Your calibration, not the average one
-------------------------------------
A user has one calibration, whose error against the true sensors is one draw from its
covariance. The monitor's inflation for the calibration uncertainty in a manoeuvre is right
on average over draws, but a draw whose misalignment and scale error point along the parity
directions the flight excites raises the healthy statistic beyond it: tuned on the average
over draws (one draw per flight), one cone6 tuning at 60/h gave 44 to 268 alarms/h over 20
draws (mean 82). So each correction pass flies :data:`DRAWS` fixed draws of the
calibration error (:mod:`thresholds.per_draw`), each for the same time (at most the time
:data:`MAX_DRAW_ALARMS` alarms take at the target, so its Poisson noise is small against
the spread), and the correction makes the worse of ``mean/target`` and
``p95/(2·target)`` equal to 1 (:meth:`thresholds.per_draw.DrawRates.excess`): the rate
holds on average at the target and for draws of this calibration's error up to the 95th
percentile at twice the target. The second pass steps with the sensitivity of that ratio
to the correction measured between the passes (:func:`_next_correction`).
docs/thresholds-per-calibration.md gives the Monte Carlo (``studies/per_calibration.py``).

Drift over the horizon
----------------------
Where the calibration carries a drift model of its whitened parity (:mod:`fdi.drift`,
``docs/drift.md``), every scale's variance factor is raised after the tail overbound so
that, at the scale's α, its threshold covers an offset of the variance δ²(t) the
calibration's own long-τ Allan covariance predicts (random-walk extrapolation) over the
horizon h (``drift_horizon_s``, default the span of the calibration data), averaged over
the horizon and for the worse of an offset along one direction or spread over all
(:func:`fdi.drift.drift_variance_factors`). The detectable sizes below then grow with it,
and the tuning states the drift given up (1 σ of the offset at the horizon's end, worst
sensor).

Targets tune refuses
--------------------
An alarm episode lasts at least ``clear_samples`` samples (the hysteresis). A target whose
mean time between alarms is less than ten such episodes (:data:`MAX_DEAD_TIME_SHARE`,
:func:`max_false_alarms_per_hour`: 157/h at 43.5 Hz, 180/h at 50 Hz, 3600/h at 1 kHz) is
refused: alarms would merge, and the counted rate no longer follows the thresholds.

Detectable size (at rest)
-------------------------
A step b on sensor i moves the whitened parity by ``b·u_i``; over a full window of w
samples ``D_w ~ ncx2(df, λ = w·b²·|u_i|²/f_w)``. The smallest step detected with 99 %
probability by one window of scale w solves ``ncx2.sf(T_w(1 + w·β/f_w), df, λ) = 0.99``
(:func:`fdi.detector.minimum_detectable_noncentrality`), with the bias-uncertainty
inflation β of the monitor and the worst sensor (smallest |u_i|).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import UTC, datetime
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from scipy import integrate, linalg, optimize, stats

from fdi.calfile import Calibration
from fdi.detector import (
    chi2_threshold,
    minimum_detectable_noncentrality,
    noise_model,
    tail_note,
    variance_factors,
)
from fdi.drift import drift_variance_factors
from fdi.errors import ConfigError
from fdi.fileio import to_jsonable
from fdi.parity import parity_matrix
from fdi.settings import MAX_SCALE, MonitorSettings, Thresholds
from fdi.tails import TailChoice, tail_variance_factors
from fdi.units import DPS
from thresholds.per_draw import rate_error_factor
from thresholds.select import TUNING_SCHEMA

__all__ = ["CORRECTION_MAX_RATE_DPS", "CORRECTION_PASSES", "DRAWS", "MAX_DEAD_TIME_SHARE",
           "MAX_DRAW_ALARMS", "MAX_SHARE_OF_TOP", "MIN_SIMULATED_RATE", "ZERO_COUNT_UPPER",
           "DetectableSize", "Tuning", "check_scales", "correction_max_rate_dps",
           "detectable_at", "detectable_sizes", "max_false_alarms_per_hour",
           "max_upcrossing_rate", "tune", "upcrossing_probability"]

MAX_DEAD_TIME_SHARE = 0.1
"""Largest share of the mean time between false alarms that one alarm's shortest episode
(``clear_samples`` of :class:`fdi.settings.MonitorSettings`) may take: above it, episodes
merge (a dead time D thins a Poisson rate R to R/(1 + R·D)), the counted rate no longer
follows the thresholds, and ``tune`` refuses the target."""
MIN_SIMULATED_RATE = 20.0
"""False alarms per hour below which the simulation correction is measured at this rate."""
CORRECTION_MAX_RATE_DPS = 300.0
"""Largest body rate (°/s) of the correction flights of a calibration that states no
validated range (:func:`correction_max_rate_dps`)."""
DETECTION_PROBABILITY = 0.99
"""Detection probability of the detectable sizes."""
CORRECTION_PASSES = 2
"""Correction passes of ``rimu tune`` (each flies every draw); the second's step uses the
rate's measured sensitivity to the correction (:func:`_next_correction`)."""
DRAWS = 20
"""Drawn calibration errors flown per correction pass (:mod:`thresholds.per_draw`)."""
MAX_DRAW_ALARMS = 60.0
"""A draw is flown at most as long as this many alarms at the target take (its Poisson
noise is then small against the spread over draws)."""


@lru_cache(maxsize=4096)
def upcrossing_probability(alpha: float, df: int, w: int) -> float:
    """``P(D_{t−1} ≤ T < D_t)`` for the w-sample window of white noise, T = χ²_df isf(alpha).

    Parameters
    ----------
    alpha : float
        Per-sample exceedance probability of the scale.
    df : int
        Parity dimension.
    w : int
        Window length (samples).
    """
    if w <= 1:
        return alpha * (1.0 - alpha)
    T = chi2_threshold(alpha, df)

    def f(s: float) -> float:
        p = stats.ncx2.sf(w * T, df, s * (w - 1))
        return p * (1.0 - p) * stats.chi2.pdf(s, df)

    mid = T * w / (w - 1)
    hi = max(4.0 * mid, mid + 60.0)
    v, _ = integrate.quad(f, 0.0, hi, points=[mid], limit=400, epsabs=0.0, epsrel=1e-8)
    return float(v)


_ALPHA_MAX = 0.45
"""Largest per-sample alpha searched (the upcrossing probability peaks below 1/2)."""


def max_upcrossing_rate(df: int, w: int) -> float:
    """The largest upcrossing probability a w-sample window reaches (at alpha 0.45): a
    share above it cannot be met by any threshold."""
    return upcrossing_probability(_ALPHA_MAX, df, w)


def _alpha_for_upcrossings(rate: float, df: int, w: int) -> float:
    """Per-sample alpha whose upcrossing probability is ``rate`` (per sample).

    Raises
    ------
    ConfigError
        A rate no threshold of this window can give (above :func:`max_upcrossing_rate`).
    """
    rate = min(rate, 0.2)
    top = max_upcrossing_rate(df, w)
    if rate >= top:
        raise ConfigError(f"scale {w}: {rate:.3g} upcrossings per sample asked, a {w}-sample "
                          f"window gives at most {top:.3g}: no threshold meets this share")
    g = lambda la: math.log(upcrossing_probability(math.exp(la), df, w)) - math.log(rate)  # noqa: E731
    lo = math.log(rate) - 1e-12
    return math.exp(optimize.brentq(g, lo, math.log(_ALPHA_MAX), xtol=1e-10))


ZERO_COUNT_UPPER = -math.log(0.05)
"""Alarms taken for a correction pass that counted none: the 95 % upper bound (Poisson)."""
MAX_SHARE_OF_TOP = 0.5
"""A scale's share of the episode rate stays below this fraction of the most its window
can give (:func:`max_upcrossing_rate`); the correction is held there."""


def _least_correction(rate_per_hour: float, fs: float, scales: tuple[int, ...], df: int
                      ) -> float:
    """The smallest correction γ that keeps every scale's share ``rate/(3600·fs·K·γ)`` below
    :data:`MAX_SHARE_OF_TOP` of what its window can give."""
    share = rate_per_hour / (3600.0 * fs) / len(scales)
    return max(share / (MAX_SHARE_OF_TOP * max_upcrossing_rate(df, w)) for w in scales)


def max_false_alarms_per_hour(sample_rate_hz: float) -> float:
    """Highest target ``tune`` accepts: one alarm's shortest episode (``clear_samples`` of
    the default :class:`fdi.settings.MonitorSettings`) at most :data:`MAX_DEAD_TIME_SHARE`
    of the mean time between alarms (per hour; 157/h at 43.5 Hz, 180/h at 50 Hz)."""
    return 3600.0 * MAX_DEAD_TIME_SHARE * float(sample_rate_hz) / MonitorSettings().clear_samples


def check_scales(cal: Calibration, scales: int | tuple[int, ...], *, kind: str = "gyro",
                 sample_rate_hz: float | None = None) -> tuple[int, ...]:
    """Window lengths to tune (K: 1 ... 2^K), checked against the Allan table.

    Raises
    ------
    ConfigError
        A scale that is not a positive integer up to 2^20, or longer than the longest τ of
        the calibration's Allan table (its noise is unknown there).
    """
    if isinstance(scales, int):
        if not 0 <= scales <= 20:
            raise ConfigError(f"scales: K must be in 0..20, got {scales}")
        sc = tuple(2**k for k in range(scales + 1))
    else:
        sc = []
        for w in scales:
            if not (float(w) == int(w) and 1 <= int(w) <= MAX_SCALE):
                raise ConfigError(f"unknown scale {w!r}: expected a window length in samples, "
                                  f"an integer in 1..{MAX_SCALE}")
            sc.append(int(w))
        sc = tuple(sorted(set(sc)))
        if not sc:
            raise ConfigError("scales: give at least one window length")
    s = cal.kind(kind)
    fs = float(sample_rate_hz or cal.sample_rate_hz)
    tmax = float(np.max(s.allan.tau_s)) if s.allan is not None else math.inf
    for w in sc:
        if w / fs > tmax * (1 + 1e-9):
            raise ConfigError(f"unknown scale {w}: {w / fs:g} s is beyond the calibration's "
                              f"Allan table (longest tau {tmax:g} s); its noise is unknown there")
    return sc


def _parity_geometry(cal: Calibration, kind: str
                     ) -> tuple[int, np.ndarray, float, np.ndarray, np.ndarray]:
    """Full set: df, |u_i|², β, whitened columns U (df, n) and bias-error covariance G.

    z = L⁻¹·p with L·Lᵀ = VΣVᵀ; ``U = L⁻¹V``; a bias error e ~ N(0, diag(bias_sd²)) moves z
    by ``L⁻¹V·e`` with covariance ``G``; β is the largest eigenvalue of G (the monitor's
    bias-uncertainty constant).
    """
    s = cal.kind(kind)
    V = parity_matrix(s.H)
    S = np.asarray(s.noise_covariance, float)
    L = np.linalg.cholesky(V @ S @ V.T)
    U = linalg.solve_triangular(L, V, lower=True)
    D = np.diag([c.bias_sd**2 for c in s.sensors])
    G = U @ D @ U.T
    beta = float(np.linalg.eigvalsh(G).max()) if G.size else 0.0
    return V.shape[0], np.sum(U * U, axis=0), max(beta, 0.0), U, G


@dataclass(frozen=True)
class DetectableSize:
    """Smallest step detected with :data:`DETECTION_PROBABILITY` by one window, at rest.

    Attributes
    ----------
    scale : int
        Window length (samples).
    window_s : float
    size : float
        SI (rad/s for gyros, m/s² for accelerometers), worst sensor.
    size_unit_value : float
        The same in ``unit``.
    unit : str
        ``"deg/s"`` for gyros, ``"m/s^2"`` for accelerometers.
    size_sigma : float
        In units of that sensor's white-noise sd per sample.
    sensor : int
        1-based worst sensor.
    """

    scale: int
    window_s: float
    size: float
    size_unit_value: float
    unit: str
    size_sigma: float
    sensor: int


def detectable_sizes(cal: Calibration, thresholds: Thresholds, *, kind: str = "gyro",
                     probability: float = DETECTION_PROBABILITY, draws: int = 4000
                     ) -> tuple[DetectableSize, ...]:
    """Per scale, the smallest step one full window detects with ``probability`` (at rest).

    The window sum of z is ``N(w(b·u_i + g), w·f_w·I)`` with g the parity offset of the
    bias error (``g ~ N(0, G)`` over flights, see :func:`_parity_geometry`), so
    ``P(detect) = E_g[ncx2.sf(T_w(1 + w·β/f_w), df, w·|b·u_i + g|²/f_w)]``, averaged over
    ``draws`` fixed draws of g; b solves P = ``probability`` for the worst sensor.
    """
    s = cal.kind(kind)
    if s.n < 4:
        raise ConfigError(f"{s.n} {kind} sensors: no parity space, no detectable size")
    df, u2, beta, U, G = _parity_geometry(cal, kind)
    i = int(np.argmin(u2))
    sd = float(s.noise_sd[i])
    unit, conv = ("deg/s", DPS) if kind == "gyro" else ("m/s^2", 1.0)
    g = np.random.default_rng(12345).multivariate_normal(np.zeros(df), G, size=draws,
                                                         method="eigh")
    ui = U[:, i]
    out = []
    for w, a, f in zip(thresholds.scales, thresholds.alpha, thresholds.variance_factor,
                       strict=True):
        T = chi2_threshold(a, df) * (1.0 + w * beta / f)
        b = detectable_at(T, int(w), f, df, ui, g, float(u2[i]), probability)
        out.append(DetectableSize(int(w), w / thresholds.sample_rate_hz, b, b / conv, unit,
                                  b / sd, i + 1))
    return tuple(out)


def detectable_at(T: float, w: int, f: float, df: int, ui: np.ndarray, g: np.ndarray,
                  u2: float, probability: float = DETECTION_PROBABILITY) -> float:
    """The step b (SI) one full w-sample window detects with ``probability`` against the
    threshold T (χ² units, all inflations in): ``E_g[ncx2.sf(T, df, w·|b·u_i + g|²/f)]``
    over the draws ``g`` (n_draws, df) of the bias error's parity offset; ``ui`` the worst
    sensor's whitened column, ``u2 = |ui|²``."""
    def miss(b: float) -> float:
        lam = w * np.sum((b * ui + g) ** 2, axis=1) / f
        return float(np.mean(stats.ncx2.sf(T, df, lam))) - probability

    b0 = math.sqrt(minimum_detectable_noncentrality(T, df, 1.0 - probability) * f / (w * u2))
    hi = 2.0 * b0
    while miss(hi) < 0:
        hi *= 2.0
    return float(optimize.brentq(miss, 0.0, hi, xtol=1e-9 * b0))


@dataclass(frozen=True)
class Tuning:
    """Thresholds tuned for a false-alarm rate, with what they assume.

    Attributes
    ----------
    thresholds : Thresholds
    detectable : tuple of DetectableSize
    assumptions : dict
        Noise model, Allan deviation per scale, calibration covariance, residual tails, the
        simulated correction.
    choices : tuple of TailChoice
        Per scale, what the variance factor rests on (Gaussian white or the overbound of
        the calibration's residual tail model), for printing.
    schema : str
    """

    thresholds: Thresholds
    detectable: tuple[DetectableSize, ...]
    assumptions: dict[str, Any] = field(default_factory=dict)
    choices: tuple[TailChoice, ...] = ()
    schema: str = TUNING_SCHEMA

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready ``rimu.tuning/1`` document."""
        return to_jsonable({"schema": self.schema, "thresholds": self.thresholds.to_dict(),
                            "detectable": [d.__dict__ for d in self.detectable],
                            "assumptions": self.assumptions})

    def save(self, path: str | Path) -> None:
        """Write as JSON (NaN as null)."""
        import json

        Path(path).write_text(json.dumps(self.to_dict(), indent=1, allow_nan=False) + "\n",
                              encoding="utf-8")


def _share_thresholds(base: dict[str, Any], per_scale_rate: float, df: int) -> Thresholds:
    al = tuple(_alpha_for_upcrossings(per_scale_rate, df, w) for w in base["scales"])
    return Thresholds(**{**base, "alpha": al,
                         "threshold": tuple(chi2_threshold(a, df) for a in al)})


def simulated_rate(cal: Calibration, thr: Thresholds, *, hours: float, seed: int,
                   kind: str = "gyro", flight_s: float | None = None,
                   bar: Any = None, max_rate_dps: float = CORRECTION_MAX_RATE_DPS
                   ) -> tuple[int, float]:
    """False alarms and exposure (h) of the full set over simulated healthy flights.

    Flights last ``flight_s`` (default: about one expected false alarm each at the
    thresholds' budget, between 60 and 600 s): the rate varies from flight to flight with
    the drawn calibration error, so many flights are needed. Their manoeuvres reach
    ``max_rate_dps`` (°/s) on each axis. ``bar``: a progress bar (``update(hours)``)
    advanced by the simulated hours.
    """
    from thresholds.campaign import RunSpec, run_one

    if flight_s is None:
        flight_s = float(np.clip(3600.0 / thr.false_alarms_per_hour, 60.0, 600.0))

    nf = max(1, math.ceil(hours * 3600.0 / flight_s))
    count, expo = 0, 0.0
    for j in range(nf):
        r = run_one(cal, thr, RunSpec(j, int(np.random.SeedSequence([seed, 77, j])
                                               .generate_state(1)[0]), "healthy", 0.0, 0.0,
                                      0, math.inf, flight_s, float(max_rate_dps)),
                    kind=kind)
        count += int(r.false_alarm)
        expo += r.exposure_s
        if bar is not None:
            bar.update(flight_s / 3600.0)
    return count, expo / 3600.0


def correction_max_rate_dps(cal: Calibration, kind: str = "gyro") -> float:
    """Largest body rate (°/s) of the correction flights: inside the calibration's
    validated range on every axis.

    A gyro calibration that states the rates its samples covered (``validated_rate``,
    :mod:`fdi.envelope`) is monitored inside that range only: beyond it the monitor marks
    the answer ``range`` and its alarms are context, not false alarms. So the flights that
    measure the correction keep every axis within the smallest axis's range, and at most
    :data:`CORRECTION_MAX_RATE_DPS`. A set calibrated at rest is corrected on flights at
    rest: its datasheet scale-factor tolerance inflates the thresholds in a manoeuvre (ρ,
    :mod:`fdi.detector`), and flights at 300 °/s would raise the budget at rest about
    fourfold (4×MPU9250, measured). The smallest axis is the conservative choice for a
    flight whose axes reach different rates (flight 41: 254, 148, 71 °/s gives 71): fewer
    manoeuvres inflate fewer thresholds, more simulated alarms lower α. Without a stated
    range (turntable calibrations, accelerometers): :data:`CORRECTION_MAX_RATE_DPS`.
    """
    return _correction_rate(cal, kind)[0]


def _correction_rate(cal: Calibration, kind: str) -> tuple[float, str]:
    """:func:`correction_max_rate_dps` and where it comes from (for the tuning file)."""
    vr = cal.kind(kind).validated_rate
    lo = math.nan if vr is None else float(np.min(np.asarray(vr, float))) / DPS
    if not math.isfinite(lo):
        return CORRECTION_MAX_RATE_DPS, f"default ({CORRECTION_MAX_RATE_DPS:g} deg/s)"
    if lo >= CORRECTION_MAX_RATE_DPS:
        return CORRECTION_MAX_RATE_DPS, (f"the calibration's validated range, capped at "
                                         f"{CORRECTION_MAX_RATE_DPS:g} deg/s")
    return max(lo, 0.0), "the calibration's validated range (smallest axis)"


def _assumptions(cal: Calibration, thr: Thresholds, kind: str, df: int, beta: float
                 ) -> dict[str, Any]:
    s = cal.kind(kind)
    fs = thr.sample_rate_hz
    tau = np.array(thr.scales, float) / fs
    adev = None
    if s.allan is not None:
        lt = np.log(np.asarray(s.allan.tau_s, float))
        la = np.log(np.asarray(s.allan.adev, float))
        adev = np.exp([np.interp(np.log(tau), lt, la[:, i]) for i in range(s.n)]).T
    noise_rec = cal.extras.noise_model
    white = all(abs(f - 1.0) < 1e-9 for f in thr.variance_factor)
    steps = cal.extras.residual_steps
    return {
        "noise_model": {
            "detector_assumes": "zero-mean Gaussian parity noise, white within each window "
                                "up to the Allan variance factors f_w",
            "white": white,
            "calibration_noise_model": noise_rec.method if noise_rec is not None else None},
        "allan_deviation": {"source": "the calibration's Allan table (allantools.oadev of "
                                      "its residuals), log-log interpolated at tau = w/fs",
                            "scale": list(thr.scales), "tau_s": tau.tolist(),
                            "unit": "SI input (rad/s or m/s^2)",
                            "adev": None if adev is None else adev.tolist(),
                            "variance_factor": list(thr.variance_factor)},
        "calibration_covariance": {
            "noise_covariance": np.asarray(s.noise_covariance, float).tolist(),
            "noise_sd": s.noise_sd.tolist(),
            "bias_sd": [c.bias_sd for c in s.sensors],
            "input_error_cov_trace": [float(np.trace(c.input_error_cov)) for c in s.sensors],
            "parity_dof": df, "bias_inflation_beta": beta},
        "residual_tails": {
            "assumed": ("Gaussian (chi-square detection statistics)" if s.tails is None else
                        "the calibration's tail model (rimu.tails/1): per scale Gaussian white "
                        "where the residual passes its normality check, else the variance "
                        "factor max(Allan, overbound)"),
            "model_source": None if s.tails is None else s.tails.source,
            "model_samples": None if s.tails is None else s.tails.samples,
            "residual_rms": [c.residual_rms for c in s.sensors],
            "calibration_step_residuals": "recorded in the calibration file" if steps
            else "not recorded",
            "check": "docs/noise-tails.md measures the tails of real static recordings"},
    }


def _drift_assumptions(cal: Calibration, kind: str, thr: Thresholds, vf_no_drift: tuple,
                       horizon_s: float | None, u2: np.ndarray) -> dict[str, Any]:
    """What the drift term assumes and gives up (for the tuning file and ``rimu tune``)."""
    s = cal.kind(kind)
    m = s.drift
    if m is None:
        return {"model": None, "note": "no drift model in the calibration: the thresholds "
                                       "assume the biases stay as calibrated"}
    d2 = m.offset_variance(horizon_s)
    conv = DPS if kind == "gyro" else 1.0
    # a bias b on sensor i moves the whitened parity by b·|u_i|: δ per direction is the
    # bias δ/|u_i| on sensor i (the worst sensor: the smallest |u_i|)
    i = int(np.argmin(u2))
    return {"model": m.method, "source": m.source, "span_s": m.span_s,
            "horizon_s": m.span_s if horizon_s is None else float(horizon_s),
            "horizon_tau_s": m.horizon_tau_s(horizon_s),
            "longest_resolved_tau_s": m.tau_s[-1] if m.tau_s else None,
            "excess_at_longest_tau": m.excess[-1] if m.excess else None,
            "offset_variance_whitened": d2,
            "offset_sd_worst_sensor": math.sqrt(d2 / u2[i]),
            "offset_sd_worst_sensor_unit_value": math.sqrt(d2 / u2[i]) / conv,
            "unit": "deg/s" if kind == "gyro" else "m/s^2", "worst_sensor": i + 1,
            "variance_factor_without_drift": list(vf_no_drift),
            "variance_factor": list(thr.variance_factor),
            "rule": "f_w*max(q_one, q_spread)/chi2(df).isf(alpha_w): the levels exceeded "
                    "with probability alpha_w on average over the horizon by an offset of "
                    "variance delta^2(t) along one direction or spread over all; "
                    "delta^2(t) = 2*max(e(tau_L)*tau_t/tau_L, max e), "
                    "tau_h = 1.5 h + T_c/2 (random walk beyond the longest resolved tau)"}


def _check_target(cal: Calibration, R: float, kind: str, drift_horizon_s: float | None
                  ) -> float:
    """The calibration's sample rate once the target, the horizon and the residual
    statistics pass (:func:`tune`'s Raises)."""
    if not (math.isfinite(R) and R > 0):
        raise ConfigError(f"--false-alarms-per-hour must be positive and finite, got {R:g}")
    if drift_horizon_s is not None and not (math.isfinite(float(drift_horizon_s))
                                            and float(drift_horizon_s) >= 0):
        raise ConfigError(f"--drift-horizon-s must be >= 0 and finite, got {drift_horizon_s}")
    if cal.kind(kind).allan is None:
        raise ConfigError(f"the calibration has no residual statistics for its {kind} "
                          f"sensors (no Allan table of the residuals): recalibrate with the "
                          f"Allan table on, or give thresholds by hand")
    fs = float(cal.sample_rate_hz)
    if R > max_false_alarms_per_hour(fs):
        dead_s = MonitorSettings().clear_samples / fs
        raise ConfigError(
            f"--false-alarms-per-hour {R:g} is more than the monitor can count as separate "
            f"alarms at {fs:g} Hz (at most {max_false_alarms_per_hour(fs):.3g}): an "
            f"alarm lasts at least {dead_s:.3g} s (clear_samples), and at this rate that "
            f"is more than {MAX_DEAD_TIME_SHARE:.0%} of the time between alarms; alarms "
            f"would merge and that is not a false-alarm budget")
    return fs


def _max_rate(cal: Calibration, kind: str, max_rate_dps: float | None) -> tuple[float, str]:
    """The correction flights' largest rate (°/s) and where it comes from."""
    if max_rate_dps is None:
        return _correction_rate(cal, kind)
    if not (math.isfinite(float(max_rate_dps)) and float(max_rate_dps) >= 0):
        raise ConfigError(f"--max-rate-dps must be >= 0 and finite, got {max_rate_dps}")
    return float(max_rate_dps), "given"


def _next_correction(history: list[tuple[float, float]], floor: float) -> float:
    """The next correction γ from the passes so far, ``(γ, excess)`` each.

    The first step assumes the rate falls as 1/γ (γ·excess); later steps use the slope
    e of log(excess) against log(γ) between the last two passes (clipped to 0.3–2: the
    rate of a draw whose alarms come from its calibration error falls more slowly than
    1/γ), γ·excess^(1/e).
    """
    g, x = history[-1]
    e = 1.0
    if len(history) > 1:
        g0, x0 = history[-2]
        if g != g0 and x > 0 and x0 > 0:
            e = float(np.clip(-math.log(x / x0) / math.log(g / g0), 0.3, 2.0))
    return max(g * x ** (1.0 / e), floor)


def _correct(cal: Calibration, base: dict[str, Any], df: int, *, kind: str,
             simulate_hours: float, draws: int, seed: int, progress: bool,
             max_rate_dps: float) -> tuple[float, list[dict[str, Any]], float]:
    """The simulated correction γ of the per-scale shares, its passes, and the rate Rc
    it was measured at (module docstring; :mod:`thresholds.per_draw`)."""
    from fdi.progress import current
    from thresholds.per_draw import draw_rates, draw_seeds

    R, fs, sc = base["false_alarms_per_hour"], base["sample_rate_hz"], base["scales"]
    Rc = max(R, MIN_SIMULATED_RATE)
    n_pass = CORRECTION_PASSES if simulate_hours > 0 and draws > 0 else 0
    per_draw = min(simulate_hours / max(draws, 1), MAX_DRAW_ALARMS / Rc)
    seeds = draw_seeds(seed, draws)
    # the command's progress (fdi.progress): a bar on a terminal, a line every 10 s else
    bar = (current().bar(n_pass * draws * per_draw, "simulated flight", unit="h")
           if progress and n_pass else None)
    floor = _least_correction(Rc, fs, sc, df)
    gamma, passes, history = 1.0, [], []
    for p in range(n_pass):
        thr_c = _share_thresholds({**base, "false_alarms_per_hour": Rc},
                                  Rc / (3600.0 * fs) / len(sc) / gamma, df)
        dr = draw_rates(cal, thr_c, seeds, hours=per_draw, max_rate_dps=max_rate_dps,
                        kind=kind, seed=seed + 1000 * p, bar=bar)
        x = dr.excess(Rc)
        passes.append({"target_per_hour": Rc, "false_alarms": int(sum(dr.alarms)),
                       "exposure_h": float(sum(dr.hours)), "rate_per_hour": dr.mean,
                       "quantile_per_hour": dr.true_quantile(), "excess": x,
                       "correction_before": gamma, "bound_only": sum(dr.alarms) == 0,
                       "per_draw": dr.to_dict()})
        history.append((gamma, x))
        gamma = _next_correction(history, floor)
    if bar is not None:
        bar.close()
    return gamma, passes, Rc


def _correction_record(gamma: float, passes: list[dict[str, Any]], R: float, Rc: float,
                       capped: bool, max_rate_dps: float, rate_source: str, draws: int
                       ) -> dict[str, Any]:
    """``assumptions["simulation_correction"]`` of the tuning file."""
    from thresholds.per_draw import DRAW_QUANTILE, DRAW_QUANTILE_FACTOR

    q = f"p{100 * DRAW_QUANTILE:g}"
    covers = (f"holds for draws of this calibration's error up to {q}: the mean over "
              f"{draws} drawn calibration errors at the target, the {q} draw at "
              f"<= {DRAW_QUANTILE_FACTOR:g}x the target")
    note = ("not simulated: analytic shares only (conservative)" if not passes
            else f"measured at {Rc:g}/h and carried over to {R:g}/h" if R < Rc
            else "measured at the target")
    if any(p["bound_only"] for p in passes):
        note += "; no alarm in a pass: its 95 % upper bound used (a conservative step)"
    if capped:
        note += "; held at the least correction every scale's share allows"
    return {
        "factor": gamma, "passes": passes,
        "flights": "replay.flight_sim healthy, per drawn calibration error (axis, scale, "
                   "bias from the calibration covariance, thresholds.per_draw), "
                   f"manoeuvres up to {float(max_rate_dps):.4g} deg/s",
        "criterion": covers if passes else "none (not simulated)",
        "draws": draws if passes else 0,
        "max_rate_dps": float(max_rate_dps),
        "max_rate_source": rate_source,
        "extrapolated": R < MIN_SIMULATED_RATE and bool(passes),
        "capped": bool(capped),
        "note": note}


def _tail_assumptions(choices: tuple[TailChoice, ...]) -> list[dict[str, Any]]:
    return [{"scale": c.scale, "choice": c.choice, "allan_factor": c.allan_factor,
             "overbound_factor": c.overbound_factor, "variance_factor": c.factor,
             "excess_kurtosis": c.excess_kurtosis, "gpd_shape": c.shape,
             "gpd_shape_sd": c.shape_sd, "text": c.text()} for c in choices]


def _drift_note(cal: Calibration, kind: str, drift_horizon_s: float | None) -> str:
    d = cal.kind(kind).drift
    if d is None:
        return ""
    h = d.span_s if drift_horizon_s is None else float(drift_horizon_s)
    return (f"; parity drift over a {h:g} s horizon (offset variance up to "
            f"{d.offset_variance(drift_horizon_s):.3g} per sample, fdi.drift)")


def tune(cal: Calibration, *, false_alarms_per_hour: float, kind: str = "gyro",
         scales: int | tuple[int, ...] = 7, simulate_hours: float = 8.0,
         seed: int = 0, progress: bool = False,
         drift_horizon_s: float | None = None,
         max_rate_dps: float | None = None, draws: int = DRAWS) -> Tuning:
    """Thresholds whose full-set false-alarm rate is ``false_alarms_per_hour``, for the
    calibration the user has (over its uncertainty), not only on average.

    Parameters
    ----------
    cal : Calibration
        Must carry residual statistics (an Allan table) for ``kind``.
    false_alarms_per_hour : float
        Target rate of false alarms (episodes) per hour of healthy operation (> 0).
    kind : str
    scales : int or tuple of int
        K (windows 1 ... 2^K) or window lengths (samples).
    simulate_hours : float
        Hours of healthy flight simulated per correction pass, shared by the ``draws``
        drawn calibration errors, each at most the time in which
        :data:`MAX_DRAW_ALARMS` false alarms are expected (0: analytic shares only).
    seed : int
        Seed of the correction flights and of the drawn calibration errors.
    progress : bool
        A bar over the simulated flight hours (:func:`fdi.progress.current`: shown by the
        CLI on stderr once the work has taken 3 s).
    drift_horizon_s : float, optional
        How long after its data the calibration must hold (s): the horizon of the drift
        term (module docstring). Default: the span of the calibration data. Ignored when
        the calibration has no drift model.
    max_rate_dps : float, optional
        Largest body rate of the correction flights (°/s). Default: inside the
        calibration's validated range (:func:`correction_max_rate_dps`).
    draws : int
        Drawn calibration errors per correction pass (:mod:`thresholds.per_draw`): the
        correction holds the mean over them at the target and their
        :data:`thresholds.per_draw.DRAW_QUANTILE` quantile at
        :data:`thresholds.per_draw.DRAW_QUANTILE_FACTOR` × the target.

    Raises
    ------
    ConfigError
        No residual statistics, a target that is not positive and finite or so high that
        alarms would merge (:data:`MAX_DEAD_TIME_SHARE`), an unknown scale, a set without
        redundancy, a negative or non-finite horizon.
    """
    R = float(false_alarms_per_hour)
    fs = _check_target(cal, R, kind, drift_horizon_s)
    s = cal.kind(kind)
    sc = check_scales(cal, scales, kind=kind, sample_rate_hz=fs)
    max_rate_dps, rate_source = _max_rate(cal, kind, max_rate_dps)
    if s.n < 4:
        raise ConfigError(f"{s.n} {kind} sensors: no parity space, nothing to tune")
    df, u2, beta, _, _ = _parity_geometry(cal, kind)
    vf = variance_factors(s.allan, s.noise_covariance, fs, sc)
    base = {"kind": kind, "n": s.n, "sample_rate_hz": fs, "false_alarms_per_hour": R,
            "scales": sc, "variance_factor": vf, "detector": "windows"}
    ref = _share_thresholds(base, R / (3600.0 * fs) / len(sc), df)
    qf = rate_error_factor(cal, max(ref.threshold), kind, seed=seed)
    base["rate_error_factor"] = qf.factor
    gamma, passes, Rc = _correct(cal, base, df, kind=kind, simulate_hours=simulate_hours,
                                 draws=int(draws), seed=seed, progress=progress,
                                 max_rate_dps=float(max_rate_dps))
    floor = _least_correction(R, fs, sc, df)
    capped = gamma < floor
    gamma = max(gamma, floor)
    thr = _share_thresholds(base, R / (3600.0 * fs) / len(sc) / gamma, df)
    # the simulated correction is measured on Gaussian flights with the Allan factors; the
    # measured tails then inflate the variance per scale at the alpha it ended with
    vf_tail, choices = tail_variance_factors(s.tails, sc, thr.alpha, vf)
    # then the drift expected over the horizon (fdi.drift), on top of noise and tail
    vf_used = drift_variance_factors(s.drift, sc, vf_tail, drift_horizon_s, thr.alpha)
    per_draw = (f"; rate term x{qf.factor:.3g} for the p95 calibration error "
                f"(thresholds.per_draw)" + (f"; the mean over {int(draws)} drawn calibration "
                                            f"errors at the target, the p95 draw at <= 2x"
                                            if passes else ""))
    notes = (f"tuned for {R:g} false alarms/h: exact white-noise upcrossing rate per scale, "
             f"equal shares, simulated correction {gamma:.3f}{per_draw}{tail_note(choices)}"
             f"{_drift_note(cal, kind, drift_horizon_s)} (rimu tune)")
    thr = Thresholds(kind=kind, n=s.n, sample_rate_hz=fs, false_alarms_per_hour=R,
                     scales=sc, alpha=thr.alpha, variance_factor=vf_used,
                     threshold=thr.threshold, detector="windows", notes=notes,
                     calibration_fingerprint=cal.fingerprint(),
                     noise_model=noise_model(choices), rate_error_factor=qf.factor)
    ass = _assumptions(cal, thr, kind, df, beta)
    ass["residual_tails"]["per_scale"] = _tail_assumptions(choices)
    ass["drift"] = _drift_assumptions(cal, kind, thr, vf_tail, drift_horizon_s, u2)
    ass["method"] = "rimu tune: upcrossing shares + simulated correction per drawn error"
    ass["rate_error_factor"] = qf.to_dict()
    ass["simulation_correction"] = _correction_record(gamma, passes, R, Rc, capped,
                                                      float(max_rate_dps), rate_source,
                                                      int(draws))
    ass["created"] = datetime.now(UTC).isoformat(timespec="seconds")
    return Tuning(thr, detectable_sizes(cal, thr, kind=kind), ass, choices)
