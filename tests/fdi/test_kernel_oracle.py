"""The compiled monitor kernel against the plain-numpy oracle (tests/fdi/oracle_monitor.py).

Step-versus-block identity cannot catch an error both paths share; the oracle computes the
same answers from the definitions (direct window sums, Page's CUSUM, ρ from the 3×3
input-error covariances and the timing jitters with ω̇̂ from successive answers). Discrete
outputs (health, capability, events: type, sensor, reason) must agree exactly; numbers to
rounding (the two evaluate sums in other orders).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from oracle_monitor import OracleMonitor

from fdi.detector import default_thresholds
from fdi.monitor import Monitor
from fdi.settings import MonitorSettings
from studies.synthetic import draw_truth, raw_samples, synthetic_calibration

FS = 100.0
_CAL: dict = {}
EXTREME = [np.nan, np.inf, -np.inf, 1e308, -1e308, 5e-324, -5e-324, 2.2e-308]


def _full_input_error(cal):
    """The calibration with a random full (correlated) input-error covariance per sensor,
    large enough that ρ moves the thresholds (the synthetic one is isotropic, 1e-8), and a
    random timing jitter on every sensor but the first (the reference), large enough that
    its term τ_i²(h_iᵀω̇̂)²/Σ_ii moves them too."""
    rng = np.random.default_rng(7)
    sensors = []
    for k, s in enumerate(cal.gyro.sensors):
        L = rng.normal(size=(3, 3)) * 3e-4
        tau = 0.0 if k == 0 else float(rng.uniform(0.05e-3, 0.3e-3))
        sensors.append(dataclasses.replace(s, input_error_cov=L @ L.T + 1e-8 * np.eye(3),
                                           timing_jitter=tau))
    sets = dict(cal.sets, gyro=dataclasses.replace(cal.gyro, sensors=tuple(sensors)))
    return dataclasses.replace(cal, sets=sets)


def _flight(cfg: str, N: int, seed: int) -> tuple:
    if cfg not in _CAL:
        _CAL[cfg] = _full_input_error(synthetic_calibration(cfg, seed=2))
    cal = _CAL[cfg]
    rng = np.random.default_rng(seed)
    tt = np.arange(N) / FS
    f = rng.uniform(0.05, 0.5, 3)
    om = 2.0 * np.sin(2 * np.pi * f * tt[:, None] + rng.uniform(0, 6, 3))
    raw = raw_samples(cal, om, seed=seed + 1, truth=draw_truth(cal, seed=seed + 2))
    return cal, tt, raw


def _close(a, b, what: str, rtol: float = 1e-9, atol: float = 1e-12) -> None:
    a, b = np.asarray(a, float), np.asarray(b, float)
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=f"{what}: NaN pattern")
    np.testing.assert_allclose(np.nan_to_num(a, nan=0.0, posinf=1e300, neginf=-1e300),
                               np.nan_to_num(b, nan=0.0, posinf=1e300, neginf=-1e300),
                               rtol=rtol, atol=atol, err_msg=what)


def compare(cal, th, t, raw, valid, mset=None) -> list:
    """Run the kernel (Monitor.run) and the oracle on one block; assert agreement."""
    mset = mset or MonitorSettings()
    res = Monitor(cal, th, settings=mset).run(t, raw, valid, parity=True)
    orc = OracleMonitor(cal, th, mset)
    ok = np.ones(raw.shape, bool) if valid is None else valid
    ev_k = [(e.t, e.type, e.sensor, e.reason) for e in res.events]
    ev_o = []
    for r in range(len(t)):
        o = orc.step(t[r], raw[r], ok[r])
        np.testing.assert_array_equal(res.healthy[r], o.healthy, err_msg=f"healthy row {r}")
        assert res.capability[r] == o.capability, f"capability row {r}"
        _close(res.omega[r], o.omega, f"omega row {r}", atol=1e-12)
        _close(res.omega_sd[r], o.omega_sd, f"omega_sd row {r}")
        _close(res.statistics[r], o.statistics, f"statistics row {r}", rtol=1e-7, atol=1e-9)
        _close(res.thresholds[r], o.thresholds, f"thresholds row {r}", rtol=1e-9)
        _close(res.parity[r], o.parity, f"parity row {r}", atol=1e-12)
        _close(res.protection_level[r], o.protection_level, f"PL row {r}")
        ev_o += [(t[r], e[0], e[1], e[2]) for e in o.events]
        for e in o.events:
            if e[0] != "health" and e[3] is not None:
                k = next(x for x in res.events if (x.t, x.type) == (t[r], e[0]))
                _close([k.statistic, k.threshold], [e[3], e[4]], f"event row {r}", rtol=1e-7)
                if e[5] is not None:
                    _close(k.magnitude, e[5], f"magnitude row {r}", rtol=1e-6, atol=1e-12)
    assert ev_k == ev_o
    return res.events


@pytest.mark.parametrize("cfg", ["cone6", "tetrad"])
@pytest.mark.parametrize("detector", ["windows", "both"])
def test_kernel_matches_oracle_on_healthy_flight_and_a_fault(cfg, detector):
    cal, t, raw = _flight(cfg, 600, seed=11)
    sd = cal.gyro.noise_sd / cal.gyro.scale_factors
    raw[300:, 1] += 12.0 * sd[1]
    th = default_thresholds(cal, detector=detector)
    events = compare(cal, th, t, raw, None)
    assert any(e.type == "detected" for e in events)


@pytest.mark.parametrize("seed", range(6))
def test_kernel_matches_oracle_on_random_healthy_subsets(seed):
    """Sensors removed by a non-finite value at a random time leave a random healthy set;
    a fault on a random remaining sensor follows."""
    rng = np.random.default_rng(seed)
    cal, t, raw = _flight("cone6", 800, seed=seed)
    sd = cal.gyro.noise_sd / cal.gyro.scale_factors
    order = rng.permutation(6)
    n_kill = int(rng.integers(0, 4))
    for k, i in enumerate(order[:n_kill]):
        raw[50 + 100 * k, i] = np.nan
    victim = order[n_kill]
    raw[500:, victim] += rng.choice([-1, 1]) * rng.uniform(6, 30) * sd[victim]
    th = default_thresholds(cal, detector=str(rng.choice(["windows", "both"])))
    compare(cal, th, t, raw, None)


EDITS = st.lists(st.tuples(st.integers(0, 5), st.integers(0, 299),
                           st.sampled_from(["step", "extreme", "stuck", "miss", "spike"]),
                           st.floats(-40.0, 40.0), st.sampled_from(EXTREME)), max_size=5)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(EDITS, st.integers(0, 1000), st.sampled_from(["cone6", "tetrad"]),
       st.sampled_from(["windows", "both"]))
def test_kernel_matches_oracle_on_faults_and_extreme_values(edits, seed, cfg, detector):
    cal, t, raw = _flight(cfg, 300, seed=seed % 20)
    n = raw.shape[1]
    sd = cal.gyro.noise_sd / cal.gyro.scale_factors
    valid = np.ones(raw.shape, bool)
    for s, row, kind, size, value in edits:
        i = s % n
        if kind == "step":
            raw[row:, i] += size * sd[i]
        elif kind == "extreme":
            raw[row, i] = value
        elif kind == "stuck":
            raw[row:, i] = raw[row, i]
        elif kind == "miss":
            valid[row:row + 15, i] = False
        else:
            raw[row, i] += 40.0 * size * sd[i]
    th = default_thresholds(cal, detector=detector)
    compare(cal, th, t, raw, valid, MonitorSettings(stuck_count=20))


def test_subnormal_raw_values_are_plausible_numbers_not_faults():
    """A raw value of 5e-324 lies inside the raw bounds: compensated as any number, no
    health event (the oracle agrees on every output)."""
    cal, t, raw = _flight("cone6", 200, seed=3)
    raw[100, 2] = 5e-324
    events = compare(cal, default_thresholds(cal), t, raw, None)
    assert not [e for e in events if e.type == "health"]


def test_one_compiled_specialisation_whatever_the_input_types():
    """float32/int/list/Fortran-ordered inputs and valid masks of any dtype reach the kernel
    as float64/bool C arrays: numba compiles it once per process (CI time)."""
    from fdi import kernel

    cal, t, raw = _flight("tetrad", 20, seed=1)
    mon = Monitor(cal)
    mon.step(t[0], raw[0])
    mon.step(t[1], raw[1].astype(np.float32), [1, 1, 0, 1])
    mon.step(t[2], list(raw[2]))
    mon.step(t[3], np.asfortranarray(raw[:4])[3], np.ones(4, np.int8))
    mon.run(t[4:10], raw[4:10].astype(np.float32))
    mon.run(t[10:], np.asfortranarray(raw[10:]), np.ones((10, 4), np.float64))
    assert len(kernel.advance.signatures) == 1
    assert len(kernel.reconstruct_row.signatures) <= 1
