"""Accelerometer multi-position test (seed 001 Eqs. 5-10)."""

import numpy as np
import pytest

from calibration.multiposition import multiposition
from fdi.errors import CalibrationError

G = 9.8


def _positions():
    F = np.array([[0, 0, -G], [0, -G, 0], [0, 0, G], [0, G, 0], [G, 0, 0], [-G, 0, 0],
                  [-G * 0.7071, G * 0.7071, 0], [G * 0.7071, G * 0.7071, 0],
                  [-G * 0.7071, 0, G * 0.7071], [G * 0.7071, 0, G * 0.7071]])  # Table 1
    return F


def test_recovers_gain_and_offset_exactly():
    rng = np.random.default_rng(7)
    F = _positions()
    a = rng.normal(size=(6, 3)) * 500.0                    # LSB per m/s^2
    c = rng.normal(size=6) * 2e4                           # LSB
    U = F @ a.T + c
    N = rng.integers(1000, 3000, size=F.shape[0]).astype(float)
    mp = multiposition(U, N, F)
    np.testing.assert_allclose(mp.a, a, rtol=1e-9, err_msg="a = m/SF (Eq. 7)")
    np.testing.assert_allclose(mp.c, c, rtol=1e-9, err_msg="c = b/SF (Eq. 7)")
    np.testing.assert_allclose(mp.S, np.column_stack([F, np.ones(10)]), err_msg="S (Eq. 8)")


def test_covariance_is_seed001_eq19a():
    F = _positions()
    N = np.full(10, 2000.0)
    mp = multiposition(np.zeros((10, 1)), N, F)
    np.testing.assert_allclose((mp.op / N) @ mp.op.T, np.linalg.inv(mp.S.T @ mp.S) / 2000.0,
                               rtol=1e-9, atol=1e-15,
                               err_msg="cov/sigma^2 = (S^T S)^-1 / N (Eq. 19a)")


def test_not_enough_positions():
    F = _positions()[[0, 2, 0, 2]]                          # gravity along z only
    with pytest.raises(CalibrationError) as e:
        multiposition(F @ np.ones((3, 1)), np.full(4, 100.0), F, step_numbers=[1, 3, 5, 7],
                      source="s.dir")
    assert "s.dir" in str(e.value) and "1, 3, 5, 7" in str(e.value)
    assert "rank of S is 2" in str(e.value)
