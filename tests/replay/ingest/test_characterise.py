"""The residual statistics against simulated truth (fixed seeds)."""

import numpy as np
import pytest

from replay.ingest.characterise import (
    allan,
    excess_kurtosis,
    fit_alignment,
    noise_density,
    noise_from_pairs,
    spectral_lines,
    time_offset,
)


def _motion(rng, t, tau=0.0):
    """Body rates (rad/s) at times t - tau: 20 random sines per axis, 0.1-3 Hz, about
    1 rad/s RMS (evaluated exactly, so a lag is exact)."""
    f = rng.uniform(0.1, 3.0, (20, 3))
    ph = rng.uniform(0, 2 * np.pi, (20, 3))
    amp = rng.uniform(0.1, 0.4, (20, 3))
    tt = (t - tau)[:, None, None]
    return np.sum(amp * np.sin(2 * np.pi * f * tt + ph), axis=1)


def test_time_offset_recovered_within_its_sigma():
    fs, n, tau = 50.0, 6000, 0.005
    z = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        t = np.arange(n) / fs
        state = rng.bit_generator.state
        w = _motion(rng, t)
        rng.bit_generator.state = state
        lag = _motion(rng, t, tau)
        ref = w + rng.normal(0, 0.01, w.shape)
        lag = lag + rng.normal(0, 0.01, w.shape)
        est, _ = time_offset(ref, lag, t)
        z.append((est.value - tau) / est.sd)
    z = np.array(z)
    assert np.all(np.abs(z) < 3.5), z
    assert 0.5 < z.std() < 1.6, z.std()          # σ is honest: spread of err/σ near 1


def test_no_offset_claimed_where_there_is_none():
    fs, n = 50.0, 6000
    rng = np.random.default_rng(7)
    t = np.arange(n) / fs
    w = _motion(rng, t)
    est, res = time_offset(w + rng.normal(0, 0.01, w.shape),
                           w + rng.normal(0, 0.01, w.shape), t)
    assert abs(est.value / est.sd) < 3
    assert np.nanstd(res) < 0.02


def test_alignment_recovers_a_small_rotation():
    rng = np.random.default_rng(1)
    w = _motion(rng, np.arange(5000) / 50.0)
    ang = np.radians(2.0)
    R = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1]])
    ref = w @ R.T + [0.01, 0, 0] + rng.normal(0, 0.001, w.shape)
    al = fit_alignment(ref, w)
    assert al.angle_deg == pytest.approx(2.0, abs=0.01)
    np.testing.assert_allclose(al.scales, 1.0, atol=1e-3)
    assert np.all(al.rms_after < 0.0012) and al.rms_before[0] > 0.02


def test_noise_density_and_allan_of_white_noise():
    fs, sig = 100.0, 0.3
    rng = np.random.default_rng(3)
    x = rng.normal(0, sig, 200_000)
    d = noise_density(x, fs, (1.0, 40.0))
    want = sig / np.sqrt(fs / 2)                 # one-sided density of white noise
    assert abs(d.value - want) < 3 * d.sd
    a = allan(x, fs)
    # σ_A(τ) = N/√τ with N = σ/√fs (two-sided); at τ = 1 s within a few %
    assert a["n_at_1s"] == pytest.approx(sig / np.sqrt(fs), rel=0.05)


def test_spectral_lines_false_alarms_and_a_real_line():
    fs, n = 50.0, 4000
    hits = 0
    for seed in range(40):
        x = np.random.default_rng(seed).normal(0, 1, (n, 3))
        hits += bool(spectral_lines(x, fs, alpha=0.01))
    # family-wise 1 % per record: 40 records, P(≥ 4 hits) < 1e-3 under the binomial
    assert hits <= 3, hits
    rng = np.random.default_rng(99)
    t = np.arange(n) / fs
    x = rng.normal(0, 1, (n, 3))
    x[:, 0] += 0.5 * np.sin(2 * np.pi * 7.3 * t)
    lines = spectral_lines(x, fs)
    assert lines and lines[0]["f_hz"] == pytest.approx(7.3, abs=fs / 256)


def test_noise_from_pairs_and_kurtosis():
    rng = np.random.default_rng(5)
    sig = np.array([0.1, 0.2, 0.15, 0.12])
    common = rng.normal(0, 1, (100_000, 1))         # common input cancels in differences
    x = common + rng.normal(0, 1, (100_000, 4)) * sig
    np.testing.assert_allclose(np.sqrt(noise_from_pairs(x)), sig, rtol=0.02)
    k = excess_kurtosis(rng.normal(0, 1, (50_000, 2)))
    assert np.all(np.abs(k.value) < 3 * k.sd + 1e-12)
    k = excess_kurtosis(rng.standard_t(5, (50_000, 1)))      # t5: excess kurtosis 6
    assert k.value[0] > 3
