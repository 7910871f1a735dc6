"""The envelope of the vehicle (issue 27, item 4): a saturation every IMU confirms is the
envelope, not a sensor fault (no health exclusion there), and the tumble rule is relative to
the vehicle's calibrated or declared range about each axis, so a healthy manoeuvre the
simulator flies is not a tumble."""

from __future__ import annotations

import numpy as np
import pytest
from test_isolation import triads

from fdi.envelope import SATURATION, TUMBLE, EnvelopeSettings, EnvelopeTracker
from fdi.monitor import Monitor
from replay.flight_sim import simulate_flight
from studies.synthetic import synthetic_calibration

DPS = np.pi / 180


def _codes(cal, t, raw, groups=None, **kw):
    s = cal.gyro
    rates = raw * s.scale_factors - s.biases
    tr = EnvelopeTracker(H=s.H, groups=groups, **kw)
    return tr.update(t, rates)


@pytest.mark.parametrize("k", [2, 3])
def test_a_saturation_every_imu_confirms_excludes_no_one(tmp_path, k):
    """A crash spin: every IMU's z gyro beyond 2000 °/s for 0.3 s (35.3 rad/s > the
    35 rad/s health limit). Every IMU confirms it (SATURATION): nothing is excluded."""
    cal = triads(tmp_path, k, seed=2)
    fl = simulate_flight(cal, 10.0, seed=1, max_rate_dps=100.0)
    raw = fl.raw.copy()
    s = cal.gyro
    spin = slice(500, 530)
    for j in range(k):
        raw[spin, 3 * j + 2] = (35.3 + s.biases[3 * j + 2]) / s.scale_factors[3 * j + 2]
    groups = [list(range(3 * j, 3 * j + 3)) for j in range(k)]
    env = _codes(cal, fl.t, raw, groups)
    assert (env[spin] & SATURATION).all()
    res = Monitor(cal).run(fl.t, raw, envelope=env)
    assert res.healthy.all(), [e for e in res.events if e.type == "health"]
    # without the envelope the health check would exclude them (what it does for one
    # gyro alone at its range: that is a sensor's problem)
    bare = Monitor(cal).run(fl.t, raw)
    assert not bare.healthy[-1].all()
    one = fl.raw.copy()
    one[spin, 2] = raw[spin, 2]
    env1 = _codes(cal, fl.t, one, groups)
    assert not (env1[spin] & SATURATION).any()
    res1 = Monitor(cal).run(fl.t, one, envelope=env1)
    assert not res1.healthy[-1, 2] and res1.healthy[-1, 3:].all()


def test_the_simulators_healthy_manoeuvres_are_not_tumbles():
    """cone6 flights at the simulator's 300 °/s about every axis (520 °/s in all): no
    sample is a tumble (the fixed 400 °/s on the vector marked 3.6–3.8 % of them)."""
    cal = synthetic_calibration("cone6", seed=1)
    beyond = 0
    for seed in range(3):
        fl = simulate_flight(cal, 120.0, seed=seed, max_rate_dps=300.0)
        codes = _codes(cal, fl.t, fl.raw)
        assert not (codes & TUMBLE).any()
        beyond += int((np.linalg.norm(fl.omega_true, axis=1) > 400 * DPS).sum())
    assert beyond > 100                     # what the old rule, 400 °/s on the vector, marked


def test_the_tumble_limit_follows_the_vehicles_range():
    cal = synthetic_calibration("cone6", seed=1)
    H = cal.gyro.H
    base = EnvelopeTracker(H=H)
    np.testing.assert_allclose(base.tumble_limit(), 400 * DPS)
    cal_range = EnvelopeTracker(H=H, validated_rate=np.array([500, 200, 100]) * DPS)
    np.testing.assert_allclose(cal_range.tumble_limit(), [625 * DPS, 400 * DPS, 400 * DPS])
    declared = EnvelopeTracker(EnvelopeSettings(vehicle_rate_dps=720.0), H=H)
    np.testing.assert_allclose(declared.tumble_limit(), 900 * DPS)
    # a spin at 600 °/s about z: a tumble for the default vehicle, not for the acrobat
    t = np.arange(300) / 100.0
    rates = np.zeros((300, 6))
    rates[100:200] = H @ np.array([0.0, 0.0, 600 * DPS])
    assert (base.update(t, rates)[100:200] & TUMBLE).all()
    assert not (declared.update(t, rates) & TUMBLE).any()
