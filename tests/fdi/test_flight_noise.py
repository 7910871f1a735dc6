"""Noise that is the flight's (issue 27, item 3): the thresholds follow the in-flight noise
of the parity within a stated bound, and with three or more IMUs an IMU axis far noisier
than its peers is excluded as a fault of its own kind ("vibration").

The noise level v is an exponential mean of |z_t − z_{t−1}|²/(2·df) (1 at the calibrated
level); the windows' thresholds and clearing levels take s = min(K, max(1, v/1.5)). A
difference carries no bias, step (after its onset) or drift, so a slow fault cannot raise
its own threshold, and no fault can raise it beyond K (MonitorSettings.noise_scale_max).
Simulated flights (``replay.flight_sim.simulate_flight``, faults from the truth sidecar's
specs, ``noise:S:Kx:T``) give the truth.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_isolation import triads
from test_monitor import assert_identical, scenario

from fdi import state as S
from fdi.monitor import Monitor
from fdi.settings import MonitorSettings
from replay.faults import parse_fault
from replay.flight_sim import simulate_flight

OFF = MonitorSettings(noise_scale_max=1.0, vibration_ratio=0.0)
"""The calibrated noise only (the monitor before this work)."""


def _vibrating(cal, sensor: int, factor: float, onset: float, seed: int, duration=40.0):
    spec = f"noise:{sensor}:{factor:g}x:{onset:g}"
    return simulate_flight(cal, duration, seed=seed, faults=[parse_fault(spec, cal)],
                           max_rate_dps=100.0)


@pytest.fixture(scope="module")
def three_imus(tmp_path_factory):
    return triads(tmp_path_factory.mktemp("imus"), 3, seed=2)


@pytest.mark.parametrize("sensor", range(1, 10))
def test_an_axis_that_vibrates_beyond_its_peers_is_blamed_within_10_s(three_imus, sensor):
    """The issue's must-hold on three IMUs: one axis with 3× its noise from 5 s on is
    excluded within 10 s, to the right sensor, and nothing else is excluded."""
    fl = _vibrating(three_imus, sensor, 3.0, 5.0, seed=sensor)
    assert [f.sensor for f in fl.faults] == [sensor - 1] or \
        [getattr(f, "sensor", None) for f in fl.faults]            # the truth names it
    res = Monitor(three_imus).run(fl.t, fl.raw)
    out = [e for e in res.events if e.type in ("isolated", "health") and e.sensor]
    assert [e.sensor for e in out] == [sensor], out
    assert 5.0 <= out[0].t <= 15.0, out[0]


def test_vibration_is_its_own_kind(three_imus):
    """Noise the parity test does not isolate (3× on imu3.z: zero-mean, its windows
    average it away) is excluded by the vibration test, with status and reason
    ``vibration``."""
    fl = _vibrating(three_imus, 9, 3.0, 5.0, seed=3)
    mon = Monitor(three_imus)
    res = mon.run(fl.t, fl.raw)
    iso = [e for e in res.events if e.type == "isolated"]
    assert [(e.sensor, e.reason) for e in iso] == [(9, "vibration")]
    assert iso[0].t <= 15.0
    assert mon._status[8] == "vibration"
    assert iso[0].statistic > iso[0].threshold                # v_9 above ratio × the next


@pytest.mark.parametrize("seed", range(6))
def test_healthy_flights_of_three_imus_blame_no_one(three_imus, seed):
    fl = simulate_flight(three_imus, 60.0, seed=100 + seed, max_rate_dps=100.0)
    res = Monitor(three_imus).run(fl.t, fl.raw)
    assert not [e for e in res.events if e.type in ("isolated", "health")]


def _vibration_verdict(cal_sd_dps, flight_sd_dps, dwell=5, weight=0.8):
    """The kernel's vibration test on four sensors (the y axes of four IMUs) whose in-flight
    sd and calibrated sd are given (°/s): levels v_i = 1 + (a_i − 1)·w with a_i the variance
    ratio and w = |u_i|²·Σ_ii the sensor's share of its own unit column; the sensor the
    test returns after ``dwell`` samples (−1: none)."""
    from fdi.kernel import _vibration_test
    from fdi.units import DPS

    n = len(cal_sd_dps)
    sig2 = (np.asarray(cal_sd_dps, float) * DPS) ** 2
    a = (np.asarray(flight_sd_dps, float) * DPS) ** 2 / sig2
    sensors = np.zeros((S.SENSORS.SENSOR_COLS, n))
    sensors[S.SENSORS.IN_SET] = 1.0
    sensors[S.SENSORS.SIGMA_II] = sig2
    sensors[S.SENSORS.U_NORM2] = weight / sig2
    fconst = np.zeros(S.FCONST.F_SLOTS)
    fconst[S.FCONST.VIB_RATIO] = MonitorSettings().vibration_ratio
    fconst[S.FCONST.VIB_LEVEL] = MonitorSettings().vibration_level
    counters = np.zeros(S.COUNTERS.HEALTH0 + n, np.int64)
    vib = 1.0 + (a - 1.0) * weight
    out = -1
    for _ in range(dwell):
        out = _vibration_test(sensors, fconst, dwell, vib, counters)
    return out, vib


def test_an_understated_calibration_is_not_a_vibrating_axis():
    """Four IMUs' y axes calibrated at 2.5, 3, 5 and 8.7 °/s and flying at 7, 5, 9 and
    12 °/s (the Xsens DOT paths H5 and H7 look like this: imu1.y, whose noise the
    calibration of the other paths understated, was excluded for vibration while quieter
    in °/s than the other IMUs' y axes). imu1.y's level relative to its calibration is
    above the vibration level and more than twice every other's, so the relative test
    alone blames it; it is the quietest in °/s, and the physical comparison blames no one.
    The same sensor at 25 °/s is blamed."""
    cal = [2.5, 3.0, 5.0, 8.7]
    blamed, vib = _vibration_verdict(cal, [7.0, 5.0, 9.0, 12.0])
    top, rest = vib[0], np.delete(vib, 0)
    assert top > MonitorSettings().vibration_level and \
        top > MonitorSettings().vibration_ratio * rest.max(), vib     # relative: passes
    assert blamed == -1, vib
    blamed, vib = _vibration_verdict(cal, [25.0, 5.0, 9.0, 12.0])
    assert blamed == 0, vib


def test_two_nearly_aligned_triads_never_blame_vibration(tmp_path):
    cal = triads(tmp_path, 2, seed=2)
    fl = _vibrating(cal, 1, 3.0, 5.0, seed=1)
    res = Monitor(cal).run(fl.t, fl.raw)
    assert not [e for e in res.events if e.type == "isolated"]


def test_thresholds_follow_a_vibration_every_sensor_feels_within_the_bound():
    """All six cone sensors at 3× their noise from 10 s (an airframe that vibrates): with
    the calibrated noise the monitor alarms and stays unverified most of the time;
    following the flight's noise it stays verified, and its thresholds rise by at most K."""
    cal, t, raw, _ = scenario("cone6", 6000, [], seed=4)
    raw = raw.copy()
    rng = np.random.default_rng(4)
    sd, sf = cal.gyro.noise_sd, cal.gyro.scale_factors
    raw[1000:] += rng.normal(0, 1, (5000, 6)) * (np.sqrt(8.0) * sd / sf)
    before = Monitor(cal, settings=OFF).run(t, raw)
    mon = Monitor(cal)
    after = mon.run(t, raw)
    n_after = sum(e.type == "detected" for e in after.events)
    unv_before = before.unverified[1000:].any(axis=1).mean()
    unv_after = after.unverified[1000:].any(axis=1).mean()
    # (after: the one detection at the onset, open while v follows over its 2 s time
    # constant and the clearing run: 5.6 % of the 50 s; before: 99.4 %)
    assert unv_before > 0.5 and unv_after < 0.1 and n_after <= 1, (unv_before, unv_after)
    full = np.isfinite(after.statistics[:, :8]) & np.isfinite(before.statistics[:, :8])
    ratio = np.where(full, after.thresholds[:, :8] / before.thresholds[:, :8], np.nan)
    assert np.nanmax(ratio) <= mon.settings.noise_scale_max * (1 + 1e-12)
    assert np.nanmedian(ratio[3000:]) > 3.0                  # it did follow (9/1.5 = 6)
    assert np.all(ratio[:1000][full[:1000]] == 1.0)          # calm: the tuned thresholds


def test_a_slow_fault_cannot_raise_its_own_threshold():
    """A ramp of 0.5σ per second on sensor 3: the differences carry nothing of it, the
    thresholds stay those of the calibrated noise and the ramp is detected when it is with
    the noise scale off."""
    cal, t, raw, _ = scenario("cone6", 6000, [], seed=5)
    raw = raw.copy()
    sd, sf = cal.gyro.noise_sd, cal.gyro.scale_factors
    raw[1000:, 2] += 0.5 * sd[2] / sf[2] * (np.arange(5000) / 100.0)
    off = Monitor(cal, settings=OFF).run(t, raw)
    on = Monitor(cal).run(t, raw)
    np.testing.assert_array_equal(on.thresholds, off.thresholds)
    d_off = [e.t for e in off.events if e.type in ("detected", "isolated")]
    d_on = [e.t for e in on.events if e.type in ("detected", "isolated")]
    assert d_on and d_on == d_off


def test_the_bound_holds_for_any_noise():
    """Noise 100× the calibrated on every sensor: the scale stops at K."""
    cal, t, raw, _ = scenario("cone6", 3000, [], seed=6)
    raw = raw.copy()
    rng = np.random.default_rng(6)
    raw[500:] += rng.normal(0, 1, (2500, 6)) * (100 * cal.gyro.noise_sd / cal.gyro.scale_factors)
    mon = Monitor(cal, settings=MonitorSettings(noise_scale_max=4.0, vibration_ratio=0.0))
    res = mon.run(t, raw)
    base = Monitor(cal, settings=OFF).run(t, raw)
    full = np.isfinite(res.statistics[:, :8]) & np.isfinite(base.statistics[:, :8])
    ratio = np.where(full, res.thresholds[:, :8] / base.thresholds[:, :8], np.nan)
    assert np.nanmax(ratio) == pytest.approx(4.0)


def test_step_and_run_agree_with_the_noise_scale_and_a_vibration(three_imus):
    fl = _vibrating(three_imus, 4, 2.5, 3.0, seed=7, duration=20.0)
    mon = Monitor(three_imus)
    res = mon.run(fl.t, fl.raw, parity=True)
    assert any(e.reason == "vibration" or e.type == "isolated" for e in res.events)
    mon.reset()
    answers = [mon.step(fl.t[r], fl.raw[r]) for r in range(fl.t.shape[0])]
    assert_identical(answers, res)
    assert S.STOP_VIBRATION & S.STOP_MASK
