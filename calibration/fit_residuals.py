"""Stage 4 of the calibration: residuals of the gyro fit and the white-noise checks.

Residuals ``r = u − a·x − c (− β·z)`` per sample (raw units) over the bias steps give the
per-sample noise covariance. Two checks test whiteness against the data: the scatter of
the rate-step differences about the fit (:meth:`calibration.rate_test.RateTestFit.chi2`) and
the scatter of the per-step residual means, whose exact expectation under white noise is
computed from the operators: with ``r_step = B·ū_seg``,
``E[Σ_k N_k r_k²] = σ²·tr(D·B·diag(1/N_seg)·Bᵀ)`` (D = diag N_k over the bias steps).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.stats

from calibration.linear_fit import LinearFit
from calibration.problem import GyroProblem
from calibration.rate_test import RateTestFit
from calibration.residuals import noise_covariance

__all__ = ["FitResiduals", "fit_residuals", "whiteness_warnings"]

WARN_ALPHA = 1e-3
"""Level of the whiteness checks that add a warning."""


@dataclass(frozen=True)
class FitResiduals:
    """What the gyro fit leaves over (calibrate stage 4).

    Attributes
    ----------
    mask : ndarray of bool, shape (N,)
        Samples of the bias steps.
    raw : ndarray, shape (N_used, n)
        Residuals in raw units over ``mask``.
    noise_cov_raw : ndarray, shape (n, n)
        Per-sample noise covariance (raw units²), ``4 + m`` parameters removed.
    rate_chi2_dof : ndarray, shape (n,)
        Scatter of the rate-step differences over white noise (NaN: no spare dof).
    rate_dof : int
        Spare degrees of freedom of the rate test (pairs − 3).
    step_chi2_dof : ndarray, shape (n,)
        Scatter of the per-step residual means over white noise (expectation 1).
    step_dof : int
    step_means : ndarray, shape (S_b, n)
        Residual step means (raw) over the bias steps.
    """

    mask: np.ndarray
    raw: np.ndarray
    noise_cov_raw: np.ndarray
    rate_chi2_dof: np.ndarray
    rate_dof: int
    step_chi2_dof: np.ndarray
    step_dof: int
    step_means: np.ndarray


def fit_residuals(problem: GyroProblem, rt: RateTestFit, fit: LinearFit) -> FitResiduals:
    """Residuals, noise covariance and the two whiteness statistics (calibrate stage 4)."""
    m = problem.n_regressors
    bs = np.array(fit.bias_steps)
    mask = (problem.step_pos >= 0) & np.isin(problem.step_pos, bs)
    r_raw = problem.raw[mask] - problem.x[mask] @ fit.a.T - fit.c
    if m:
        r_raw = r_raw - problem.regressors[mask] @ fit.beta.T
    Sigma_raw = noise_covariance(r_raw, dof_used=4 + m)
    cnt = np.maximum(problem.step_count, 1)
    chi2 = rt.chi2(np.sqrt(np.diag(Sigma_raw)), cnt)
    frac = problem.frac
    B = frac[bs] - problem.step_x[bs] @ fit.op[:3] - fit.op[3][None, :]
    if m:
        B = B - (frac[bs] @ np.nan_to_num(problem.seg_z)) @ fit.op[4:]
    r_step = B @ np.nan_to_num(problem.seg_u)                      # (S_b, n) raw
    cb = problem.step_count[bs]
    expect = float(np.trace((cb[:, None] * B * fit.inv_count) @ B.T))
    step_chi2 = (cb @ r_step**2) / (np.diag(Sigma_raw) * max(expect, 1e-300))
    return FitResiduals(mask=mask, raw=r_raw, noise_cov_raw=Sigma_raw, rate_chi2_dof=chi2,
                        rate_dof=rt.R.shape[0] - 3, step_chi2_dof=step_chi2,
                        step_dof=max(len(bs) - 4 - m, 1), step_means=r_step)


def whiteness_warnings(res: FitResiduals, names: tuple[str, ...],
                       widened: bool) -> list[str]:
    """Warning lines for the whiteness checks failing at :data:`WARN_ALPHA`.

    ``widened``: the Gauss-Markov noise model widened the uncertainties.
    """
    consequence = ("the Gauss-Markov noise model (extra['noise_model']) widens the "
                   "uncertainties for correlated noise; an unmodelled effect would not be "
                   "covered") if widened else None
    out: list[str] = []
    checks = (
        (res.rate_dof, res.rate_chi2_dof, "the rate-step differences",
         "correlated noise or an unmodelled effect: ", "the uncertainties are too small"),
        (res.step_dof, res.step_chi2_dof, "the step means of the residuals",
         "correlated noise (bias instability) or an unmodelled effect: ",
         "the bias uncertainty is too small"),
    )
    for dof, chi2_dof, what, cause, default in checks:
        if dof <= 0:
            continue
        lim = float(scipy.stats.chi2.isf(WARN_ALPHA, dof)) / dof
        for i in np.flatnonzero(chi2_dof > lim):
            out.append(f"gyro {names[i]}: {what} scatter more than white noise explains "
                       f"(chi2/dof {chi2_dof[i]:.2f}, 0.1 % limit {lim:.2f}); {cause}"
                       + (consequence or default))
    return out
