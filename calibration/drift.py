"""Measure the slow drift of a calibration residual's whitened parity (:mod:`fdi.drift`).

The residual (N, n) of a calibration is whitened as the monitor whitens its parity
(:func:`calibration.tails.whitened_parity`: ``z = L⁻¹·V·r`` with ``L·Lᵀ = VΣVᵀ``). For
dyadic block lengths m = 1, 2, 4, ... samples with at least :data:`fdi.drift.MIN_BLOCKS`
non-overlapping blocks, the Allan covariance ``C_A = ½·mean(Δb Δbᵀ)`` of the ν adjacent
differences of block means b, and its excess over white noise summed over the parity
directions,

    e = tr C_A − df/m    where tr C_A exceeds the white level significantly, else 0,

are kept in a :class:`fdi.drift.DriftModel`. Significantly: above the upper 99 % point of
the white-noise sampling law (for white noise ``2ν·m·tr C_A`` is a sum of χ²(1) weighted
by the eigenvalues λ_k = 2 − 2cos(πk/B) of the differencing of B blocks, taken as
χ²(ν_eff)·mean/ν_eff with Satterthwaite's ``ν_eff = df·(Σλ)²/Σλ²``), so a white residual
shows no drift at a τ 99 times in 100; where it is significant the expected white part
df/m is removed (an unbiased excess).
The level is strict because the random-walk extrapolation multiplies a chance excess at
the longest τ by τ_h/τ_L (about 20 for a horizon of the span).
The trace, not the largest eigenvalue, because the largest eigenvalue of a covariance of
few differences is biased upwards by white noise alone (about fourfold for ν = df = 9);
a drift along one direction has all of the trace, one spread over several is
over-counted, which errs on the conservative side.

Blocks use the valid rows only (rows with a NaN are dropped and the rest taken in time
order); a recording with gaps should be measured per run, which the static calibration
does not need. The largest eigenvalue of a sample covariance from few differences is
biased upwards, which errs on the conservative side.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from calibration.tails import whitened_parity
from fdi.drift import MIN_BLOCKS, DriftModel

__all__ = ["WHITE_BOUND", "allan_excess", "fit_drift_model"]

WHITE_BOUND = 0.99
"""Quantile of the white-noise sampling law of tr C_A above which an excess counts
(module docstring)."""


def allan_excess(z: np.ndarray, sample_rate_hz: float
                 ) -> tuple[tuple[float, ...], tuple[int, ...], tuple[float, ...]]:
    """τ (s), blocks and excess e(τ) of whitened parity ``z`` (N, df) (module docstring)."""
    z = np.asarray(z, float)
    taus, blocks, excess = [], [], []
    m = 1
    df = z.shape[1]
    while z.shape[0] // m >= MIN_BLOCKS:
        nb = z.shape[0] // m
        b = z[: nb * m].reshape(nb, m, df).mean(axis=1)
        d = np.diff(b, axis=0)
        nu = d.shape[0]
        tr = 0.5 * float(np.sum(d * d)) / nu
        k = np.arange(1, nb)
        lam = 2.0 - 2.0 * np.cos(np.pi * k / nb)          # eigenvalues of the differencing
        dof = df * float(lam.sum()) ** 2 / float(np.sum(lam * lam))
        bound = df / m * float(stats.chi2.isf(1.0 - WHITE_BOUND, dof)) / dof
        e = tr - df / m if tr > bound else 0.0
        taus.append(m / float(sample_rate_hz))
        blocks.append(int(nb))
        excess.append(max(e, 0.0))
        m *= 2
    return tuple(taus), tuple(blocks), tuple(excess)


def fit_drift_model(residual: np.ndarray, H: np.ndarray, noise_cov: np.ndarray,
                    sample_rate_hz: float, *, source: str = "") -> DriftModel | None:
    """The drift model of a calibration residual.

    Parameters
    ----------
    residual : ndarray, shape (N, n)
        Residual per sensor (SI) in time order, NaN rows where a sample is not used.
    H : ndarray, shape (n, 3)
        Calibrated axes.
    noise_cov : ndarray, shape (n, n)
        The calibration's per-sample noise covariance (SI²).
    sample_rate_hz : float
    source : str
        What the residual is (recorded).

    Returns
    -------
    DriftModel or None
        None without a parity space (n < 4), with a singular parity noise covariance, or
        with fewer than :data:`fdi.drift.MIN_BLOCKS` valid samples.
    """
    H = np.asarray(H, float)
    if H.shape[0] < 4:
        return None
    try:
        z, valid = whitened_parity(residual, H, noise_cov)
    except np.linalg.LinAlgError:
        return None
    z = z[valid]
    if z.shape[0] < MIN_BLOCKS:
        return None
    fs = float(sample_rate_hz)
    tau, blocks, excess = allan_excess(z, fs)
    return DriftModel(df=int(z.shape[1]), samples=int(z.shape[0]), sample_rate_hz=fs,
                      span_s=z.shape[0] / fs, tau_s=tau, blocks=blocks, excess=excess,
                      source=source)
