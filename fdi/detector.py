"""Detection arithmetic: multi-scale chi-square thresholds, Allan variance factors, CUSUM.

The detector tests running means of the whitened parity vector z (Cov z = I for healthy
white noise) over dyadic windows of w = 1, 2, 4, ... 2^K samples (a Haar-like
multi-resolution in the spirit of seed 000's wavelet analysis)::

    D_w = |Σ_window z|² / (w · f_w)      ~ χ²(m − 3)

``f_w ≥ 1`` is the variance of a w-sample mean relative to white noise, read from the
Allan variance of the calibration residuals at τ = w/fs (for white noise the variance of a
τ-mean equals the Allan variance at τ).

False-alarm budget: ``alpha_total = false_alarms_per_hour / (3600 · fs)`` per sample, split
equally across the tests (Bonferroni). Running means are strongly correlated in time (a
w-sample window holds only ~1/w new information per sample), so charging each scale its
share *per sample* is conservative for the longer windows; we accept that (it keeps the
arithmetic simple and the budget a guaranteed upper bound).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy import optimize, stats

from fdi.calfile import AllanTable, Calibration
from fdi.drift import drift_variance_factors
from fdi.errors import ConfigError
from fdi.settings import Thresholds
from fdi.tails import tail_variance_factors

__all__ = [
    "alpha_per_sample",
    "chi2_threshold",
    "clear_thresholds",
    "cusum_threshold",
    "default_scales",
    "default_thresholds",
    "minimum_detectable_noncentrality",
    "noise_model",
    "tail_note",
    "variance_factors",
]


def default_scales(K: int = 7) -> tuple[int, ...]:
    """Dyadic window lengths 1, 2, 4, ..., 2^K samples."""
    if K < 0 or K > 20:
        raise ConfigError(f"scales: K must be in 0..20, got {K}")
    return tuple(2**k for k in range(K + 1))


def alpha_per_sample(false_alarms_per_hour: float, sample_rate_hz: float) -> float:
    """Per-sample false-alarm probability for a rate of false alarms per hour."""
    if not false_alarms_per_hour > 0 or not sample_rate_hz > 0:
        raise ConfigError("false_alarms_per_hour and sample_rate_hz must be positive")
    return min(0.5, false_alarms_per_hour / (3600.0 * sample_rate_hz))


@lru_cache(maxsize=1024)
def chi2_threshold(alpha: float, df: int) -> float:
    """Threshold on a χ²(df) statistic exceeded with probability ``alpha``.

    Uses ``isf`` (``ppf(1 − alpha)`` fails below ~1e-16).
    """
    if df < 1:
        return float("inf")
    return float(stats.chi2.isf(alpha, df))


def clear_thresholds(thr, df: int, settings) -> list[float]:
    """Per scale, the level every statistic must stay below for a detection to clear.

    ``min(T_w, max(clear_ratio·T_w, q))`` with q the χ²(df) level exceeded with probability
    ``clear_miss / (clear_samples · K)`` (K scales): by the union bound healthy white noise
    stays below q for ``clear_samples`` samples on every scale with probability at least
    ``1 − clear_miss``. Half a far-tail threshold is above q (the hysteresis as set); half a
    threshold in the bulk of the statistic is not, and without the floor a detection at a
    high target would never clear.

    Parameters
    ----------
    thr : sequence of float, shape (K,)
        Base thresholds T_w (χ² units).
    df : int
        Parity dimension of the set.
    settings : MonitorSettings
    """
    thr = [float(t) for t in thr]
    if df < 1 or not thr:
        return [settings.clear_ratio * t for t in thr]
    q = chi2_threshold(settings.clear_miss / (settings.clear_samples * len(thr)), df)
    return [min(t, max(settings.clear_ratio * t, q)) for t in thr]


def variance_factors(allan: AllanTable | None, noise_cov: np.ndarray, sample_rate_hz: float,
                     scales: tuple[int, ...]) -> tuple[float, ...]:
    """Variance of a w-sample mean relative to white noise, per scale (≥ 1).

    ``f_w = max_i adev_i(τ)² · w / Σ_ii`` at τ = w/fs, interpolated log-log in the Allan
    table, the worst sensor (conservative), never below 1. Outside the table the nearest
    tabulated ratio is held (the table should cover the windows used). Without a table
    every factor is 1 (white noise assumed).
    """
    scales = tuple(int(w) for w in scales)
    if allan is None:
        return tuple(1.0 for _ in scales)
    tau = np.asarray(allan.tau_s, float)
    adev = np.asarray(allan.adev, float)
    var0 = np.diag(np.asarray(noise_cov, float))
    ok = (tau > 0) & np.all(np.isfinite(adev), axis=1) & np.all(adev > 0, axis=1)
    tau, adev = tau[ok], adev[ok]
    if tau.size == 0:
        return tuple(1.0 for _ in scales)
    order = np.argsort(tau)
    tau, adev = tau[order], adev[order]
    # ratio of the Allan variance to the white-noise prediction σ²/(τ fs) at each tabulated τ
    out = []
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):   # huge inputs: inf
        ratio = adev**2 * (tau[:, None] * sample_rate_hz) / var0[None, :]
        for w in scales:
            lt = math.log(w / sample_rate_hz)
            r = np.array([np.interp(lt, np.log(tau), np.log(ratio[:, i]))
                          for i in range(ratio.shape[1])])
            out.append(max(1.0, float(np.exp(r).max())))
    return tuple(out)


def noise_model(choices: tuple) -> str:
    """``"overbound"`` when some scale's factor is the overbound, ``"gaussian-measured-variance"``
    when some scale's is the measured variance, else ``"gaussian-white"``."""
    if any(c.choice == "overbound" for c in choices):
        return "overbound"
    if any(c.choice == "measured-variance" for c in choices):
        return "gaussian-measured-variance"
    return "gaussian-white"


def tail_note(choices: tuple) -> str:
    """``"; residual tails: overbound at scales 1, 2 (gaussian white at 128)"`` or ``""``."""
    over = [c.scale for c in choices if c.choice == "overbound"]
    if all(math.isnan(c.excess_kurtosis) and c.choice == "gaussian-white" for c in choices):
        return ""                       # no tail model kept

    mv = [c.scale for c in choices if c.choice == "measured-variance"]
    return ("; residual tails (calibration's tail model): overbound factor at scale(s) "
            + (", ".join(map(str, over)) if over else "none")
            + (", measured variance at " + ", ".join(map(str, mv)) if mv else "")
            + ", gaussian white at "
            + (", ".join(str(c.scale) for c in choices if c.choice == "gaussian-white")
               or "none"))


def _siegmund_arl0(h: float, nu: float) -> float:
    """Siegmund's approximation of the in-control ARL of a one-sided CUSUM.

    Increments ``x − ν`` with x ~ N(0, 1); ``b = h + 1.166``.
    """
    b = h + 1.166
    a = 2.0 * nu * b
    return (math.expm1(a) - a) / (2.0 * nu * nu)


@lru_cache(maxsize=1024)
def cusum_threshold(alpha: float, nu: float, n_cusums: int) -> float:
    """CUSUM decision threshold h for a per-sample false-alarm probability ``alpha``.

    ``n_cusums`` one-sided CUSUMs run in parallel (2 per sensor direction); each gets an
    in-control ARL of ``n_cusums / alpha`` samples (Siegmund's approximation).
    """
    if n_cusums < 1:
        return float("inf")
    target = n_cusums / alpha
    f = lambda h: math.log(_siegmund_arl0(h, nu)) - math.log(target)  # noqa: E731
    hi = 1.0
    while f(hi) < 0:
        hi *= 2.0
    return float(optimize.brentq(f, 1e-6, hi, xtol=1e-10))


@lru_cache(maxsize=1024)
def minimum_detectable_noncentrality(threshold: float, df: int, missed_detection: float) -> float:
    """Noncentrality λ at which a χ²(df) test at ``threshold`` misses with ``missed_detection``.

    Solves ``ncx2.cdf(threshold, df, λ) = missed_detection`` (RAIM minimum detectable bias:
    a bias b on sensor i gives λ = b²·|u_i|², u_i its whitened parity column).
    """
    if df < 1 or not math.isfinite(threshold):
        return float("inf")
    f = lambda lam: stats.ncx2.cdf(threshold, df, lam) - missed_detection  # noqa: E731
    hi = max(1.0, threshold)
    while f(hi) > 0:
        hi *= 2.0
    return float(optimize.brentq(f, 1e-9, hi, xtol=1e-10))


def default_thresholds(cal: Calibration, *, kind: str = "gyro",
                       false_alarms_per_hour: float = 1e-3, scales: int | tuple[int, ...] = 7,
                       detector: str = "windows", cusum_drift: float = 0.5,
                       missed_detection: float = 1e-3,
                       sample_rate_hz: float | None = None) -> Thresholds:
    """Thresholds from a calibration: χ² per scale, variance factors, CUSUM h.

    The variance factor of each scale is the Allan one, or where the calibration's tail
    model says the residual fails its normality check, ``max(Allan, overbound f_w(α_w))``
    (:func:`fdi.tails.tail_variance_factors`); where the calibration carries a drift model,
    raised to cover the drift over a horizon of the calibration's span at each scale's α
    (:func:`fdi.drift.drift_variance_factors`).

    Parameters
    ----------
    cal : Calibration
    kind : str
    false_alarms_per_hour : float
        Budget of false alarms per hour of healthy operation.
    scales : int or tuple of int
        K (windows 1 ... 2^K) or the window lengths themselves.
    detector : str
        ``"windows"``, ``"cusum"`` or ``"both"``: how the budget is split (equal shares per
        window scale, one more share for the CUSUM bank when used).
    cusum_drift : float
        CUSUM allowance ν in whitened σ units.
    missed_detection : float
        For the protection level.
    sample_rate_hz : float, optional
        Defaults to the calibration's.
    """
    s = cal.kind(kind)
    fs = float(sample_rate_hz or cal.sample_rate_hz)
    if detector not in ("windows", "cusum", "both"):
        raise ConfigError(f"detector must be windows, cusum or both, got {detector!r}")
    sc = default_scales(scales) if isinstance(scales, int) else tuple(int(w) for w in scales)
    if detector == "cusum":
        sc = (1,)                       # the single-sample test stays for hard faults
    if not sc or any(w < 1 for w in sc):
        raise ConfigError("scales must be positive window lengths")
    a_tot = alpha_per_sample(false_alarms_per_hour, fs)
    n_tests = len(sc) + (1 if detector != "windows" else 0)
    share = a_tot / n_tests
    df = s.n - 3
    vf_allan = variance_factors(s.allan, s.noise_covariance, fs, sc)
    vf, choices = tail_variance_factors(s.tails, sc, tuple(share for _ in sc), vf_allan)
    vf = drift_variance_factors(s.drift, sc, vf, alpha=tuple(share for _ in sc))
    thr = tuple(chi2_threshold(share, df) if df >= 1 else 1e300 for _ in sc)
    h = cusum_threshold(share, cusum_drift, 2 * s.n) if detector != "windows" else float("nan")
    notes = (f"per-sample alpha {a_tot:.3e} = {false_alarms_per_hour:g}/h at {fs:g} Hz split "
             f"equally over {n_tests} test(s) (Bonferroni, conservative for correlated "
             f"running means); chi-square with m-3 dof; variance factors from "
             f"{'the Allan table' if s.allan is not None else 'white noise (no Allan table)'}"
             f"{tail_note(choices)}"
             f"{'' if s.drift is None else '; plus the parity drift over the calibration span'}"
             f"; detector {detector}")
    return Thresholds(kind=kind, n=s.n, sample_rate_hz=fs,
                      false_alarms_per_hour=float(false_alarms_per_hour), scales=sc,
                      alpha=tuple(share for _ in sc), detector=detector,
                      variance_factor=vf, threshold=thr, cusum_drift=float(cusum_drift),
                      cusum_threshold=h, missed_detection=float(missed_detection), notes=notes,
                      calibration_fingerprint=cal.fingerprint(),
                      noise_model=noise_model(choices))
