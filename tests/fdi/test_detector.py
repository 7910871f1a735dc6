"""Detection arithmetic: chi-square thresholds, Allan variance factors, CUSUM threshold, and
the empirical false-alarm rate of each scale's statistic on simulated healthy data."""

from __future__ import annotations

import numpy as np
from scipy import special, stats

from fdi.calfile import AllanTable
from fdi.detector import (
    alpha_per_sample,
    chi2_threshold,
    cusum_threshold,
    default_thresholds,
    minimum_detectable_noncentrality,
    variance_factors,
)
from fdi.monitor import Monitor
from fdi.settings import MonitorSettings
from studies.synthetic import raw_samples, synthetic_calibration


def test_chi2_threshold_small_alpha_against_closed_forms():
    """Closed forms, not the scipy call it wraps: χ²(2) tail exp(−T/2), so T = −2 ln α;
    χ²(1) = N(0,1)², so T = (Φ⁻¹(α/2))² (from erfcinv). Down to α = 1e-20, where
    ``ppf(1 − α)`` would be inf."""
    for alpha in (1e-3, 1e-9, 1e-20):
        np.testing.assert_allclose(chi2_threshold(alpha, 2), -2.0 * np.log(alpha), rtol=1e-10)
        np.testing.assert_allclose(chi2_threshold(alpha, 1), 2.0 * special.erfcinv(alpha) ** 2,
                                   rtol=1e-10)
    assert chi2_threshold(0.5, 0) == np.inf
    assert alpha_per_sample(1e-3, 100.0) == 1e-3 / 360000.0


def test_variance_factors_white_and_coloured():
    fs, sd = 100.0, 1e-3
    tau = 2.0 ** np.arange(12) / fs
    white = AllanTable(tau, np.full((12, 2), sd) / np.sqrt(tau[:, None] * fs))
    np.testing.assert_allclose(variance_factors(white, np.eye(2) * sd**2, fs, (1, 8, 512)), 1.0)
    # a flicker floor at sd/20: the mean of 512 samples varies more than white noise says
    floor = np.sqrt(white.adev**2 + (sd / 20) ** 2)
    f = variance_factors(AllanTable(tau, floor), np.eye(2) * sd**2, fs, (1, 8, 512))
    expect = (floor[[0, 3, 9], 0] ** 2 * np.array([1, 8, 512])) / sd**2
    np.testing.assert_allclose(f, np.maximum(expect, 1.0), rtol=1e-9)
    assert f[2] > 2.0


def test_minimum_detectable_noncentrality_gives_the_missed_detection():
    T = chi2_threshold(1e-9, 3)
    lam = minimum_detectable_noncentrality(T, 3, 1e-3)
    assert abs(stats.ncx2.cdf(T, 3, lam) - 1e-3) < 1e-9


def test_cusum_threshold_matches_simulated_false_alarm_rate():
    """One-sided CUSUM, ν = 0.5, designed for 2e-3 alarms per sample (Siegmund)."""
    h = cusum_threshold(2e-3, 0.5, 1)
    x = np.random.default_rng(0).standard_normal(200_000)
    g, alarms = 0.0, 0
    for v in x - 0.5:                                       # restart after each alarm
        g = max(0.0, g + v)
        if g > h:
            alarms += 1
            g = 0.0
    rate = alarms / x.size
    assert abs(rate / 2e-3 - 1.0) < 0.25, rate


def test_each_scale_false_alarm_rate_matches_its_alpha():
    """Healthy white noise, exact calibration: per-sample exceedance of each scale ≈ alpha
    (tolerance: 4 binomial σ, inflated by √w for the correlation of running means)."""
    cal = synthetic_calibration("cone6", seed=4, bias_uncertainty=0.0, input_error_sd=0.0,
                                noise_sd_spread=0.4)
    alpha = 0.01
    scales = (1, 4, 16)
    th = default_thresholds(cal, scales=scales,
                            false_alarms_per_hour=alpha * len(scales) * 3600 * 100.0)
    np.testing.assert_allclose(th.alpha, alpha)
    N = 30_000
    raw = raw_samples(cal, np.tile([0.3, -0.2, 0.1], (N, 1)), seed=5)
    mon = Monitor(cal, th, settings=MonitorSettings(persistence=10**9, clear_samples=1))
    res = mon.run(np.arange(N) / 100.0, raw)
    assert res.healthy.all()
    for k, w in enumerate(scales):
        st = res.statistics[w:, k]
        rate = float(np.mean(st > res.thresholds[w:, k]))
        tol = 4 * np.sqrt(alpha * (1 - alpha) / st.size) * np.sqrt(w)
        assert abs(rate - alpha) < tol, (w, rate)
        # and the statistic is χ²(3) in the bulk: mean 3
        assert abs(st.mean() - 3.0) < 4 * np.sqrt(6.0 * w / st.size), (w, st.mean())
