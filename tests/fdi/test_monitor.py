"""Streaming monitor: parity cache, step/run identity, isolation sequence, reconstruction,
magnitude, protection level. Truth comes from raw samples simulated from a true model."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fdi.detector import default_thresholds
from fdi.errors import ConfigError
from fdi.monitor import Monitor
from fdi.settings import MonitorSettings
from studies.synthetic import draw_truth, raw_samples, synthetic_calibration

FS = 100.0


def manoeuvre(N: int, seed: int, amp: float = 3.0) -> np.ndarray:
    """Smooth body rates (N, 3), rad/s, with |ω| up to ``amp`` (reached now and then)."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) / FS
    f = rng.uniform(0.05, 0.5, 3)
    ph = rng.uniform(0, 2 * np.pi, 3)
    om = np.sin(2 * np.pi * f[None, :] * t[:, None] + ph[None, :])
    return amp / np.sqrt(3.0) * om


def scenario(cfg: str, N: int, faults: list[tuple[int, int, float]], seed: int = 0,
             cal_seed: int = 1) -> tuple:
    """(cal, t, raw, omega_true); faults = [(sensor 1-based, onset row, size in sigma)]."""
    cal = synthetic_calibration(cfg, seed=cal_seed)
    n = cal.gyro.n
    om = manoeuvre(N, seed)
    f = np.zeros((N, n))
    sd = cal.gyro.noise_sd
    for s, row, size in faults:
        f[row:, s - 1] += size * sd[s - 1]
    raw = raw_samples(cal, om, seed=seed + 100, truth=draw_truth(cal, seed=seed + 7), fault=f)
    return cal, np.arange(N) / FS, raw, om


def with_jitter(cal, seed: int = 0, lo: float = 0.2e-3, hi: float = 1e-3):
    """The calibration with a random timing jitter τ (s) on every gyro but the first (the
    reference): the thresholds then move with the reconstructed angular acceleration."""
    rng = np.random.default_rng(seed)
    sensors = tuple(dataclasses.replace(c, timing_jitter=0.0 if k == 0 else
                                        float(rng.uniform(lo, hi)))
                    for k, c in enumerate(cal.gyro.sensors))
    return dataclasses.replace(cal, sets=dict(cal.sets, gyro=dataclasses.replace(
        cal.gyro, sensors=sensors)))


def assert_identical(answers, res) -> None:
    """Every array and the event list of stepping equal the block result, bit for bit."""
    for name in ("omega", "omega_sd", "healthy", "statistics", "thresholds"):
        np.testing.assert_array_equal(np.array([getattr(a, name) for a in answers]),
                                      getattr(res, name), err_msg=name)
    np.testing.assert_array_equal(np.array([a.protection_level for a in answers]),
                                  res.protection_level, err_msg="protection_level")
    np.testing.assert_array_equal(np.array([a.parity for a in answers]), res.parity,
                                  err_msg="parity")
    assert [a.capability for a in answers] == list(res.capability)
    assert [e for a in answers for e in a.events] == res.events


def test_parity_of_every_cached_set_annihilates_calibrated_axes():
    cal = synthetic_calibration("cone6", seed=3)
    mon = Monitor(cal)
    mon.cache.precompute(3)
    H = cal.gyro.H
    Sig = cal.gyro.noise_covariance
    assert len(mon.cache) == 1 + 6 + 15 + 20
    for mask in mon.cache.masks():
        mdl = mon.cache.get(mask)
        if mdl.df == 0:
            continue
        np.testing.assert_allclose(mdl.V @ H, 0.0, atol=1e-12, err_msg=f"mask {mask:06b}")
        W = mdl.A @ mdl.V @ Sig @ mdl.V.T @ mdl.A.T
        np.testing.assert_allclose(W, np.eye(mdl.df), atol=1e-9, err_msg=f"mask {mask:06b}")
        np.testing.assert_allclose(mdl.G @ H, np.eye(3), atol=1e-12, err_msg=f"mask {mask:06b}")
        off = [i for i in range(6) if not (mask >> i) & 1]
        np.testing.assert_array_equal(mdl.V[:, off], 0.0)


@pytest.mark.parametrize("detector", ["windows", "cusum", "both"])
@pytest.mark.parametrize("cfg", ["cone6", "tetrad"])
def test_step_and_run_are_bit_identical(cfg, detector):
    faults = [(3, 700, 8.0), (5, 1400, -10.0), (1, 2100, 12.0)] if cfg == "cone6" else \
        [(2, 700, 9.0)]
    cal, t, raw, _ = scenario(cfg, 3000, faults, seed=4)
    valid = np.ones(raw.shape, bool)
    valid[300, 1] = False                       # a missing sample
    valid[900:903, 3] = False
    raw[2500:, 5 if cfg == "cone6" else 3] = raw[2500, 5 if cfg == "cone6" else 3]  # stuck
    th = default_thresholds(cal, detector=detector)
    a = Monitor(cal, th)
    answers = [a.step(t[i], raw[i], valid[i]) for i in range(len(t))]
    b = Monitor(cal, th)
    res = b.run(t, raw, valid, parity=True, chunk=257)
    assert_identical(answers, res)
    assert any(e.type == "detected" for e in res.events)


def apply_random_faults(cal, raw, faults):
    """Apply ``faults`` [(sensor 1-based, row, size in noise sd, kind)] to ``raw`` in place
    (kinds: step, nan, miss (20 samples invalid), stuck, spike (50 × size)); returns the
    validity mask."""
    valid = np.ones(raw.shape, bool)
    sd = cal.gyro.noise_sd / cal.gyro.scale_factors
    for s, row, size, kind in faults:
        i = s - 1
        if kind == "step":
            raw[row:, i] += size * sd[i]
        elif kind == "nan":
            raw[row, i] = np.nan
        elif kind == "miss":
            valid[row:row + 20, i] = False
        elif kind == "stuck":
            raw[row:, i] = raw[row, i]
        else:
            raw[row, i] += 50 * size * sd[i]
    return valid


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.integers(1, 6), st.integers(0, 399),
                          st.floats(-30.0, 30.0), st.sampled_from(["step", "nan", "miss",
                                                                    "stuck", "spike"])),
                max_size=4),
       st.integers(0, 10_000), st.integers(1, 97), st.sampled_from(["windows", "both"]),
       st.booleans())
def test_step_and_run_identical_for_random_fault_scenarios(faults, seed, chunk, detector,
                                                           jitter):
    cal, t, raw, _ = scenario("cone6", 400, [], seed=seed % 50)
    if jitter:
        cal = with_jitter(cal, seed)
    valid = apply_random_faults(cal, raw, faults)
    th = default_thresholds(cal, detector=detector)
    a = Monitor(cal, th)
    answers = [a.step(t[i], raw[i], valid[i]) for i in range(len(t))]
    res = Monitor(cal, th).run(t, raw, valid, parity=True, chunk=chunk)
    assert_identical(answers, res)


def test_sequential_isolation_cone6_down_to_reconstruction():
    N = 4000
    cal, t, raw, om = scenario("cone6", N, [(3, 500, 15.0), (5, 1500, -15.0), (1, 2500, 15.0)],
                               seed=11)
    raw[3200:, 0] = np.nan                      # then the faulty sensor 1 dies: 3 left
    mon = Monitor(cal)
    answers = [mon.step(t[i], raw[i]) for i in range(N)]
    ev = [e for a in answers for e in a.events]
    iso = [e for e in ev if e.type == "isolated"]
    assert [e.sensor for e in iso] == [3, 5], ev
    assert answers[499].capability == "isolate"
    assert answers[1000].capability == "isolate" and answers[1000].healthy.sum() == 5
    assert answers[2000].capability == "detect" and answers[2000].healthy.sum() == 4
    det3 = [e for e in ev if e.type == "detected" and 2500 / FS <= e.t < 3200 / FS]
    assert len(det3) == 1 and det3[0].sensor is None, det3   # one event, not attributed
    assert all(a.status.count("detected") == 4 for a in answers[2510:3199])
    assert answers[3300].capability == "reconstruct"
    assert answers[3300].status[0] == "nonfinite"
    assert np.isinf(answers[3300].protection_level)
    # body rates still delivered from the last three healthy sensors
    err = np.array([a.omega for a in answers[3300:]]) - om[3300:]
    sd = np.array([a.omega_sd for a in answers[3300:]])
    assert np.all(np.isfinite(err))
    assert np.abs(err / sd).max() < 6.0


def test_tetrad_detects_and_never_isolates():
    for s in range(1, 5):
        cal, t, raw, _ = scenario("tetrad", 1200, [(s, 300, 15.0)], seed=20 + s)
        res = Monitor(cal).run(t, raw)
        types = [e.type for e in res.events]
        assert "isolated" not in types, res.events
        det = [e for e in res.events if e.type == "detected"]
        assert len(det) == 1 and det[0].sensor is None and abs(det[0].t - 3.0) < 0.1
        assert set(res.capability) == {"detect"}


def test_magnitude_estimate_within_3_sigma():
    """15σ steps, 60 runs: (f̂ − f)/σ_f within 3 and its spread within ±25 % of 1."""
    zs = []
    per = MonitorSettings().persistence
    wm = 1 << (per.bit_length() - 1)            # window the monitor estimates from
    for k in range(60):
        s = 1 + k % 6
        cal, t, raw, _ = scenario("cone6", 300, [(s, 150, 15.0)], seed=200 + k)
        mon = Monitor(cal)
        u = mon.model.U[:, s - 1]
        sig_f = 1.0 / (np.linalg.norm(u) * np.sqrt(wm))
        res = mon.run(t, raw)
        iso = [e for e in res.events if e.type == "isolated"]
        assert len(iso) == 1 and iso[0].sensor == s, res.events
        f = 15.0 * cal.gyro.noise_sd[s - 1]
        zs.append((iso[0].magnitude - f) / sig_f)
    zs = np.array(zs)
    assert np.abs(zs).max() < 3.0, zs
    assert 0.75 < zs.std() < 1.25, zs.std()


def test_reconstruction_covariance_is_honest_after_isolation():
    """MC: empirical covariance of ω̂ − ω equals the reported one within 3 Monte Carlo sd
    (white errors: a variance ratio over n samples has sd sqrt(2/n), 0.7 % here; an
    off-diagonal whitened entry sd sqrt(1/n))."""
    N = 40_000
    cal = synthetic_calibration("cone6", seed=5, noise_sd_spread=0.3)
    om = manoeuvre(N, 3, amp=0.5)
    f = np.zeros((N, 6))
    f[100:, 1] = 20 * cal.gyro.noise_sd[1]
    raw = raw_samples(cal, om, seed=9, fault=f)     # calibration exact: noise only
    mon = Monitor(cal)
    res = mon.run(np.arange(N) / FS, raw)
    assert [e.sensor for e in res.events if e.type == "isolated"] == [2]
    sl = slice(1000, N)
    err = res.omega[sl] - om[sl]
    emp = np.cov(err.T)
    rep = mon.model.cov
    assert mon.model.m == 5
    np.testing.assert_allclose(res.omega_sd[sl][0], np.sqrt(np.diag(rep)))
    n = err.shape[0]
    tol = 3.0 * np.sqrt(2.0 / n)
    np.testing.assert_allclose(np.diag(emp) / np.diag(rep), 1.0, atol=tol, err_msg="variance")
    # the whole matrix: whitened empirical covariance close to I
    L = np.linalg.cholesky(np.linalg.inv(rep))
    np.testing.assert_allclose(L.T @ emp @ L, np.eye(3), atol=tol, err_msg="whitened cov")


def test_protection_level_covers_undetected_faults():
    """Bias faults near the minimum detectable size: when the single-sample test does not
    see them, |ω̂ − ω| exceeds the protection level in at most P_md of the samples."""
    cal = synthetic_calibration("cone6", seed=8)
    th = default_thresholds(cal, scales=(1,))
    rng = np.random.default_rng(0)
    n_bad = n_tot = 0
    for s in range(6):
        mdb = Monitor(cal, th).model.pl.mdb[s]
        for size in (0.3, 0.6, 0.9, 1.1):
            N = 5000
            om = manoeuvre(N, int(rng.integers(1 << 30)), amp=2.0)
            f = np.zeros((N, 6))
            f[:, s] = size * mdb * rng.choice([-1, 1])
            raw = raw_samples(cal, om, seed=int(rng.integers(1 << 30)), fault=f)
            mon = Monitor(cal, th, settings=MonitorSettings(persistence=10**9))
            res = mon.run(np.arange(N) / FS, raw)
            undetected = ~(res.statistics[:, 0] > res.thresholds[:, 0])
            err = np.linalg.norm(res.omega - om, axis=1)
            n_bad += int((undetected & (err > res.protection_level)).sum())
            n_tot += N
    p_md = th.missed_detection
    assert n_bad / n_tot <= p_md + 3 * np.sqrt(p_md / n_tot), (n_bad, n_tot)


def test_no_alarm_in_healthy_manoeuvring_flight_with_calibration_error():
    N = 12_000                                  # 2 min at 100 Hz, up to 300 °/s
    cal = synthetic_calibration("cone6", seed=2)
    om = manoeuvre(N, 5, amp=np.deg2rad(300.0))
    raw = raw_samples(cal, om, seed=6, truth=draw_truth(cal, seed=3))
    res = Monitor(cal).run(np.arange(N) / FS, raw)
    assert res.events == []
    assert res.thresholds[:, -1].max() > 1.5 * res.thresholds[:, -1].min()  # rate inflation


@pytest.mark.slow
@pytest.mark.parametrize("cfg", ["cone6", "tetrad"])
def test_long_healthy_300dps_flight_raises_no_alarm(cfg):
    """5 calibration-error draws × 1 h at 100 Hz, manoeuvres up to 300 °/s: no event."""
    top = 0.0
    for k in range(5):
        cal = synthetic_calibration(cfg, seed=30 + k)
        truth = draw_truth(cal, seed=40 + k)
        mon = Monitor(cal)
        for blk in range(6):                     # 6 × 10 min
            N = 60_000
            om = manoeuvre(N, 1000 * k + blk, amp=np.deg2rad(300.0))
            raw = raw_samples(cal, om, seed=50 + 100 * k + blk, truth=truth)
            t = (blk * N + np.arange(N)) / FS
            res = mon.run(t, raw)
            assert res.events == [], (cfg, k, blk, res.events[:3])
            top = max(top, float(np.nanmax(res.statistics / res.thresholds)))
    assert 0.3 < top < 1.0, top                 # the statistics are alive, and below 1


@pytest.mark.parametrize("chunk", [1, 31, 257])
def test_step_and_run_identical_with_timing_jitter(chunk):
    """The jitter term reads the ω̂ of the sample before: across block and chunk boundaries,
    missing samples, a stuck sensor and isolations, stepping and a block agree bit for bit,
    and the term moves the thresholds (against the same flight without jitter)."""
    cal0, t, raw, _ = scenario("cone6", 1500, [(3, 500, 14.0), (5, 1000, -16.0)], seed=4)
    cal = with_jitter(cal0, 3)
    valid = np.ones(raw.shape, bool)
    valid[300, 1] = False
    valid[700:703, 3] = False
    raw[1300:, 0] = raw[1300, 0]
    th = default_thresholds(cal, detector="both")
    a = Monitor(cal, th)
    answers = [a.step(t[i], raw[i], valid[i]) for i in range(len(t))]
    res = Monitor(cal, th).run(t, raw, valid, parity=True, chunk=chunk)
    assert_identical(answers, res)
    assert any(e.type == "isolated" for e in res.events)
    base = Monitor(cal0, th).run(t[:400], raw[:400], valid[:400])
    grew = res.thresholds[:400] > base.thresholds
    assert grew[50:].mean() > 0.5, grew.mean()


@pytest.mark.parametrize("chunk", [1, 64, 8192])
def test_step_and_run_identical_with_readmission(chunk):
    """Re-admission runs inside the kernel on both paths: a glitch isolates sensor 2, it is
    re-admitted after the dwell, a later step fault on sensor 5 is isolated; missing samples
    in between."""
    cal, t, raw, _ = scenario("cone6", 1500, [(5, 1200, 12.0)], seed=8)
    raw[100:105, 1] = np.nan
    valid = np.ones(raw.shape, bool)
    valid[700:703, 3] = False
    mset = MonitorSettings(readmission=True, readmit_dwell_s=3.0)
    a = Monitor(cal, settings=mset)
    answers = [a.step(t[i], raw[i], valid[i]) for i in range(len(t))]
    res = Monitor(cal, settings=mset).run(t, raw, valid, parity=True, chunk=chunk)
    assert_identical(answers, res)
    types = [(e.type, e.sensor) for e in res.events]
    assert ("readmitted", 2) in types and ("isolated", 5) in types, types


def gate_case():
    """Sensor 2: a NaN at row 100 isolates it, and from then on it carries a 6σ bias (about
    4.9 standard deviations of its residual against the reconstruction, whose variance is
    Σ_ii + h_iᵀPh_i ≈ 1.5 Σ_ii on the cone)."""
    cal, t, raw, _ = scenario("cone6", 1500, [(2, 100, 6.0)], seed=8)
    raw[100, 1] = np.nan
    return cal, t, raw


@pytest.mark.parametrize("gate, readmitted", [(9.0, False), (100.0, True)])
def test_readmit_gate_decides_readmission(gate, readmitted):
    """The re-admission gate is the setting's: at the default 9 (3σ) the biased sensor never
    behaves for the 3 s dwell (a sample passes with probability ~3 %), at 100 (10σ) it
    nearly always does (a sample fails with probability ~1e-6) and is re-admitted; stepping
    and the block agree."""
    cal, t, raw = gate_case()
    mset = MonitorSettings(readmission=True, readmit_dwell_s=3.0, readmit_gate=gate)
    res = Monitor(cal, settings=mset).run(t, raw, parity=True)
    a = Monitor(cal, settings=mset)
    assert_identical([a.step(t[i], raw[i]) for i in range(len(t))], res)
    types = [(e.type, e.sensor) for e in res.events]
    assert ("health", 2) in types, types
    assert (("readmitted", 2) in types) == readmitted, types


def test_readmit_gate_default_and_checks():
    """Default 9: a 3σ gate on the squared standardised residual; it must be positive and
    finite."""
    assert MonitorSettings().readmit_gate == 9.0
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="readmit_gate"):
            MonitorSettings(readmit_gate=bad)
