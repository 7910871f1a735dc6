"""Repeated and backward time stamps in an in-flight fit (issue 27): the samples that
cannot be placed are left out as a ``time stamp`` segment, counted and named, never a
traceback (a repeated stamp reached scipy's spline as ``ValueError``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calibration.inflight.fit import fit_inflight
from calibration.inflight.segments import find_segments, stamp_faults
from replay.imu_set import ImuSetSpec, simulate_imu_set


def _flight():
    return simulate_imu_set(ImuSetSpec(imus=3, duration_s=12.0, seed=7, max_rate_dps=150))


def test_stamp_faults_counts_repeated_and_backward_and_leaves_increasing_rows() -> None:
    t = np.array([0.0, 1.0, 1.0, 2.0, 1.5, 3.0, 4.0])
    mask, rep, back = stamp_faults(t)
    assert (rep, back) == (1, 1)
    assert mask.tolist() == [False, False, True, False, True, False, False]
    assert np.all(np.diff(t[~mask]) > 0)


def test_fit_leaves_out_a_repeated_and_a_backward_stamp_and_says_so() -> None:
    f = _flight()
    clean = fit_inflight(f)
    t = f.t.copy()
    t[400] = t[399]                      # repeated (as Xsens DOT Vertical/path_4/IMU_1)
    t[500] = t[497]                      # backward
    bad = replace(f, t=t)
    fit = fit_inflight(bad)
    segs = [s for s in find_segments(bad) if s.reason == "time stamp"]
    assert len(segs) == 2
    assert "1 repeated" in segs[0].detail and "1 running backward" in segs[1].detail
    assert [s.reason for s in fit.left_out].count("time stamp") == 2
    for k in (399, 400, 497, 500):
        assert not fit.used[k]
    # the rest of the flight still calibrates as before: same relative gains within 3 sd
    for g, a in fit.alignments.items():
        a0 = clean.alignments[g]
        sd = np.sqrt(np.diag(a0.A_cov)).reshape(3, 3)
        assert np.all(np.abs(a.A - a0.A) <= 3 * sd + 1e-12)
