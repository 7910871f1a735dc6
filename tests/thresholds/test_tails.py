"""The residual tail model: the monitor's statistic, the overbound, the file, the thresholds.

The statistical test draws a residual of known heavy tail (Student-t, ν = 3, per sensor),
fits the tail model on 5·10⁴ samples and counts exceedances of 5·10⁵ fresh samples: the
overbound's thresholds hold the per-sample exceedance probability (within the exact
Poisson interval of the count), the Gaussian model's do not.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from calibration.tails import fit_tail_model, whitened_parity, window_statistics
from fdi.calfile import load_calibration
from fdi.detector import default_thresholds
from fdi.errors import FileFormatError
from fdi.tails import ScaleTail, overbound_factor, tail_variance_factors
from studies.realnoise import static_calibration

H2 = np.vstack([np.eye(3), np.eye(3)])
NAMES = tuple(f"imu{k}_{a}" for k in (1, 2) for a in "xyz")


def _t_noise(rng: np.random.Generator, N: int, nu: float = 3.0, sd: float = 0.01):
    return rng.standard_t(nu, size=(N, 6)) * sd


def _cal_with_tails(y: np.ndarray, fs: float = 100.0):
    cal = static_calibration(y, fs, NAMES)
    s = cal.gyro
    model = fit_tail_model(y - y.mean(axis=0), s.H, s.noise_covariance, fs,
                           scales=(1, 2, 4, 8), source="test")
    return replace(cal, sets={"gyro": replace(s, tails=model)})


def test_statistic_is_the_monitors():
    from fdi.monitor import Monitor
    from fdi.settings import MonitorSettings

    rng = np.random.default_rng(3)
    y = rng.normal(0.0, 0.01, (600, 6))
    cal = static_calibration(y, 100.0, NAMES, allan=False)
    thr = default_thresholds(cal, scales=(1, 2, 4, 8))
    assert thr.variance_factor == (1.0, 1.0, 1.0, 1.0)
    res = Monitor(cal, thr, settings=MonitorSettings(persistence=1 << 30)).run(
        np.arange(600) / 100.0, y)
    z, v = whitened_parity(y - cal.gyro.biases, cal.gyro.H, cal.gyro.noise_covariance)
    for k, w in enumerate(thr.scales):
        S, end, _ = window_statistics(z, v, w)
        np.testing.assert_allclose(res.statistics[end, k], S, rtol=1e-9, atol=1e-12)


def test_factor_arithmetic_on_a_known_curve():
    p = 10.0 ** -np.arange(1.0, 10.5, 0.5)
    tail = ScaleTail(scale=1, windows=10, independent=10, variance_ratio=1.0,
                     excess_kurtosis=5.0, kurtosis_p=0.0, exceedance_p=0.0, gaussian=False,
                     probability=tuple(p), quantile=tuple(np.full(p.size, np.nan)),
                     quantile_upper=tuple(2.5 * stats.chi2.isf(p, 3)),
                     source=("empirical",) * p.size)
    for a in (1e-2, 3e-5, 1e-9, 1e-12):            # 1e-12: beyond the table, last slope
        assert overbound_factor(tail, a, 3) == pytest.approx(2.5, rel=0.05)
    f, why = tail_variance_factors(None, (1,), (1e-6,), (1.7,))
    assert f == (1.7,) and why[0].choice == "gaussian-white"


def test_gaussian_residual_passes_and_keeps_todays_thresholds():
    rng = np.random.default_rng(11)
    cal = _cal_with_tails(rng.normal(0.0, 0.01, (40_000, 6)))
    assert all(s.gaussian for s in cal.gyro.tails.scales)
    before = default_thresholds(replace(cal, sets={"gyro": replace(cal.gyro, tails=None)}),
                                scales=(1, 2, 4, 8))
    after = default_thresholds(cal, scales=(1, 2, 4, 8))
    assert after.variance_factor == before.variance_factor
    assert after.noise_model == "gaussian-white"


def test_student_t_overbound_holds_the_rate_where_the_gaussian_model_does_not():
    rng = np.random.default_rng(2026)
    cal = _cal_with_tails(_t_noise(rng, 50_000))
    model = cal.gyro.tails
    assert not any(s.gaussian for s in model.scales)
    assert all(s.excess_kurtosis > 1.0 for s in model.scales[:2])
    z, v = whitened_parity(_t_noise(rng, 500_000), cal.gyro.H, cal.gyro.noise_covariance)
    alpha = 1e-4
    T = stats.chi2.isf(alpha, model.df)
    for rec in model.scales:
        S, _, _ = window_statistics(z, v, rec.scale)
        f = overbound_factor(rec, alpha, model.df)
        n = S.size
        over = int(np.sum(S / f > T))
        gauss = int(np.sum(S > T))
        # exact Poisson 99 % upper limit of the count expected at alpha, in independent
        # windows (overlapping running means: counts in units of n/w)
        m = alpha * n / rec.scale
        hi = stats.chi2.ppf(0.99, 2 * (m + 1)) / 2
        assert over / rec.scale <= hi, (rec.scale, over, alpha * n)
        assert gauss / rec.scale > 5 * hi, (rec.scale, gauss, alpha * n)
    thr = default_thresholds(cal, scales=(1, 2, 4, 8), false_alarms_per_hour=36.0)
    assert thr.noise_model == "overbound"
    assert min(thr.variance_factor) > 2.0


def test_file_round_trip_fingerprint_and_bad_field(tmp_path):
    rng = np.random.default_rng(5)
    cal = _cal_with_tails(_t_noise(rng, 20_000))
    p = tmp_path / "cal.json"
    cal.save(p)
    doc = json.loads(p.read_text())
    assert doc["schema"] == "rimu.calibration/3" and "gyro" in doc["residual_tails"]
    back = load_calibration(p)
    assert back.gyro.tails == cal.gyro.tails
    assert back.fingerprint() == cal.fingerprint() and len(cal.fingerprint()) == 16
    moved = replace(cal, sets={"gyro": replace(cal.gyro, noise_covariance=1.01
                                               * cal.gyro.noise_covariance)})
    assert moved.fingerprint() != cal.fingerprint()
    thr = default_thresholds(back)
    assert thr.calibration_fingerprint == cal.fingerprint()
    # a /2 file (no residual_tails) still loads, and keeps its fingerprint when migrated
    old = dict(doc)
    old["schema"] = "rimu.calibration/2"
    del old["residual_tails"]
    (tmp_path / "old.json").write_text(json.dumps(old))
    o = load_calibration(tmp_path / "old.json")
    assert o.gyro.tails is None
    # a bad field is named
    bad = json.loads(p.read_text())
    bad["residual_tails"]["gyro"]["scales"][1]["probability"][2] = 0.9
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(FileFormatError) as ei:
        load_calibration(tmp_path / "bad.json")
    assert ei.value.field == "residual_tails.gyro.scales[2].probability"
    bad = json.loads(p.read_text())
    bad["residual_tails"]["gyro"]["scales"][0]["gpd"]["scale_param"] = -1.0
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(FileFormatError) as ei:
        load_calibration(tmp_path / "bad.json")
    assert ei.value.field == "residual_tails.gyro.scales[1].gpd.scale_param"
    assert math.isfinite(thr.variance_factor[0])


def test_tune_prints_the_choice_and_writes_fingerprint_and_noise_model(tmp_path, capsys):
    from fdi.settings import load_thresholds
    from replay.threshold_choice import load_any_thresholds
    from rimu.cli import main

    rng = np.random.default_rng(8)
    heavy = _cal_with_tails(_t_noise(rng, 20_000))
    white = _cal_with_tails(rng.normal(0.0, 0.01, (20_000, 6)))
    for cal, want in ((heavy, "overbound f="), (white, "gaussian white: passes")):
        p = tmp_path / "cal.json"
        cal.save(p)
        out = tmp_path / "t.json"
        assert main(["tune", "--cal", str(p), "--false-alarms-per-hour", "60",
                     "--simulate-hours", "0", "--scales", "1,2,4,8", "--out", str(out)]) == 0
        text = capsys.readouterr().out
        assert "scale 1: " + want in text, text
        thr, _, ass = load_any_thresholds(out)
        assert thr.calibration_fingerprint == cal.fingerprint()
        assert thr.noise_model == ("overbound" if cal is heavy else "gaussian-white")
        assert len(ass["residual_tails"]["per_scale"]) == 4
        plain = tmp_path / "plain.json"
        thr.save(plain)
        back = load_thresholds(plain)
        assert (back.calibration_fingerprint, back.noise_model, back.variance_factor) == (
            thr.calibration_fingerprint, thr.noise_model, thr.variance_factor)


@pytest.mark.slow
def test_overbound_coverage_over_repeated_fits():
    """30 independent fits (Student-t ν = 3, 2·10⁴ samples), w = 1 and 4, α = 1e-3 (in the
    data), 1e-4 and 1e-5 (the GPD extrapolation): the held-out exceedance probability of the
    overbound threshold (from 4·10⁶ fresh samples) exceeds α in at most as many of the 180
    cases as a 95 % bound allows (Binomial(180, 0.05), 99.9 % upper limit)."""
    H = H2
    nu = 3.0
    cov = np.eye(6) * 0.01**2 * nu / (nu - 2)
    rng = np.random.default_rng(99)
    z, v = whitened_parity(_t_noise(rng, 4_000_000, nu), H, cov)
    big = {w: np.sort(window_statistics(z, v, w)[0]) for w in (1, 4)}
    over = cases = 0
    for _ in range(30):
        m = fit_tail_model(_t_noise(rng, 20_000, nu), H, cov, 100.0, scales=(1, 4))
        for rec in m.scales:
            s = big[rec.scale]
            for a in (1e-3, 1e-4, 1e-5):
                x = overbound_factor(rec, a, 3) * stats.chi2.isf(a, 3)
                p = 1.0 - np.searchsorted(s, x) / s.size
                over += int(p > a)
                cases += 1
    assert cases == 180
    assert over <= stats.binom.isf(0.001, cases, 0.05), over


def test_statistic_relative_to_the_monitors_inflation():
    """With the calibration's ρ (calibration uncertainty and timing jitter), κ and β, the
    statistic the tail model fits is the monitor's D_w over its inflation T_w/thr_w, sample
    for sample, and the tail model's scales see exactly those values."""
    from fdi.monitor import Monitor
    from fdi.reconstruction import inflation_terms
    from fdi.settings import MonitorSettings

    rng = np.random.default_rng(4)
    N, fs = 800, 100.0
    t = np.arange(N) / fs
    om = np.column_stack([2.0 * np.sin(2 * np.pi * f * t) for f in (0.7, 1.3, 2.1)])
    y = np.hstack([om, om]) + rng.normal(0.0, 0.01, (N, 6))
    cal = static_calibration(y - np.hstack([om, om]), fs, NAMES, allan=False)
    s = cal.gyro
    sensors = tuple(replace(c, input_error_cov=1e-6 * np.eye(3), bias_sd=1e-3,
                            timing_jitter=2e-3 if k >= 3 else 0.0)
                    for k, c in enumerate(s.sensors))
    cal = replace(cal, sets={"gyro": replace(s, sensors=sensors)})
    s = cal.gyro
    thr = default_thresholds(cal, scales=(1, 2, 4, 8))
    res = Monitor(cal, thr, settings=MonitorSettings(persistence=1 << 30)).run(t, y)
    rho, kappa, beta = inflation_terms(
        s.H, s.scale_factors, s.biases, s.noise_covariance,
        np.array([c.input_error_cov for c in sensors]), np.array([c.bias_sd for c in sensors]),
        np.array([c.timing_jitter for c in sensors]), fs, y)
    assert beta > 0 and np.median(rho) > 0.1             # both inflations are at work
    z, v = whitened_parity(y - s.biases, s.H, s.noise_covariance)
    cq = np.concatenate([[0.0], np.cumsum(rho)])
    for k, w in enumerate(thr.scales):
        S, end, _ = window_statistics(z, v, w)
        infl = 1.0 + w * beta + kappa * (cq[end + 1] - cq[end + 1 - w])
        base = res.thresholds[end, k][0] / (1.0 + w * beta + kappa * (cq[end[0] + 1]
                                                                     - cq[end[0] + 1 - w]))
        np.testing.assert_allclose(res.thresholds[end, k] / base, infl, rtol=1e-9)
        np.testing.assert_allclose(res.statistics[end, k], S, rtol=1e-9, atol=1e-12)
    m0 = fit_tail_model(y - s.biases, s.H, s.noise_covariance, fs, scales=(1,))
    m1 = fit_tail_model(y - s.biases, s.H, s.noise_covariance, fs, scales=(1,), rho=rho,
                        kappa=kappa, beta=beta)
    S1 = window_statistics(z, v, 1)[0]
    assert m0.scales[0].variance_ratio == pytest.approx(np.mean(S1) / z.shape[1])
    assert m1.scales[0].variance_ratio == pytest.approx(
        np.mean(S1 / (1.0 + beta + kappa * rho)) / z.shape[1])
