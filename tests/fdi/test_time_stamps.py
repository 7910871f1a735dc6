"""Bad time stamps are health events, never a blind spot (issue 28, item 2).

One time stamp of +inf, 1e300 or NaN, a clock that runs backwards, jumps or freezes: the
sample is tested as any other, its answer says what was wrong with its time
(``Answer.time_status``), one ``health`` event marks each run of bad time stamps, and the
stale clock keeps running (on the last good time and on the sample count), so a sensor
that goes silent later is declared stale and a later fault on another sensor is detected
and isolated. Before this, one +inf time froze every sensor's stale clock at +inf: the
silent sensor was never declared stale, every later sample was incomplete (no parity test,
infinite protection level) and a step on another sensor 20 s later went unseen.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_monitor import assert_identical, scenario

from fdi.monitor import Monitor
from fdi.settings import MonitorSettings

FS = 100.0
N = 6000
BAD_ROW, SILENT_ROW, STEP_ROW = 1000, 2000, 4000
SILENT, STEPPED = 2, 5                      # 1-based sensors


def blind_spot_case(bad: str, seed: int = 0):
    """The issue's scenario on cone6 at 100 Hz: a bad time stamp at 10 s, sensor 2 silent
    from 20 s on, a 12σ step on sensor 5 at 40 s. Returns (cal, t, raw, valid)."""
    cal, t, raw, _ = scenario("cone6", N, [(STEPPED, STEP_ROW, 12.0)], seed=seed)
    t = t.copy()
    if bad == "backward-reset":             # the clock restarts 100 s earlier, for good
        t[BAD_ROW:] -= 100.0
    elif bad == "frozen":                   # the clock stops: every later time the same
        t[BAD_ROW:] = t[BAD_ROW]
    elif bad == "jump-for-good":            # two hours forward, for good
        t[BAD_ROW:] += 7200.0
    else:
        t[BAD_ROW] = {"inf": np.inf, "1e300": 1e300, "nan": np.nan, "-inf": -np.inf,
                      "backward": t[BAD_ROW] - 5.0}[bad]
    valid = np.ones(raw.shape, bool)
    valid[SILENT_ROW:, SILENT - 1] = False
    return cal, t, raw, valid


def check_blind_spot(res) -> None:
    """The must-hold: the silent sensor declared unhealthy, the step detected and isolated
    to its sensor within 0.5 s (counted in samples: a frozen clock's times cannot say), at
    most 1 % of the samples after the bad time stamp untested (no finite statistic)."""
    stale = [e for e in res.events if e.type == "health" and e.sensor == SILENT]
    assert stale and stale[0].reason == "stale", res.events
    assert not res.healthy[-1, SILENT - 1]
    out = np.flatnonzero(~res.healthy[:, STEPPED - 1])
    assert out.size and STEP_ROW <= out[0] <= STEP_ROW + 0.5 * FS, out[:1]
    assert any(e.type == "detected" for e in res.events)
    iso = [e for e in res.events if e.type == "isolated"]
    assert [e.sensor for e in iso] == [STEPPED], iso
    later = res.statistics[BAD_ROW:]
    untested = ~np.isfinite(later).any(axis=1)
    assert untested.mean() <= 0.01, untested.mean()


@pytest.mark.parametrize("bad", ["inf", "1e300", "nan", "-inf", "backward", "backward-reset",
                                 "frozen", "jump-for-good"])
def test_a_bad_time_stamp_leaves_no_blind_spot(bad):
    cal, t, raw, valid = blind_spot_case(bad)
    res = Monitor(cal).run(t, raw, valid)
    check_blind_spot(res)


@pytest.mark.parametrize("bad,status,reason", [
    ("inf", "nonfinite", "time nonfinite"), ("nan", "nonfinite", "time nonfinite"),
    ("1e300", "jump", "time jump"), ("backward", "backward", "time backward")])
def test_the_answer_says_what_was_wrong_with_its_time(bad, status, reason):
    cal, t, raw, valid = blind_spot_case(bad)
    res = Monitor(cal).run(t, raw, valid)
    assert res.time_status[BAD_ROW] == status
    assert set(res.time_status[:BAD_ROW]) == {"ok"}
    assert set(res.time_status[BAD_ROW + 1:]) == {"ok"}
    ev = [e for e in res.events if e.type == "health" and e.sensor is None]
    assert [e.reason for e in ev] == [reason]
    # the sample itself was tested: its statistics are finite where its windows are full
    assert np.isfinite(res.statistics[BAD_ROW, 0])


def test_a_clock_reset_becomes_the_new_time_base():
    cal, t, raw, valid = blind_spot_case("backward-reset")
    res = Monitor(cal).run(t, raw, valid)
    k = MonitorSettings().time_rebase_samples
    assert list(res.time_status[BAD_ROW:BAD_ROW + k]) == ["backward"] * (k - 1) + ["rebased"]
    assert set(res.time_status[BAD_ROW + k:]) == {"ok"}
    ev = [e.reason for e in res.events if e.type == "health" and e.sensor is None]
    assert ev == ["time backward", "time rebased"]


def test_a_frozen_clock_still_finds_the_silent_sensor_by_the_sample_count():
    """Every time stamp equal from 10 s on: the time since the last sample never grows, the
    sample count declares the silent sensor stale after stale_timeout_s·fs samples."""
    cal, t, raw, valid = blind_spot_case("frozen")
    res = Monitor(cal).run(t, raw, valid)
    stale = [e for e in res.events if e.type == "health" and e.sensor == SILENT]
    limit = MonitorSettings().stale_timeout_s * FS
    rows = np.flatnonzero(~res.healthy[:, SILENT - 1])
    assert rows[0] == SILENT_ROW + int(limit), (rows[0], limit)   # the (limit + 1)-th missing
    assert stale[0].statistic == pytest.approx((limit + 1) / FS)


@pytest.mark.parametrize("bad", ["inf", "backward-reset", "frozen"])
def test_step_and_run_agree_on_bad_time_stamps(bad):
    cal, t, raw, valid = blind_spot_case(bad)
    mon = Monitor(cal)
    res = mon.run(t[:4500], raw[:4500], valid[:4500], parity=True)
    mon.reset()
    answers = [mon.step(t[r], raw[r], valid[r]) for r in range(4500)]
    assert_identical(answers, res)
    assert [a.time_status for a in answers] == list(res.time_status)


def test_readmission_dwell_restarts_at_a_bad_time_stamp():
    """A bad time stamp in the middle of a dwell: the dwell's length is not known there,
    so it starts again (an isolated sensor is not re-admitted across a 1e300)."""
    cal, t, raw, _ = scenario("cone6", 3000, [], seed=3)
    raw = raw.copy()
    raw[100:105, 1] = np.nan                        # sensor 2 isolated (nonfinite) at 1 s
    s = MonitorSettings(readmission=True, readmit_dwell_s=3.0)
    ok = Monitor(cal, settings=s).run(t, raw)
    back = [e.t for e in ok.events if e.type == "readmitted"]
    assert back and 4.0 <= back[0] <= 4.2
    t2 = t.copy()
    t2[300] = 1e300                                 # 3 s into the dwell... at 3.0 s
    res = Monitor(cal, settings=s).run(t2, raw)
    back2 = [e.t for e in res.events if e.type == "readmitted"]
    assert back2 and back2[0] >= 3.0 + 3.0 - 1e-9
