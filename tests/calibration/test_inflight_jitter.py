"""Timing jitter of an IMU against the reference, estimated by the in-flight calibration.

Truth from simulated two-IMU flights (replay.imu_set) with a known random sampling-time
error on imu2 (δt ~ N(0, τ²) per sample, on top of a constant offset): τ is recovered
within its sd, the sd is honest (Monte Carlo spread of error/sd near 1, --slow), next to
nothing is found where there is none, and the calibration file carries it per sensor.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from calibration.inflight.calfile import calibration_from_fit
from calibration.inflight.fit import fit_inflight
from calibration.inflight.jitter import fit_timing_jitter
from replay.imu_set import ImuSetSpec, simulate_imu_set

TAU = 2e-3
Z3 = 2 * stats.norm.sf(3)


def _fit(seed: int, tau: float, duration_s: float = 60.0):
    f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=duration_s, seed=seed,
                                    time_offset_s=(0.0, 3e-3), timing_jitter_s=(0.0, tau)))
    fit = fit_inflight(f)
    return f, fit, fit.alignments["imu2"]


def test_jitter_recovered_within_3_sd_and_written_per_sensor():
    f, fit, a = _fit(101, TAU)
    true = f.truth["relative_to_reference"]["imu2"]["timing_jitter_s"]
    assert true == pytest.approx(TAU)
    assert abs(a.timing_jitter_s - true) < 3 * a.timing_jitter_sd_s, (a.timing_jitter_s,
                                                                       a.timing_jitter_sd_s)
    assert 0 < a.timing_jitter_sd_s < 0.2 * TAU                  # resolved, not a bound
    cal = calibration_from_fit(fit, f, tails=False)
    jit = [c.timing_jitter for c in cal.gyro.sensors]
    assert jit[:3] == [0.0, 0.0, 0.0]                            # the reference
    assert jit[3:] == [a.timing_jitter_s] * 3
    assert cal.extra["inflight"]["imus"]["imu2"]["timing_jitter_ms"] == pytest.approx(
        a.timing_jitter_s * 1e3)


APPARENT = 0.1e-3
"""Without any jitter the fit still sees a little growth of the residual with the motion
(the cubic spline that reads the reference between its samples errs most where the rate
changes fast): an apparent τ of at most 0.072 ms in 30 simulated flights at 50 Hz. Bound:
5 % of the 2 ms injected."""


def test_no_jitter_found_without_one():
    _, _, a = _fit(102, 0.0)
    assert a.timing_jitter_s < APPARENT, (a.timing_jitter_s, a.timing_jitter_sd_s)


def test_fit_timing_jitter_on_the_model_itself():
    """Residuals drawn from N(0, Σ + τ²aaᵀ) with heavy-tailed a: τ within 3 sd, Σ close."""
    rng = np.random.default_rng(5)
    N = 20000
    a = rng.standard_t(3, size=(N, 3)) * 5.0                     # rad/s²
    L = np.array([[1.0, 0, 0], [0.3, 0.8, 0], [0.1, -0.2, 0.6]]) * 1e-2
    tau = 1.5e-3
    r = rng.standard_normal((N, 3)) @ L.T + a * (tau * rng.standard_normal(N))[:, None]
    j = fit_timing_jitter(r, a)
    assert abs(j.tau_s - tau) < 3 * j.tau_sd_s, (j.tau_s, j.tau_sd_s)
    np.testing.assert_allclose(j.noise_cov, L @ L.T, rtol=0.1, atol=2e-6)


def test_too_few_samples_give_nan():
    j = fit_timing_jitter(np.zeros((10, 3)), np.ones((10, 3)))
    assert np.isnan(j.tau_s) and j.samples == 10


@pytest.mark.slow
def test_jitter_sd_is_honest_monte_carlo():
    """30 flights with τ = 2 ms: error/sd has mean ≈ 0 and spread ≈ 1; 30 without: the
    apparent jitter stays below :data:`APPARENT` in every one."""
    z, apparent = [], []
    for seed in range(30):
        f, _, a = _fit(seed, TAU)
        true = f.truth["relative_to_reference"]["imu2"]["timing_jitter_s"]
        z.append((a.timing_jitter_s - true) / a.timing_jitter_sd_s)
        _, _, b = _fit(seed, 0.0)
        apparent.append(b.timing_jitter_s)
    z = np.array(z)
    assert np.sum(np.abs(z) > 3) <= stats.binom.isf(1e-3, z.size, Z3)
    assert abs(z.mean()) < 4 / np.sqrt(z.size)
    assert 0.7 < z.std() < 1.35                     # 30 values: sd of the sd ≈ 0.13
    assert max(apparent) < APPARENT, apparent
