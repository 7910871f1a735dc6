"""Gyro rate test (seed 000 Eqs. 16-19): inject known gains, recover them exactly."""

import numpy as np
import pytest

from calibration.rate_test import group_misalignment_matrices, rate_test, split_gain
from fdi.calfile import misalignment_angles
from fdi.errors import CalibrationError
from fdi.geometry import tetrad
from fdi.parity import calibrated_axes

M1 = np.array([[0.9999895, -0.0019974, 0.0041171],          # seed 000 Eq. 26
               [0.0004597, 0.9999998, -0.0004378],
               [-0.0009892, 0.0003843, 0.9999994]])
M2 = np.array([[0.99999, 0.0010024, 0.0016921]])


def _design(rng, n_pairs=8, rate=0.17):
    """Step mean inputs of n_pairs ±ω pairs about random axes, plus Earth-like offsets."""
    axes = rng.normal(size=(n_pairs, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    X = np.empty((2 * n_pairs, 3))
    X[0::2] = rate * axes + 5e-5
    X[1::2] = -rate * axes + 5e-5
    pairs = [(2 * k, 2 * k + 1) for k in range(n_pairs)]
    return X, pairs


def test_recovers_injected_gains_exactly():
    rng = np.random.default_rng(1)
    X, pairs = _design(rng)
    a_true = rng.normal(size=(5, 3)) * 40.0               # raw per rad/s
    c_true = rng.normal(size=5) * 3.0
    U = X @ a_true.T + c_true                              # step means, noise-free
    N = rng.integers(2000, 4000, size=X.shape[0]).astype(float)
    rt = rate_test(U, N, X, pairs)
    np.testing.assert_allclose(rt.a, a_true, rtol=1e-10, err_msg="a = h/SF (Eq. 18)")
    np.testing.assert_allclose(rt.R, X[0::2] - X[1::2], err_msg="R rows (Eq. 16)")
    np.testing.assert_allclose(rt.G, U[0::2] - U[1::2], err_msg="G-bar (Eq. 18)")
    np.testing.assert_allclose(rt.chi2(np.ones(5), N), 0.0, atol=1e-12,
                               err_msg="chi2 of an exact fit")


def test_operator_covariance_is_sigma2_RtWR_inverse():
    rng = np.random.default_rng(2)
    X, pairs = _design(rng, n_pairs=6)
    N = rng.integers(500, 4000, size=X.shape[0]).astype(float)
    rt = rate_test(np.zeros((X.shape[0], 1)), N, X, pairs)
    cov_op = (rt.op / N) @ rt.op.T
    W = np.diag(rt.weights)
    np.testing.assert_allclose(cov_op, np.linalg.inv(rt.R.T @ W @ rt.R), rtol=1e-10,
                               err_msg="cov(a)/sigma^2 = (R^T W R)^-1 (seed 001 Eq. 19b)")
    # equal step lengths: the unweighted paper formula times 2/N
    Ne = np.full(X.shape[0], 1000.0)
    rt2 = rate_test(np.zeros((X.shape[0], 1)), Ne, X, pairs)
    np.testing.assert_allclose((rt2.op / Ne) @ rt2.op.T,
                               np.linalg.inv(rt2.R.T @ rt2.R) * 2 / 1000, rtol=1e-10,
                               err_msg="equal steps: sigma^2 (2/N) (R^T R)^-1")


def test_operator_covariance_matches_monte_carlo():
    rng = np.random.default_rng(3)
    X, pairs = _design(rng, n_pairs=4)
    N = np.full(X.shape[0], 50.0)
    a_true = np.array([[30.0, -2.0, 1.0]])
    rt0 = rate_test(X @ a_true.T, N, X, pairs)
    sig = 0.7
    est = []
    for _ in range(4000):
        U = X @ a_true.T + rng.normal(0, sig / np.sqrt(N))[:, None]
        est.append(rate_test(U, N, X, pairs).a[0])
    emp = np.cov(np.array(est).T)
    pred = sig**2 * (rt0.op / N) @ rt0.op.T
    np.testing.assert_allclose(np.sqrt(np.diag(emp)), np.sqrt(np.diag(pred)), rtol=0.08,
                               err_msg="sd of a: Monte Carlo vs sigma^2 op diag(1/N) op^T")


def test_rank_deficient_names_source_and_steps():
    rng = np.random.default_rng(4)
    X = np.zeros((4, 3))
    X[0, 0], X[1, 0], X[2, 1], X[3, 1] = 0.17, -0.17, 0.17, -0.17   # only x and y excited
    U = X @ rng.normal(size=(3, 2)) + 1.0
    with pytest.raises(CalibrationError) as e:
        rate_test(U, np.full(4, 100.0), X, [(0, 1), (2, 3)], step_numbers=[3, 4, 7, 8],
                  source="sess/dir")
    msg = str(e.value)
    assert "sess/dir" in msg and "3/4" in msg and "7/8" in msg and "rank of R is 2" in msg
    with pytest.raises(CalibrationError, match="no paired rate steps"):
        rate_test(U, np.full(4, 100.0), X, [], source="s")


def test_split_gain_values_and_jacobian():
    rng = np.random.default_rng(5)
    h0 = np.array([1, 1, 1]) / np.sqrt(3)
    h = h0 + np.array([2e-3, -1e-3, 0.5e-3])
    h /= np.linalg.norm(h)
    sf = 0.0021                                           # rad/s per mV
    a = h / sf
    C = np.diag([0.04, 0.09, 0.01])
    g = split_gain(a, C, h0)
    assert g.scale_factor == pytest.approx(sf, rel=1e-12), "SF = 1/|a| (Eq. 19)"
    np.testing.assert_allclose(g.axis, h, atol=1e-14, err_msg="axis = a/|a|")
    np.testing.assert_allclose(g.misalignment, misalignment_angles(h0, h), atol=1e-15,
                               err_msg="misalignment angles")

    def f(av):
        return np.concatenate([[1 / np.linalg.norm(av)], av / np.linalg.norm(av),
                               misalignment_angles(h0, av)])

    eps = 1e-6
    Jn = np.column_stack([(f(a + eps * e) - f(a - eps * e)) / (2 * eps) for e in np.eye(3)])
    np.testing.assert_allclose(g.jac, Jn, rtol=1e-5, atol=1e-12,
                               err_msg="Jacobian of (SF, axis, angles) w.r.t. a")
    sd_sf = np.sqrt(Jn[0] @ C @ Jn[0])
    assert g.scale_factor_sd == pytest.approx(sd_sf, rel=1e-5), "SF sd"
    np.testing.assert_allclose(g.misalignment_sd, np.sqrt(np.diag(Jn[4:] @ C @ Jn[4:].T)),
                               rtol=1e-5, err_msg="misalignment sd")
    del rng


def test_misalignment_matrices_as_the_paper_prints_them():
    cfg = tetrad()
    Ht = calibrated_axes(cfg.H, cfg.groups, [M1, M2])
    Ht /= np.linalg.norm(Ht, axis=1, keepdims=True)
    Ms = group_misalignment_matrices(cfg.H, Ht, cfg.groups)
    M1n = M1 / np.linalg.norm(M1 @ cfg.H[:3], axis=1, keepdims=True)
    np.testing.assert_allclose(Ms[0], M1n, atol=1e-12, err_msg="M1 = H~1 H1^-1 (Eq. 14, 26)")
    np.testing.assert_allclose(Ms[1], M2 / np.linalg.norm(M2), atol=1e-12,
                               err_msg="M2 = h~4 (H2 = I3)")
    assert Ms[1].shape == (1, 3)
