"""Thresholds that hold for any bias within a nominal bound (fdi.bias_bound)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import stats

from fdi.bias_bound import (
    _box_max,
    _whitened,
    bounded_thresholds,
    max_parity_offset,
    rate_shift_bound,
)
from fdi.detector import default_thresholds
from fdi.monitor import Monitor
from fdi.units import DPS
from studies.synthetic import synthetic_calibration

CAL = synthetic_calibration("cone6")


def test_box_maximum_is_the_worst_vertex_and_the_triangle_bound_is_above_it():
    rng = np.random.default_rng(3)
    U = rng.normal(size=(3, 6))
    B = rng.uniform(0.1, 1.0, 6)
    brute = max(float(np.sum((U @ (np.array(s) * B)) ** 2))
                for s in itertools.product((-1, 1), repeat=6))
    assert _box_max(U, B) == pytest.approx(brute)
    inside = rng.uniform(-1, 1, (2000, 6)) * B
    assert np.max(np.sum((inside @ U.T) ** 2, axis=1)) <= brute * (1 + 1e-12)
    assert float(np.sum(np.linalg.norm(U * B, axis=0)) ** 2) >= brute


def test_bounded_thresholds_hold_at_the_worst_bias_and_the_monitor_uses_them():
    """Monte Carlo (fixed seed): full windows of white whitened parity plus the offset of
    the worst bias in a 0.05 °/s box exceed the raised thresholds with probability α_w
    (within 4 binomial sd), the plain thresholds far more often; the monitor built with them
    carries the raised thresholds."""
    thr = default_thresholds(CAL, false_alarms_per_hour=3.6e6 * 0.05, scales=(1, 8, 64))
    B = np.full(6, 0.05 * DPS)
    up = bounded_thresholds(thr, CAL, B, source="test")
    U = _whitened(CAL, "gyro", np.ones(6, bool))
    signs = np.array(list(itertools.product((-1, 1), repeat=6)))
    g = (signs * B) @ U.T
    worst = g[np.argmax(np.sum(g * g, axis=1))]
    g2 = max_parity_offset(CAL, B)
    assert g2 >= float(worst @ worst) - 1e-12
    rng = np.random.default_rng(11)
    df = 3
    for w, a, T0, T1, f in zip(thr.scales, up.alpha, thr.threshold, up.threshold,
                               up.variance_factor, strict=True):
        S = w * worst + np.sqrt(w) * rng.normal(size=(40000, df))
        D = np.sum(S * S, axis=1) / w
        a0 = thr.alpha[thr.scales.index(w)]
        p_up = float(np.mean(D * thr.variance_factor[0] / f > T1))
        sd = np.sqrt(a0 * (1 - a0) / D.size)
        assert p_up <= a0 + 4 * sd, (w, p_up, a0)
        if w >= 8:
            assert float(np.mean(D > T0)) > 3 * a0
        assert T1 >= T0 and a <= a0
    mon = Monitor(CAL, up)
    assert mon.model.thr == pytest.approx(up.threshold, rel=1e-9)
    assert "bias bound" in up.notes
    assert rate_shift_bound(CAL, B) > 0.05 * DPS


def test_no_bound_changes_nothing():
    thr = default_thresholds(CAL)
    assert bounded_thresholds(thr, CAL, np.zeros(6)) is thr
    p = stats.chi2.sf(thr.threshold[0], 3)
    assert p == pytest.approx(thr.alpha[0], rel=1e-6)
