"""The definitions of the field evidence (studies.field): episodes, rates, resolution.

Fast and without measured data; the evidence itself is recomputed by the slow
test_field_results.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from fdi.answer import Event
from studies.field import RESOLVE_EXPECTED, alarm_episodes, rate_row, split_flight


def _ev(t, kind, sensor=None):
    return Event(t, sensor, kind, "parity scale 1")


def test_an_episode_is_a_detection_and_its_conclusion_is_not_another():
    evs = [_ev(1.0, "detected"), _ev(1.2, "isolated", 3),     # one episode
           _ev(3.0, "isolated", 4),                            # isolation with no detection
           _ev(5.0, "health", 2),                              # a health isolation: one
           _ev(7.0, "detected"), _ev(7.5, "disagree"), _ev(7.9, "disagree"),   # one,
           _ev(8.5, "isolated", 1),                            # concluded by an isolation
           _ev(9.5, "readmitted", 3)]                          # no alarm
    assert [e.t for e in alarm_episodes(evs)] == [1.0, 3.0, 5.0, 7.0]


def test_resolution_is_where_zero_alarms_would_show_the_rate_below_three_targets():
    # the 95 % one-sided upper limit for zero events is -ln(0.05)/T; it equals 3R at R·T = E
    assert math.isclose(-math.log(0.05) / RESOLVE_EXPECTED, 3.0)
    assert stats.poisson.cdf(0, 3.0 * RESOLVE_EXPECTED) == pytest.approx(0.05)
    h = 0.02                                                   # 72 s of exposure
    assert not rate_row(0, h, 10.0)["resolved"]                # 0.2 expected
    assert rate_row(0, h, 100.0)["resolved"]                   # 2 expected


def test_rate_row_interval_is_the_exact_poisson_one():
    r = rate_row(4, 0.5, 10.0)
    assert r["expected"] == 5.0 and r["observed"] == 4 and r["per_hour"] == 8.0
    lo, hi = r["ci95_per_hour"]
    # Garwood: P(N >= 4 | lo·h) = 0.025 and P(N <= 4 | hi·h) = 0.025
    assert stats.poisson.sf(3, lo * 0.5) == pytest.approx(0.025, rel=1e-6)
    assert stats.poisson.cdf(4, hi * 0.5) == pytest.approx(0.025, rel=1e-6)


def test_split_keeps_every_sample_once():
    from replay.flight_data import Flight

    t = np.arange(11) / 50.0
    f = Flight(t, np.zeros((11, 6)), np.ones((11, 6), bool), 50.0,
               tuple(f"s{i}" for i in range(6)))
    a, b = split_flight(f)
    assert np.array_equal(np.concatenate([a.t, b.t]), t) and a.t.size in (5, 6)
