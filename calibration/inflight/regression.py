"""Least squares over several residual channels with a coloured-noise-robust covariance.

The model is ``Y[t, c] = X[t, c, :]·β + e[t, c]`` for times ``t`` and channels ``c`` (the
three axes of one IMU, say): parameters may be shared between channels. β̂ is ordinary
least squares over all (t, c). The residuals of a flight are coloured (vibration, drift,
model error), so the covariance of β̂ is the HAC sandwich (Newey & West 1987)::

    cov(β̂) = (XᵀX)⁻¹ · N·Ω · (XᵀX)⁻¹,   s_t = Σ_c X[t, c, :]·e[t, c]   (score of time t)
    Ω = Γ₀ + Σ_{l=1..L} (1 − l/(L+1))·(Γ_l + Γ_lᵀ),   Γ_l = (1/N)·Σ_t s_t s_{t−l}ᵀ

computed through overlapping sums of L+1 consecutive scores (the Bartlett kernel is the
autocorrelation of a box window: Ω = E[B Bᵀ]/(L+1), B a window sum), which costs N·p²
instead of N·p²·L. The lag L follows Andrews (1991): L = 1.1447·(α̂·N)^(1/3) with α̂ from
an AR(1) fit to each score column. Scores of all channels of one time are summed, so the
covariance holds for any correlation between channels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from fdi.errors import CalibrationError

__all__ = ["StackedFit", "andrews_lags", "long_run_covariance", "stacked_lstsq",
           "stacked_ridge", "wald_test"]


@dataclass(frozen=True, eq=False)
class StackedFit:
    """Result of :func:`stacked_lstsq`.

    Attributes
    ----------
    beta : ndarray, shape (p,)
    cov : ndarray, shape (p, p)
        HAC covariance of ``beta``.
    residual : ndarray, shape (N, m)
    lags : int
        Newey–West lag L used.
    cov_white : ndarray, shape (p, p)
        The covariance white, uncorrelated residuals would give (for comparison).
    """

    beta: np.ndarray
    cov: np.ndarray
    residual: np.ndarray
    lags: int
    cov_white: np.ndarray

    @property
    def sd(self) -> np.ndarray:
        """Standard deviations of ``beta``, shape (p,)."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))


def andrews_lags(scores: np.ndarray) -> int:
    """Bartlett-kernel lag from Andrews' (1991) AR(1) plug-in rule.

    Parameters
    ----------
    scores : ndarray, shape (N, p)

    Returns
    -------
    int
        ``ceil(1.1447·(α̂·N)^(1/3))``, at least 1 and at most N/4.
    """
    s = np.asarray(scores, float)
    N = s.shape[0]
    if N < 8:
        return 1
    a, b = s[1:], s[:-1]
    den = np.einsum("ij,ij->j", b, b)
    ok = den > 0
    rho = np.clip(np.einsum("ij,ij->j", a, b)[ok] / den[ok], -0.97, 0.97)
    if rho.size == 0:
        return 1
    sig2 = np.var(a[:, ok] - rho * b[:, ok], axis=0)
    num = np.sum(4 * rho**2 * sig2**2 / ((1 - rho) ** 6 * (1 + rho) ** 2))
    den2 = np.sum(sig2**2 / (1 - rho) ** 4)
    alpha = num / den2 if den2 > 0 else 0.0
    return int(min(max(1, math.ceil(1.1447 * (alpha * N) ** (1 / 3))), N // 4))


def long_run_covariance(scores: np.ndarray, lags: int) -> np.ndarray:
    """Newey–West (Bartlett) long-run covariance Ω of mean-zero scores, shape (p, p).

    ``Ω = mean_t(B_t B_tᵀ)/(L+1)``, ``B_t`` the sum of scores ``t … t+L`` (equal to the
    Bartlett-weighted sum of autocovariances up to end effects of order L/N).
    """
    s = np.asarray(scores, float)
    N, p = s.shape
    L = int(max(0, min(lags, N - 1)))
    if L == 0:
        return s.T @ s / N
    c = np.vstack([np.zeros((1, p)), np.cumsum(s, axis=0)])
    B = c[L + 1:] - c[:-(L + 1)]
    return B.T @ B / (B.shape[0] * (L + 1))


def stacked_lstsq(X: np.ndarray, Y: np.ndarray, *, lags: int | None = None) -> StackedFit:
    """OLS over times and channels with a HAC covariance (module docstring).

    Parameters
    ----------
    X : ndarray, shape (N, m, p)
        Regressors of each time and channel.
    Y : ndarray, shape (N, m)
    lags : int, optional
        Newey–West lag; Andrews' rule when None.

    Returns
    -------
    StackedFit

    Raises
    ------
    CalibrationError
        When the normal matrix is singular.
    """
    X = np.asarray(X, float)
    Y = np.asarray(Y, float)
    N, m, p = X.shape
    Xf = X.reshape(N * m, p)
    M = Xf.T @ Xf
    rhs = Xf.T @ Y.reshape(N * m)
    try:
        Minv = np.linalg.inv(M)
    except np.linalg.LinAlgError:
        raise CalibrationError("the regression is singular (a parameter is not excited)") \
            from None
    beta = Minv @ rhs
    e = Y - (Xf @ beta).reshape(N, m)
    scores = np.einsum("tcp,tc->tp", X, e, optimize=True)
    L = andrews_lags(scores) if lags is None else int(lags)
    omega = long_run_covariance(scores, L)
    cov = Minv @ (N * omega) @ Minv
    dof = max(N * m - p, 1)
    cov_white = Minv * float(np.sum(e * e)) / dof
    return StackedFit(beta, 0.5 * (cov + cov.T), e, L, cov_white)


def stacked_ridge(X: np.ndarray, Y: np.ndarray, weights: np.ndarray, prior_mean: np.ndarray,
                  prior_precision: np.ndarray, *, lags: int | None = None,
                  moment: np.ndarray | None = None,
                  consider: np.ndarray | None = None) -> StackedFit:
    """Weighted least squares with a Gaussian prior as pseudo-observations, HAC covariance.

    The maximum a posteriori estimate of ``Y[t, c] = X[t, c, :]·β + e[t, c]`` with channel
    weights ``w_c`` (``1/Var e_c``) and the prior ``β ~ N(μ, Λ⁻¹)``::

        β̂ = (H + Λ)⁻¹·(Σ_t,c w_c·X[t,c]·Y[t,c] + Λμ − m),   H = Σ_t,c w_c·X[t,c]·X[t,c]ᵀ

    (``m`` an optional known bias of the data moment, removed: the reference noise in the
    regressors, :func:`calibration.inflight.fit._debias`). Its error
    ``(H + Λ)⁻¹·(Σ s_t + Λ(μ − β))`` with the weighted scores ``s_t = Σ_c w_c·X[t,c]·e[t,c]``
    and the prior independent of the noise has the sandwich covariance::

        cov(β̂) = (H + Λ)⁻¹·(N·Ω + Λ)·(H + Λ)⁻¹

    with Ω the Newey–West long-run covariance of the scores (module docstring): the HAC
    covariance where the data inform β, the prior's covariance ``Λ⁻¹`` along the
    directions they do not, and ``(H + Λ)⁻¹`` for white noise of the stated weights.

    ``consider`` (the Schmidt "consider" covariance): regressors ``X_c`` of a part of the
    signal the fit leaves out, ``X_c·β`` with the same β (the variation of a regressor
    held at the prior). It adds ``(H + Λ)⁻¹·X_cᵀWY``-type error ``Σ w·X·X_c·β``, so the
    error becomes ``(H + Λ)⁻¹·(Σ s_t + J·(β − μ))`` with ``J = Σ w·X·X_cᵀ − Λ`` over the
    parameters with a prior, and ``N·Ω + J·Λ⁻¹·Jᵀ`` replaces ``N·Ω + Λ``.

    Parameters
    ----------
    X : ndarray, shape (N, m, p)
    Y : ndarray, shape (N, m)
    weights : ndarray, shape (m,)
        ``1/Var e_c`` per channel (1/(unit of Y)²).
    prior_mean : ndarray, shape (p,)
    prior_precision : ndarray, shape (p, p)
        ``Λ`` (0 rows and columns: no prior on that parameter).
    lags : int, optional
    moment : ndarray, shape (p,), optional
    consider : ndarray, shape (N, m, p), optional
        Regressors left out of the fit whose effect the covariance carries.

    Returns
    -------
    StackedFit
        ``cov_white`` is ``(H + Λ)⁻¹``.

    Raises
    ------
    CalibrationError
        When ``H + Λ`` is singular (a parameter with neither data nor prior).
    """
    X = np.asarray(X, float)
    Y = np.asarray(Y, float)
    w = np.asarray(weights, float)
    N = X.shape[0]
    Xw = X * w[None, :, None]
    M = np.einsum("tcp,tcq->pq", Xw, X, optimize=True) + prior_precision
    rhs = np.einsum("tcp,tc->p", Xw, Y, optimize=True) + prior_precision @ prior_mean
    if moment is not None:
        rhs = rhs - moment
    try:
        Minv = np.linalg.inv(M)
    except np.linalg.LinAlgError:
        raise CalibrationError("the regression is singular (a parameter has neither data "
                               "nor a prior)") from None
    beta = Minv @ rhs
    e = Y - np.einsum("tcp,p->tc", X, beta, optimize=True)
    scores = np.einsum("tcp,tc->tp", Xw, e, optimize=True)
    L = andrews_lags(scores) if lags is None else int(lags)
    omega = long_run_covariance(scores, L)
    idx = np.flatnonzero(np.diag(prior_precision) > 0)
    J = -prior_precision[:, idx]
    if consider is not None:
        J = J + np.einsum("tcp,tcq->pq", Xw, np.asarray(consider, float)[:, :, idx],
                          optimize=True)
    P = np.linalg.inv(prior_precision[np.ix_(idx, idx)]) if idx.size else np.zeros((0, 0))
    cov = Minv @ (N * omega + J @ P @ J.T) @ Minv
    return StackedFit(beta, 0.5 * (cov + cov.T), e, L, 0.5 * (Minv + Minv.T))


def wald_test(fit: StackedFit, idx: np.ndarray | list[int]) -> tuple[float, int, float]:
    """Wald test that ``beta[idx] = 0`` with the HAC covariance.

    Returns
    -------
    stat : float
        ``βᵀ C⁻¹ β`` over the selected parameters.
    df : int
    p_value : float
        From χ²(df).
    """
    i = np.asarray(idx, int)
    b = fit.beta[i]
    C = fit.cov[np.ix_(i, i)]
    try:
        stat = float(b @ np.linalg.solve(C, b))
    except np.linalg.LinAlgError:
        stat = float(b @ np.linalg.pinv(C) @ b)
    return stat, int(i.size), float(stats.chi2.sf(stat, i.size))
