"""Detections that end (issue 27, item 3): a detection clears when its evidence has fallen
back, the answer returns to verified, and a false alarm never hides a later fault.

The clearing level of every window follows the threshold's inflation (the calibration
error that raises a healthy statistic in a manoeuvre raises the level it must fall back
below by as much); a detection that re-enters the envelope waits in the kernel's own clear
rule until every window has refilled; an alarm that rises again from below the clearing
levels inside an open detection is a new onset, whose isolation is decided afresh.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_monitor import scenario

from fdi import state as S
from fdi.monitor import Monitor
from fdi.windows import window_update

FS = 100.0


def false_alarm_then_step(seed: int, step_row: int, size: float = 8.0):
    """cone6 in a manoeuvre: a two-sample 30σ spike of opposite sign on sensors 1 and 2 at
    20 s (no single-sensor fault explains it: a detection, no exclusion), then a step of
    ``size``σ on sensor 4 from ``step_row`` on."""
    cal, t, raw, _ = scenario("cone6", 8000, [(4, step_row, size)], seed=seed)
    raw = raw.copy()
    sd, sf = cal.gyro.noise_sd, cal.gyro.scale_factors
    raw[2000:2002, 0] += 30 * sd[0] / sf[0]
    raw[2000:2002, 1] -= 30 * sd[1] / sf[1]
    return cal, t, raw


@pytest.mark.parametrize("seed", range(4))
def test_a_false_alarm_clears_and_a_later_step_is_isolated_to_its_sensor(seed):
    cal, t, raw = false_alarm_then_step(seed, 5000)
    res = Monitor(cal).run(t, raw)
    first = [e for e in res.events if e.type == "detected"]
    assert first[0].t == pytest.approx(20.0) and first[0].sensor is None
    assert not any(e.type == "isolated" and e.t < 50 for e in res.events)
    # the false alarm ended: verified again long before the step
    assert not res.unverified[2300:5000].any()
    assert np.isfinite(res.protection_level[2300:5000]).all()
    iso = [e for e in res.events if e.type == "isolated"]
    assert [e.sensor for e in iso] == [4]
    assert 0 <= iso[0].t - 50.0 <= 0.1


@pytest.mark.parametrize("seed", range(4))
def test_a_step_inside_the_open_false_alarm_is_still_isolated(seed):
    """The step starts 1.5 s after the false alarm, before it has cleared: the step is
    isolated to its sensor all the same (a new onset inside the open detection)."""
    cal, t, raw = false_alarm_then_step(seed, 2150)
    res = Monitor(cal).run(t, raw)
    iso = [e for e in res.events if e.type == "isolated"]
    assert [e.sensor for e in iso] == [4]
    assert iso[0].t - 21.5 <= 1.5


def test_the_clearing_level_follows_the_threshold_inflation():
    """One window, a statistic between the bare clearing level C and C·g (g: the threshold's
    inflation by Σρ): it clears, as it would at rest below C."""
    df, R = 3, 2
    scales = np.zeros((1, S.SCALE_COLS))
    scales[0, S.WINDOW] = 1
    scales[0, S.THRESHOLD] = 20.0
    scales[0, S.CHI2_SCALE] = 1.0
    scales[0, S.OFFSET_GAIN] = 1.0
    scales[0, S.RHO_GAIN] = 1.0
    scales[0, S.CLEAR_THRESHOLD] = 10.0
    out = np.zeros((1, S.STATS0 + 2))
    for rho, clears in ((0.0, False), (3.0, True)):      # g = 1 + ρ
        windows = np.zeros((R + 1, df + 1))
        counters = np.zeros(S.HEALTH0, np.int64)
        z = np.array([np.sqrt(15.0), 0.0, 0.0])          # D = 15: C < D < C·g at ρ = 3
        alarm, clear, _, _ = window_update(z, rho, df, windows, counters, scales, 1, out, 0)
        assert not alarm and clear == clears
        assert out[0, S.STATS0] == pytest.approx(15.0)


def test_the_hold_open_rule_lives_in_the_kernel():
    """A detection open at envelope re-entry stays open until every window has refilled:
    the kernel's clear rule reads HOLD_OPEN (the monitor sets it at re-entry)."""
    cal, t, raw = false_alarm_then_step(0, 7900)
    env = np.zeros(8000, np.int64)
    env[2010:2100] = 1                                   # out of the envelope just after
    mon = Monitor(cal)
    res = mon.run(t, raw, envelope=env)
    longest = max(mon.thresholds.scales)
    back = 2100
    unv = res.unverified[back:].any(axis=1)
    # open at re-entry, closed only after the longest window refilled and clear_samples
    cleared = back + int(np.flatnonzero(~unv)[0])
    assert cleared - back >= longest
    assert not unv[cleared - back:cleared - back + 3000].any()
