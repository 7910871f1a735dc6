"""Gyro rate test by least squares (seed 000 Eqs. 16-19, seed 001 Eqs. 11-15).

Model per sensor (seed 000 Eq. 13, seed 001 Eq. 1), raw units ``u``::

    SF·u = h̃·x + b + η   ⇔   u = a·x + c,   a = h̃/SF (raw per SI input),  c = b/SF

For a pair of opposite-rate steps (k, p) the step means differ by ``ū_k − ū_p = a·(x̄_k − x̄_p)``
(bias and any constant input cancel). Stacking the pairs gives ``Ḡ = R·a`` with the rows of
``R`` the differences of the mean body-frame inputs (seed 000 Eq. 16-17: ``R`` is written in
the subsystem frame ``H_j``; rimu estimates ``a`` directly in the MB frame, which is the same
solution re-expressed: ``a = H_jᵀ·m_i/SF_i``). The least-squares solution (seed 000 Eq. 18,
seed 001 Eq. 13) is weighted by the number of samples in each step (identical to the
unweighted one when all steps have the same length). The unit-norm constraint (seed 000
Eq. 19, seed 001 Eq. 10) splits ``a`` into ``SF = 1/|a|`` and ``h̃ = a/|a|``.

Every estimate here is a *linear operator on segment means* (a segment is a step or part
of one), so its covariance under white per-sample noise is exact:
``cov = σ²·op·diag(1/N_seg)·opᵀ`` (seed 001 Eq. 19b: ``σ²(RᵀR)⁻¹`` for equal steps).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fdi.calfile import misalignment_angles, tangent_basis
from fdi.errors import CalibrationError

__all__ = [
    "GainSplit",
    "RateTestFit",
    "group_misalignment_matrices",
    "rate_test",
    "split_gain",
]

RANK_RTOL = 1e-2
"""Smallest singular value of R (relative to the largest) counted as excitation."""


@dataclass(frozen=True)
class RateTestFit:
    """Least-squares rate test over paired steps (the fit; the calibration file's record of
    it is :class:`fdi.extras.RateTest`).

    Attributes
    ----------
    pairs : ndarray of int, shape (P, 2)
        Step positions (0-based rows of the step arrays) differenced: row k minus row p.
    R : ndarray, shape (P, 3)
        Differences of mean body inputs (rad/s), seed 000 Eq. 16.
    weights : ndarray, shape (P,)
        Weight of each difference, ``1/(1/N_k + 1/N_p)``.
    op : ndarray, shape (3, S)
        ``a = op @ ū`` for the step means ``ū`` (S,) of one sensor.
    a : ndarray, shape (n, 3)
        Estimated ``h̃_i/SF_i`` per sensor (raw per rad/s).
    G : ndarray, shape (P, n)
        Differences of the step means (raw), seed 000 Eq. 18's Ḡ.
    """

    pairs: np.ndarray
    R: np.ndarray
    weights: np.ndarray
    op: np.ndarray
    a: np.ndarray
    G: np.ndarray

    def chi2(self, sigma_raw: np.ndarray, counts: np.ndarray) -> np.ndarray:
        """Weighted residual sum of squares per sensor over its degrees of freedom.

        ≈ 1 when the per-sample noise ``sigma_raw`` (n,) explains the scatter of the step
        differences; ≫ 1 when something else (correlated noise, unmodelled effect) does.
        NaN when there are no spare degrees of freedom.
        """
        k, p = self.pairs[:, 0], self.pairs[:, 1]
        var_unit = 1.0 / counts[k] + 1.0 / counts[p]                  # (P,)
        res = self.G - self.R @ self.a.T                              # (P, n)
        dof = self.R.shape[0] - 3
        if dof <= 0:
            return np.full(self.a.shape[0], np.nan)
        s = np.asarray(sigma_raw, float)
        return np.sum(res**2 / var_unit[:, None], axis=0) / (s**2 * dof)


def rate_test(step_mean_u: np.ndarray, step_counts: np.ndarray, step_mean_x: np.ndarray,
              pairs: Sequence[tuple[int, int]], *, step_numbers: Sequence[int] | None = None,
              source: str = "<memory>") -> RateTestFit:
    """Least-squares gains ``a = h̃/SF`` from paired rate steps (seed 000 Eq. 18).

    Parameters
    ----------
    step_mean_u : ndarray, shape (S, n)
        Mean raw output of each sensor over each step.
    step_counts : ndarray, shape (S,)
        Samples per step.
    step_mean_x : ndarray, shape (S, 3)
        Mean total body-frame input per step (rad/s), from the turntable model.
    pairs : sequence of (k, p)
        0-based step rows to difference (k minus p).
    step_numbers : sequence of int, optional
        1-based step numbers of the S rows, for error messages.
    source : str
        The session file, for error messages.

    Raises
    ------
    CalibrationError
        No pairs, or the pairs do not excite three independent body axes (rank of R < 3).
    """
    U = np.asarray(step_mean_u, float)
    N = np.asarray(step_counts, float)
    X = np.asarray(step_mean_x, float)
    S = U.shape[0]
    nums = list(step_numbers) if step_numbers is not None else list(range(1, S + 1))
    P = np.asarray(pairs, int).reshape(-1, 2)
    if P.shape[0] == 0:
        raise CalibrationError(f"{source}: no paired rate steps (+w/-w); expected at least "
                               "3 pairs exciting three independent body axes")
    D = np.zeros((P.shape[0], S))
    D[np.arange(P.shape[0]), P[:, 0]] = 1.0
    D[np.arange(P.shape[0]), P[:, 1]] = -1.0
    R = D @ X                                                         # seed 000 Eq. 16
    w = 1.0 / (1.0 / N[P[:, 0]] + 1.0 / N[P[:, 1]])
    sv = np.linalg.svd(R, compute_uv=False)
    rank = int(np.sum(sv > RANK_RTOL * sv[0])) if sv.size and sv[0] > 0 else 0
    if rank < 3:
        used = ", ".join(f"{nums[k]}/{nums[p]}" for k, p in P)
        raise CalibrationError(
            f"{source}: steps {used}: the rate pairs excite only {rank} independent body "
            f"axis/axes (rank of R is {rank}); expected rate steps about 3 independent axes")
    Rw = R * w[:, None]
    A = np.linalg.solve(R.T @ Rw, Rw.T @ D)                           # seed 000 Eq. 18
    a = (A @ U).T
    return RateTestFit(pairs=P, R=R, weights=w, op=A, a=a, G=D @ U)


@dataclass(frozen=True)
class GainSplit:
    """``a = h̃/SF`` split by the unit-norm constraint, with first-order covariances.

    Attributes
    ----------
    scale_factor, scale_factor_sd : float
        SF = 1/|a| (SI input per raw unit).
    axis : ndarray, shape (3,)
        h̃ = a/|a|.
    axis_cov : ndarray, shape (3, 3)
    misalignment, misalignment_sd : ndarray, shape (2,)
        Angles (rad) about the nominal axis (:func:`fdi.calfile.misalignment_angles`).
    jac : ndarray, shape (6, 3)
        d(SF, h̃, angles)/da, for joint propagation.
    """

    scale_factor: float
    scale_factor_sd: float
    axis: np.ndarray
    axis_cov: np.ndarray
    misalignment: np.ndarray
    misalignment_sd: np.ndarray
    jac: np.ndarray


def split_gain(a: np.ndarray, cov_a: np.ndarray, axis_nominal: np.ndarray) -> GainSplit:
    """Scale factor, axis and misalignment from ``a`` (seed 000 Eq. 19, seed 001 Eq. 10).

    Parameters
    ----------
    a : ndarray, shape (3,)
        Gain vector ``h̃/SF`` (raw per SI input).
    cov_a : ndarray, shape (3, 3)
    axis_nominal : ndarray, shape (3,)
    """
    a = np.asarray(a, float)
    na = float(np.linalg.norm(a))
    h = a / na
    sf = 1.0 / na
    j_sf = -a / na**3                                                 # d(1/|a|)/da
    j_h = (np.eye(3) - np.outer(h, h)) / na                           # d(a/|a|)/da
    h0 = np.asarray(axis_nominal, float) / np.linalg.norm(axis_nominal)
    E = tangent_basis(h0)
    s = E @ h
    c = float(h0 @ h)
    # θ_j = atan2(s_j, c): dθ_j/dh = (c·E_j − s_j·h0)/(s_j² + c²)
    j_ang_h = (c * E - np.outer(s, h0)) / (s**2 + c**2)[:, None]
    j_ang = j_ang_h @ j_h
    J = np.vstack([j_sf, j_h, j_ang])
    C = J @ np.asarray(cov_a, float) @ J.T
    return GainSplit(scale_factor=sf, scale_factor_sd=float(np.sqrt(max(C[0, 0], 0.0))),
                     axis=h, axis_cov=C[1:4, 1:4], misalignment=misalignment_angles(h0, h),
                     misalignment_sd=np.sqrt(np.clip(np.diag(C)[4:6], 0.0, None)), jac=J)


def group_misalignment_matrices(H_nominal: np.ndarray, H_cal: np.ndarray,
                                groups: Sequence[Sequence[int]]) -> tuple[np.ndarray, ...]:
    """M per subsystem as the papers print it: ``H̃_g = M·H_g`` (seed 000 Eq. 14).

    A group of three sensors with invertible nominal rows gets the square
    ``M = H̃_g·H_g⁻¹``; any other group (seed 000's gyro 4, whose ``H₂ = I₃``) gets its
    calibrated rows themselves, ``M = H̃_g`` (k×3), the convention of
    :func:`fdi.parity.calibrated_axes`.
    """
    out = []
    for g in groups:
        idx = list(g)
        Hg, Ht = np.asarray(H_nominal)[idx], np.asarray(H_cal)[idx]
        if len(idx) == 3 and abs(np.linalg.det(Hg)) > 1e-9:
            out.append(Ht @ np.linalg.inv(Hg))
        else:
            out.append(Ht.copy())
    return tuple(out)
