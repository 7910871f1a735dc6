"""The monitor's run-time correction input c (y = SF·u − b − c): the entry point for the
calibration's effect terms.

A constant correction is an extra bias, so a monitor told c must answer as a monitor whose
calibration has the biases b + c (to rounding: the kernel subtracts b and c one after the
other). Per-row corrections give the same answers through step and run; a non-finite
correction counts as 0 and never raises.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fdi.monitor import Monitor
from studies.synthetic import draw_truth, raw_samples, synthetic_calibration

FS = 100.0


def _flight(N: int, seed: int):
    cal = synthetic_calibration("cone6", seed=3)
    rng = np.random.default_rng(seed)
    tt = np.arange(N) / FS
    om = 1.5 * np.sin(2 * np.pi * rng.uniform(0.05, 0.5, 3) * tt[:, None] + rng.uniform(0, 6, 3))
    return cal, tt, raw_samples(cal, om, seed=seed + 1, truth=draw_truth(cal, seed=seed + 2))


def _with_bias_shift(cal, c):
    g = cal.gyro
    sensors = tuple(dataclasses.replace(s, bias=s.bias + float(ci))
                    for s, ci in zip(g.sensors, c, strict=True))
    gyro = dataclasses.replace(g, sensors=sensors)
    return dataclasses.replace(cal, sets=dict(cal.sets, gyro=gyro))


def test_constant_correction_is_a_bias_shift():
    cal, tt, raw = _flight(3000, seed=11)
    c = np.array([3e-4, -2e-4, 1e-4, 0.0, 5e-4, -4e-4])          # rad/s, ≈ 20-100 °/h
    a = Monitor(cal).run(tt, raw, correction=c)
    b = Monitor(_with_bias_shift(cal, c)).run(tt, raw)
    np.testing.assert_allclose(a.omega, b.omega, rtol=1e-12, atol=1e-15, err_msg="omega")
    np.testing.assert_allclose(a.statistics, b.statistics, rtol=1e-7, atol=1e-12,
                               err_msg="statistics")
    np.testing.assert_allclose(a.protection_level, b.protection_level, rtol=1e-12,
                               err_msg="protection_level")
    # and the correction matters: without it the answers differ by the bias
    d = Monitor(cal).run(tt, raw)
    assert np.max(np.abs(d.omega - a.omega)) > 1e-5, "correction had no effect on omega"


def test_step_and_run_identical_with_per_row_correction():
    cal, tt, raw = _flight(800, seed=12)
    rng = np.random.default_rng(5)
    c = rng.normal(0, 2e-4, raw.shape)
    c[100:110, 2] = np.nan                                         # non-finite: counts as 0
    c[200, 4] = np.inf
    blk = Monitor(cal).run(tt, raw, correction=c)
    mon = Monitor(cal)
    for r in range(tt.size):
        a = mon.step(tt[r], raw[r], correction=c[r])
        np.testing.assert_array_equal(a.omega, blk.omega[r], err_msg=f"omega row {r}")
        np.testing.assert_array_equal(a.statistics, blk.statistics[r],
                                      err_msg=f"statistics row {r}")


def test_non_finite_correction_counts_as_zero():
    cal, tt, raw = _flight(500, seed=13)
    c = np.zeros(raw.shape)
    c[::7, 1] = np.nan
    c[::11, 3] = -np.inf
    a = Monitor(cal).run(tt, raw, correction=c)
    b = Monitor(cal).run(tt, raw)
    np.testing.assert_array_equal(a.omega, b.omega, err_msg="omega")
    assert a.events == b.events


def test_unusable_correction_shape_is_ignored():
    cal, tt, raw = _flight(200, seed=14)
    b = Monitor(cal).run(tt, raw)
    for bad in (np.zeros(5), np.zeros((7, 6)), "x", [[1, 2], [3]]):
        a = Monitor(cal).run(tt, raw, correction=bad)
        np.testing.assert_array_equal(a.omega, b.omega, err_msg=f"correction {bad!r}")
        s = Monitor(cal).step(tt[0], raw[0], correction=bad)
        np.testing.assert_array_equal(s.omega, b.omega[0], err_msg=f"step correction {bad!r}")
