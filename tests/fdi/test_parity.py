"""Parity space: seed 000 oracles and invariants."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fdi.errors import ConfigError
from fdi.geometry import Configuration, cone6, tetrad
from fdi.parity import calibrated_axes, isolability, parity_matrix

# seed 000 Eq. 26
M1 = np.array([[0.9999895, -0.0019974, 0.0041171],
               [0.0004597, 0.9999998, -0.0004378],
               [-0.0009892, 0.0003843, 0.9999994]])
M2 = np.array([[0.99999, 0.0010024, 0.0016921]])


def test_tetrad_parity_is_seed000_eq24():
    V = parity_matrix(tetrad().H)
    np.testing.assert_allclose(V[0], [-0.40825, -0.40825, -0.40825, 0.70711], atol=5e-6,
                               err_msg="v (seed 000 Eq. 24)")


def test_tetrad_calibrated_parity_is_seed000_eq25():
    cfg = tetrad()
    Ht = calibrated_axes(cfg.H, cfg.groups, [M1, M2])
    Vc = parity_matrix(Ht)
    # Eq. 25 is printed to 5 decimals: agreement "to 4 decimals" means |Δ| < 5e-5.
    np.testing.assert_allclose(Vc[0], [-0.40955, -0.40903, -0.40585, 0.70729], atol=5e-5,
                               err_msg="v_c (seed 000 Eq. 25)")


def test_cone6_parity_and_isolation():
    cfg = cone6()
    V = parity_matrix(cfg.H)
    assert V.shape == (3, 6)
    iso = isolability(V)
    assert iso["can_isolate"]
    assert not isolability(parity_matrix(tetrad().H))["can_isolate"]


def test_zeroing_a_row_keeps_parity_of_the_rest():
    cfg = cone6()
    healthy = np.ones(6, bool)
    healthy[2] = False
    V = parity_matrix(cfg.H, healthy)
    assert V.shape == (2, 6)
    np.testing.assert_allclose(V[:, 2], 0.0, err_msg="column of the isolated sensor")
    np.testing.assert_allclose(V @ cfg.H, 0.0, atol=1e-12)


def test_non_unit_and_rank_deficient_axes_rejected():
    with pytest.raises(ConfigError, match="norm"):
        Configuration("x", np.array([[1, 0, 0], [0, 1, 0], [0, 0, 2.0], [1, 0, 0]]), ())
    with pytest.raises(ConfigError, match="rank"):
        Configuration("x", np.array([[1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0.0]]), ())


unit = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3).filter(
    lambda v: 0.2 < np.linalg.norm(v))


@settings(max_examples=200, deadline=None)
@given(st.lists(unit, min_size=4, max_size=9))
def test_parity_invariants(rows):
    H = np.array(rows, float)
    H /= np.linalg.norm(H, axis=1)[:, None]
    if np.linalg.matrix_rank(H, tol=1e-3) < 3:
        return
    V = parity_matrix(H)
    assert V.shape == (H.shape[0] - 3, H.shape[0])
    np.testing.assert_allclose(V @ H, 0.0, atol=1e-9)
    np.testing.assert_allclose(V @ V.T, np.eye(V.shape[0]), atol=1e-9)
