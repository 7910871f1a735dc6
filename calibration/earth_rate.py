"""Earth rate from the modulation of the outer-axis steps (seed 000, Results and Fig. 3).

While the outer (vertical) axis turns, the horizontal Earth rate ``Ω_h = Ω·cos φ`` turns in
the body frame at the table rate, so each gyro's compensated output (table rate and bias
removed) carries a sinusoid at the table rate::

    y_i(t) = Ω_h·[cos ψ·n_i(t) + sin ψ·e_i(t)] + const_i,step + η_i(t)

with ``n_i = (C_nb·h̃_i)·North`` and ``e_i = (C_nb·h̃_i)·East`` known from the table angles and
the calibrated axis ``h̃_i``, and ψ the (unknown) heading of the table's zero. The constant
per sensor and step absorbs the bias and the vertical component ``Ω·sin φ``. The two
coefficients ``A = Ω_h cos ψ``, ``B = Ω_h sin ψ`` are fitted by linear (weighted) least squares
over all sensors and outer-axis steps; ``Ω_h = |(A, B)|`` and ``Ω = Ω_h / cos φ``.

Seed 000 reports 15.8721 °/h from its real FOG data (k = 3..8, steps 5-16); on simulated
``tetrad-paper`` sessions this fit recovers 15.041 °/h within its σ (≈ 0.15 °/h).
Seed 000 fits the wavelet-denoised outputs (db4, level 8); the same linear filter is applied
to the regressors so the fit stays unbiased. Denoised samples are correlated, so the
uncertainty is *not* taken from the denoised residuals: it is the white-noise sandwich
``(GᵀWG)⁻¹(GᵀWΣWG)(GᵀWG)⁻¹`` with ``Σ`` the per-sample noise covariance from the calibration
residuals (the low-pass filter leaves the regressors, at 0.03 Hz, unchanged, so the filtered
estimate has the same variance to first order). A second, independent figure, the scatter
of per-step estimates, is kept as a check.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibration.residuals import segment_means
from calibration.wavelet import denoise
from fdi.units import DPH

__all__ = ["EarthRateFit", "fit_earth_rate"]


@dataclass(frozen=True)
class EarthRateFit:
    """Earth-rate estimate from the outer-axis modulation.

    Attributes
    ----------
    rate_dph, rate_dph_sd : float
        Ω and its standard deviation (°/h).
    horizontal_dph, horizontal_dph_sd : float
        Ω_h = Ω cos φ (°/h).
    heading_offset_deg, heading_offset_deg_sd : float
        ψ: angle from North to the table's zero direction (deg), NaN when fixed.
    steps : tuple of int
        Outer-axis steps used (1-based).
    per_step_dph : ndarray, shape (K,)
        Ω from each step alone (°/h).
    scatter_sd_dph : float
        Standard deviation of the mean from the scatter of the per-step values (°/h);
        NaN with fewer than 2 steps.
    n_samples : int
    denoised : bool
    y, fitted : ndarray, shape (M, n)
        The (denoised) compensated outputs used and the fitted modulation + constants
        (SI), for plots; not written to files.
    """

    rate_dph: float
    rate_dph_sd: float
    horizontal_dph: float
    horizontal_dph_sd: float
    heading_offset_deg: float
    heading_offset_deg_sd: float
    steps: tuple[int, ...]
    per_step_dph: np.ndarray
    scatter_sd_dph: float
    n_samples: int
    denoised: bool
    y: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)
    fitted: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)

    def to_dict(self) -> dict:
        """JSON-ready summary (without the sample arrays)."""
        return {"rate_dph": self.rate_dph, "rate_dph_sd": self.rate_dph_sd,
                "horizontal_dph": self.horizontal_dph,
                "horizontal_dph_sd": self.horizontal_dph_sd,
                "heading_offset_deg": self.heading_offset_deg,
                "heading_offset_deg_sd": self.heading_offset_deg_sd,
                "steps": list(self.steps), "per_step_dph": self.per_step_dph.tolist(),
                "scatter_sd_dph": self.scatter_sd_dph, "n_samples": self.n_samples,
                "denoised": self.denoised}


def _demean(X: np.ndarray, seg: np.ndarray, nseg: int) -> np.ndarray:
    """Remove the mean of each segment from X (M, ...) along axis 0."""
    flat = X.reshape(X.shape[0], -1)
    _, (means,) = segment_means(seg, nseg, flat)
    return (flat - means[seg]).reshape(X.shape)


def _normal(G: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample normal-equation terms: ``Σ_i w_i g g^T`` (M, p, p) and ``Σ_i w_i g y`` (M, p)."""
    Gw = G * w[None, :, None]
    return np.matmul(np.swapaxes(Gw, 1, 2), G), np.einsum("tia,ti->ta", Gw, y)


def fit_earth_rate(y: np.ndarray, up_axes: np.ndarray, step: np.ndarray, noise_cov: np.ndarray,
                   latitude_rad: float, *, denoise_outputs: bool = True,
                   heading_known: bool = False, wavelet: str = "db4",
                   level: int = 8) -> EarthRateFit:
    """Fit the horizontal Earth rate to the compensated outer-axis outputs.

    Parameters
    ----------
    y : ndarray, shape (M, n)
        Compensated outputs ``SF·u − h̃·ω_table`` (rad/s) of the outer-axis samples (bias
        may stay in: it is absorbed by the per-step constants).
    up_axes : ndarray, shape (M, 3, n)
        ``C_nb·h̃_i`` per sample: each sensor's axis in ENU coordinates (x East, y North).
    step : ndarray of int, shape (M,)
        Step number of each sample (constants are fitted per sensor and step; the wavelet
        runs on each step separately).
    noise_cov : ndarray, shape (n, n)
        Per-sample noise covariance of the compensated outputs (rad/s)².
    latitude_rad : float
    denoise_outputs : bool
        Fit the wavelet-denoised outputs (seed 000) instead of the raw ones.
    heading_known : bool
        The table's zero points North exactly: fit ``A`` only (ψ = 0).
    """
    y = np.asarray(y, float)
    M = y.shape[0]
    Sigma = np.asarray(noise_cov, float)
    d = np.diag(Sigma)
    w = 1.0 / d if np.all(d > 0) else np.ones_like(d)       # noise-free data: equal weights
    G = np.stack([up_axes[:, 1, :], up_axes[:, 0, :]], axis=-1)      # (M, n, 2): north, east
    if heading_known:
        G = G[..., :1]
    steps, seg = np.unique(step, return_inverse=True)
    K = len(steps)
    Gd, yd = G, y
    if denoise_outputs:
        Gd, yd = np.empty_like(G), np.empty_like(y)
        for k in range(K):
            m = seg == k
            yd[m] = denoise(y[m], wavelet=wavelet, level=level)
            Gd[m] = denoise(G[m].reshape(int(m.sum()), -1), wavelet=wavelet,
                            level=level).reshape(G[m].shape)
    Gc = _demean(Gd, seg, K)
    yc = _demean(yd, seg, K)
    At, bt = _normal(Gc, yc, w)
    p = G.shape[-1]
    cnt, (Am, bm) = segment_means(seg, K, At.reshape(M, -1), bt)
    A_step = (Am * cnt[:, None]).reshape(K, p, p)              # per-step normal equations
    b_step = bm * cnt[:, None]
    theta = np.linalg.solve(A_step.sum(axis=0), b_step.sum(axis=0))
    # white-noise sandwich with the raw (unfiltered) demeaned regressors
    G0 = _demean(G, seg, K)
    A = np.matmul(np.swapaxes(G0 * w[None, :, None], 1, 2), G0).sum(axis=0)
    Wsw = (w[:, None] * Sigma) * w[None, :]
    B = G0.reshape(-1, p).T @ np.matmul(Wsw, G0).reshape(-1, p)
    Ainv = np.linalg.inv(A)
    C = Ainv @ B @ Ainv
    if heading_known:
        h, h_sd = float(theta[0]), float(np.sqrt(C[0, 0]))
        psi, psi_sd = float("nan"), float("nan")
    else:
        h = float(np.hypot(theta[0], theta[1]))
        u = theta / h
        h_sd = float(np.sqrt(u @ C @ u))
        psi = float(np.arctan2(theta[1], theta[0]))
        v = np.array([-theta[1], theta[0]]) / h**2
        psi_sd = float(np.sqrt(v @ C @ v))
    cphi = abs(np.cos(latitude_rad))
    per = np.full(K, np.nan)
    for k in range(K):
        try:
            tk = np.linalg.solve(A_step[k], b_step[k])
        except np.linalg.LinAlgError:
            continue
        per[k] = (tk[0] if heading_known else np.hypot(*tk)) / cphi / DPH
    ok = np.isfinite(per)
    scatter = float(np.std(per[ok], ddof=1) / np.sqrt(ok.sum())) if ok.sum() >= 2 else np.nan
    fitted = yd - yc + Gc @ theta
    return EarthRateFit(
        rate_dph=h / cphi / DPH, rate_dph_sd=h_sd / cphi / DPH,
        horizontal_dph=h / DPH, horizontal_dph_sd=h_sd / DPH,
        heading_offset_deg=float(np.degrees(psi)), heading_offset_deg_sd=float(np.degrees(psi_sd)),
        steps=tuple(int(s) for s in steps), per_step_dph=per, scatter_sd_dph=scatter,
        n_samples=M, denoised=denoise_outputs, y=yd, fitted=fitted)
