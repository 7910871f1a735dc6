"""Thresholds against real static noise: tune on the first part, count false alarms on the rest.

Two public static recordings (read in place, never copied; a small reader here until the
general log readers land):

- four MPU9250 IMUs on one body, 16 min at ≈43 Hz (``multi_imu_4x_mpu9250``, MATLAB .mat):
  12 gyro channels, a redundant set;
- one ADIS16405, 2.8 h at 100 Hz (``smac_adis16405``, R .rda): 3 gyro channels, no
  redundancy, used for the shape of the noise only.

The vehicle is at rest, so the true rate is zero up to Earth rate (0.004 °/s, below the
noise): the parity residual of *any* geometry of the channels sees only their noise and
bias. The four MPU triads are taken as aligned (H = four stacked identities).

:func:`static_holdout` builds a calibration from the first part (bias = mean, full noise
covariance, Allan table of the residuals), tunes thresholds for the target rate, runs the
monitor over the rest with isolation off (one false alarm = one detection episode), and
does the same with the white-noise assumption (variance factors 1), with a drift-aware
bias uncertainty (``bias_sd`` = the Allan deviation at the longest τ), and with that plus
threshold levels from the empirical tail of the first part (:func:`tail_thresholds`).
:func:`noise_shape` measures how far the noise departs from the Gaussian white model:
excess kurtosis, tail exceedances beyond 4σ against the Gaussian expectation, lag-1
autocorrelation, the largest correlation between channels, the bias shift between the two
parts in units of its white-noise standard error, and the Allan deviation at long τ
against the white-noise prediction.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from fdi.calfile import Calibration, SensorCal, SensorSet
from fdi.errors import FileFormatError
from fdi.units import DPS
from thresholds.compute import allan_from_residuals

__all__ = ["MPU9250_CROSS_AXIS", "MPU9250_SCALE_FACTOR_TOLERANCE", "PREDICTION_BLOCKS",
           "load_adis16405", "load_mpu9250_static", "noise_shape", "static_calibration",
           "static_holdout", "tail_thresholds"]


def load_mpu9250_static(folder: str | Path) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """Times (N,) s and gyro rates (N, 12) rad/s of ``imu1..4_raw.mat`` (``wb`` fields)."""
    import scipy.io

    d = Path(folder)
    cols, names, t = [], [], None
    for k in range(1, 5):
        p = d / f"imu{k}_raw.mat"
        try:
            m = scipy.io.loadmat(p)[f"imu{k}_raw"][0, 0]
            tk = np.asarray(m["t"], float).ravel()
            wk = np.asarray(m["wb"], float)
        except (OSError, KeyError, ValueError, IndexError) as exc:
            raise FileFormatError(str(p), f"expected struct imu{k}_raw with t and wb "
                                  f"({type(exc).__name__}: {exc})") from None
        if wk.shape != (tk.size, 3):
            raise FileFormatError(str(p), f"wb has shape {wk.shape}, expected ({tk.size}, 3)",
                                  field="wb")
        t = tk if t is None else t
        if tk.size != t.size:
            raise FileFormatError(str(p), f"{tk.size} samples, imu1 has {t.size}", field="t")
        cols.append(wk)
        names += [f"imu{k}_{a}" for a in "xyz"]
    return t, np.hstack(cols), tuple(names)


def load_adis16405(folder: str | Path) -> tuple[float, np.ndarray]:
    """Sample rate (Hz) and gyro rates (N, 3) rad/s of ``adis_16405_imu1.rda`` (deg/s in file)."""
    import warnings

    import rdata

    p = Path(folder) / "adis_16405_imu1.rda"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            obj = rdata.conversion.convert(rdata.parser.parse_file(p))["adis_16405_imu1"]
        a = np.asarray(obj, float)
    except (OSError, KeyError, ValueError) as exc:
        raise FileFormatError(str(p), f"expected the R matrix adis_16405_imu1 "
                              f"({type(exc).__name__}: {exc})") from None
    if a.ndim != 2 or a.shape[1] != 6:
        raise FileFormatError(str(p), f"shape {a.shape}, expected (N, 6)")
    return 100.0, a[:, :3] * DPS


MPU9250_SCALE_FACTOR_TOLERANCE = 0.03
"""Gyro sensitivity tolerance of the MPU9250 (datasheet: ±3 % at 25 °C)."""
MPU9250_CROSS_AXIS = 0.02
"""Cross-axis sensitivity of the MPU9250 (datasheet: ±2 %)."""
PREDICTION_BLOCKS = 8
"""Blocks whose means give the bias's scatter over the part (``bias_prediction``)."""


def static_calibration(y: np.ndarray, fs: float, names: tuple[str, ...],
                       *, allan: bool = True, drift_bias_sd: bool = False,
                       scale_factor_tolerance: float = 0.0, cross_axis: float = 0.0,
                       bias_prediction: bool = False, tails: bool = False,
                       drift: bool = False) -> Calibration:
    """A calibration of static channels (N, n) rad/s: aligned triads, SF 1, bias = mean.

    The measurement harness of ``docs/drift.md`` and ``docs/noise-tails.md`` (bare arrays,
    every choice a switch, so their before/after tables stay reproducible). A set at rest
    is calibrated for use by ``rimu calibrate static``
    (:func:`calibration.inflight.static.calibrate_static`: alignment from gravity and the
    shared motion, shocks left out, the range covered); both fit the residual's tail and
    drift models with the same code.

    ``bias_sd`` is the standard error of the mean, or with ``drift_bias_sd`` the Allan
    deviation at the longest τ of the part (the in-run bias wander the mean cannot
    follow), which the monitor's bias-uncertainty inflation (1 + w·β/f_w) then carries.

    At rest neither the scale factors nor the axes are observable. ``scale_factor_tolerance``
    and ``cross_axis`` state them a priori (the datasheet's tolerances, e.g.
    :data:`MPU9250_SCALE_FACTOR_TOLERANCE`) as the input-error covariance, so that the
    monitor's thresholds widen when the bench moves. ``bias_prediction`` takes the bias
    uncertainty as the scatter of :data:`PREDICTION_BLOCKS` block means times
    sqrt(1 + 1/B) (the spread of the bias in a later stretch of the same length, drift
    included), at least the other choices.

    ``tails`` measures the residual's tail model (:func:`calibration.tails.fit_tail_model`)
    relative to the monitor's threshold inflation of this calibration (ρ, κ, β of
    :func:`fdi.reconstruction.inflation_terms`), as the in-flight calibration does;
    ``drift`` measures the slow drift of its whitened parity
    (:func:`calibration.drift.fit_drift_model`, ``docs/drift.md``), which ``tune`` turns
    into the drift expected over its horizon. Both come from ``y`` alone.
    """
    y = np.asarray(y, float)
    n = y.shape[1]
    if n % 3:
        raise ValueError("channels must come in triads")
    mean = y.mean(axis=0)
    cov = np.cov(y, rowvar=False)
    sd = np.sqrt(np.diag(cov))
    table = allan_from_residuals(y - mean, fs) if (allan or drift_bias_sd) else None
    bsd = sd / math.sqrt(y.shape[0])
    if drift_bias_sd and table is not None:
        bsd = np.maximum(bsd, table.adev[-1])
    if bias_prediction:
        blocks = np.array_split(np.arange(y.shape[0]), PREDICTION_BLOCKS)
        bm = np.array([y[b].mean(axis=0) for b in blocks])
        bsd = np.maximum(bsd, bm.std(axis=0, ddof=1) * math.sqrt(1 + 1 / PREDICTION_BLOCKS))
    sensors = []
    for i in range(n):
        ax = np.eye(3)[i % 3]
        C = 1e-12 * np.eye(3)
        if scale_factor_tolerance or cross_axis:
            C = (scale_factor_tolerance**2 * np.outer(ax, ax)
                 + cross_axis**2 * (np.eye(3) - np.outer(ax, ax)) + C)
        sensors.append(SensorCal(name=names[i], axis=ax, axis_nominal=ax.copy(),
                                 scale_factor=1.0,
                                 scale_factor_sd=max(scale_factor_tolerance, 1e-6),
                                 bias=float(mean[i]), bias_sd=float(bsd[i]),
                                 input_error_cov=C, raw_unit="rad/s",
                                 scale_factor_unit="(rad/s)/raw", bias_unit="rad/s",
                                 residual_rms=float(sd[i])))
    table = table if allan else None
    groups = tuple(tuple(range(k, k + 3)) for k in range(0, n, 3))
    gs = SensorSet("gyro", tuple(sensors), cov, groups, tuple(np.eye(3) for _ in groups),
                   table)
    resid = y - mean
    if tails or drift:
        from calibration.residual_models import with_residual_models

        gs = with_residual_models(gs, resid, y, fs, tails=tails, drift=drift,
                                  source="static residual (y - mean)")
    return Calibration("static", {"gyro": gs}, fs, extra={"source": "static recording"})


def noise_shape(y: np.ndarray, fs: float, *, split: float = 0.5) -> dict[str, Any]:
    """How far static noise (N, n) departs from zero-mean white Gaussian noise."""
    y = np.asarray(y, float)
    N, n = y.shape
    k = int(N * split)
    r = y - y.mean(axis=0)
    sd = r.std(axis=0, ddof=1)
    zs = r / sd
    kurt = stats.kurtosis(r, axis=0, fisher=True)
    over4 = np.mean(np.abs(zs) > 4.0, axis=0)
    gauss4 = 2 * stats.norm.sf(4.0)
    rho1 = np.array([np.corrcoef(r[1:, i], r[:-1, i])[0, 1] for i in range(n)])
    C = np.corrcoef(r, rowvar=False)
    off = np.abs(C - np.eye(n))
    shift = (y[k:].mean(axis=0) - y[:k].mean(axis=0)) / (sd * math.sqrt(1 / k + 1 / (N - k)))
    tab = allan_from_residuals(r, fs)
    white = sd[None, :] / np.sqrt(tab.tau_s[:, None] * fs)
    ratio = tab.adev / white
    return {"samples": N, "channels": n, "sample_rate_hz": fs,
            "sd": sd.tolist(), "excess_kurtosis": kurt.tolist(),
            "beyond_4sigma": over4.tolist(), "beyond_4sigma_gaussian": gauss4,
            "lag1_autocorrelation": rho1.tolist(),
            "max_cross_correlation": float(off.max()) if n > 1 else 0.0,
            "bias_shift_in_standard_errors": shift.tolist(),
            "allan_ratio_to_white": {"tau_s": tab.tau_s.tolist(),
                                     "median_over_channels": np.median(ratio, axis=1).tolist()}}


def _holdout_rate(cal: Calibration, thr: Any, t: np.ndarray, y: np.ndarray,
                  alpha_ref: tuple[float, ...]) -> tuple[int, float, list[float], float, float]:
    """Detection episodes, hours, per scale the exceedance fraction over ``alpha_ref``
    (the Gaussian design), the fraction of samples with any statistic over its threshold,
    and the time of the first alarm (s)."""
    from fdi.monitor import Monitor
    from fdi.settings import MonitorSettings

    mon = Monitor(cal, thr, settings=MonitorSettings(persistence=1 << 30))
    res = mon.run(t - t[0], y)
    n = sum(e.type == "detected" for e in res.events)
    with np.errstate(invalid="ignore"):
        exc = np.nanmean(np.where(np.isfinite(res.statistics),
                                  res.statistics > res.thresholds, np.nan), axis=0)
    ratio = [float(e / a) for e, a in zip(exc, alpha_ref, strict=False)]
    anyx = np.any(res.statistics > res.thresholds, axis=1)
    first = float(res.t[np.argmax(anyx)]) if anyx.any() else math.inf
    return n, float(t[-1] - t[0]) / 3600.0, ratio, float(anyx.mean()), first


def tail_thresholds(cal: Calibration, thr: Any, t: np.ndarray, y: np.ndarray, *,
                    tail_fraction: float = 0.02) -> Any:
    """Thresholds whose levels come from the empirical tail of healthy data (peaks over
    threshold), never below the Gaussian ones.

    The monitor runs over the healthy samples ``y`` (isolation off); for each scale the
    largest ``tail_fraction`` of its statistic D_w are fitted with a generalised Pareto
    distribution (``scipy.stats.genpareto``, location at the empirical quantile), whose
    level exceeded with probability ``alpha_w`` becomes the threshold; it is written back
    as the χ² tail probability the monitor turns into that threshold. Running means are
    correlated, so the long windows' fits rest on fewer independent values than samples.
    """
    from fdi.detector import chi2_threshold
    from fdi.monitor import Monitor
    from fdi.settings import MonitorSettings
    from thresholds.tune import _parity_geometry

    mon = Monitor(cal, thr, settings=MonitorSettings(persistence=1 << 30))
    res = mon.run(t - t[0], y)
    df, _, beta, _, _ = _parity_geometry(cal, thr.kind)
    alphas = []
    for k, (w, a, f) in enumerate(zip(thr.scales, thr.alpha, thr.variance_factor,
                                      strict=True)):
        d = res.statistics[:, k]
        d = d[np.isfinite(d)]
        u = float(np.quantile(d, 1.0 - tail_fraction))
        exc = d[d > u] - u
        c, _, scale = stats.genpareto.fit(exc, floc=0.0)
        level = u + float(stats.genpareto.isf(min(a / tail_fraction, 0.5), c, 0.0, scale))
        gauss = chi2_threshold(a, df)
        emp = level / (1.0 + w * beta / f)
        alphas.append(float(stats.chi2.sf(emp, df)) if emp > gauss else a)
    return replace(thr, alpha=tuple(alphas),
                   threshold=tuple(chi2_threshold(x, df) for x in alphas),
                   notes=thr.notes + "; levels from the empirical tail (generalised Pareto)")


def static_holdout(t: np.ndarray, y: np.ndarray, names: tuple[str, ...], *,
                   false_alarms_per_hour: float = 60.0, fraction: float = 0.5,
                   simulate_hours: float = 1.0) -> dict[str, Any]:
    """Tune on the first ``fraction`` of a static recording, count false alarms on the rest.

    Returns the held-out rate of the tuned thresholds (Allan variance factors, full noise
    covariance) and of white-noise thresholds (no Allan table), with Poisson intervals, and
    :func:`noise_shape` of both parts.
    """
    from thresholds.evaluate import poisson_interval
    from thresholds.tune import tune

    t = np.asarray(t, float)
    y = np.asarray(y, float)
    fs = (t.size - 1) / float(t[-1] - t[0])
    k = int(t.size * fraction)
    out: dict[str, Any] = {"target_per_hour": false_alarms_per_hour, "fraction": fraction,
                           "sample_rate_hz": fs, "tuning_s": float(t[k - 1] - t[0]),
                           "held_out_s": float(t[-1] - t[k])}
    for label, allan, drift, tail in (("tuned_allan", True, False, False),
                                      ("white", False, False, False),
                                      ("drift_aware", True, True, False),
                                      ("drift_and_tail_aware", True, True, True)):
        cal = static_calibration(y[:k], fs, names, allan=True, drift_bias_sd=drift)
        thr = tune(cal, false_alarms_per_hour=false_alarms_per_hour,
                   simulate_hours=simulate_hours).thresholds
        if not allan:
            thr = replace(thr, variance_factor=tuple(1.0 for _ in thr.scales))
        design = thr.alpha
        if tail:
            thr = tail_thresholds(cal, thr, t[:k], y[:k])
        n, h, exceed, busy, first = _holdout_rate(cal, thr, t[k:], y[k:], design)
        lo, hi = poisson_interval(n, h)
        out[label] = {"false_alarms": n, "hours": h, "per_hour": n / h,
                      "ci95_per_hour": [lo, hi], "ratio_to_target": n / h / false_alarms_per_hour,
                      "time_in_alarm_fraction": busy, "first_alarm_s": first,
                      "variance_factor": list(thr.variance_factor),
                      "exceedance_over_alpha_per_scale": exceed}
    out["noise_tuning_part"] = noise_shape(y[:k], fs)
    out["noise_held_out_part"] = noise_shape(y[k:], fs)
    out["bias_shift_between_parts"] = noise_shape(y, fs, split=fraction)[
        "bias_shift_in_standard_errors"]
    return out
