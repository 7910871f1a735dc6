"""Integrity in the spirit of GNSS RAIM: the protection level of the reconstructed rate.

For a set of healthy sensors with whitened parity columns u_i (z = A·V·y, Cov z = I) and
reconstruction matrix G, a bias b on sensor i shifts the single-sample statistic's
noncentrality to λ = b²·|u_i|²/f₁. The minimum detectable bias at missed-detection
probability P_md is ``MDB_i = sqrt(λ*·f₁)/|u_i|`` with ``ncx2.cdf(T₁, df, λ*) = P_md``; it moves
ω̂ by ``MDB_i·|G e_i|``. The protection level is the worst sensor's, plus k·σ of the noise::

    PL = max_i MDB_i·|G e_i| · sqrt(1 + γ₁) + k · sqrt(f₁·λmax(GΣGᵀ) + ρ·λmax(G diag(Σ) Gᵀ))

γ₁ = κ·ρ/f₁ the threshold inflation for the calibration uncertainty at the current rate
(ρ = max_i ω̂ᵀC_iω̂/Σ_ii), k = Φ⁻¹(1 − P_md/2), f₁ the variance factor of the single-sample
scale (1 for white noise; the overbound of the measured residual where the calibration
holds one, :mod:`fdi.tails`). The level holds only where the answer is verified: the
monitor reports it infinite while a detection is active or out of the envelope. All but ρ
are precomputed per healthy set.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from fdi.detector import minimum_detectable_noncentrality

__all__ = ["ProtectionLevel", "protection_level_constants"]


@dataclass(frozen=True)
class ProtectionLevel:
    """Per-set constants of ``PL(ρ) = a·sqrt(1 + b·ρ) + c·sqrt(d + e·ρ)`` (rad/s).

    ``a`` is inf when the set cannot detect (fewer than 4 sensors).
    """

    a: float
    b: float
    c: float
    d: float
    e: float
    mdb: tuple[float, ...]

    def __call__(self, rho: float) -> float:
        """Protection level for the calibration ratio ``rho`` (same arithmetic as the block)."""
        return self.a * math.sqrt(1.0 + self.b * rho) + self.c * math.sqrt(self.d + self.e * rho)


def protection_level_constants(U: np.ndarray, G: np.ndarray, noise_cov: np.ndarray,
                               threshold1: float, f1: float, kappa: float,
                               missed_detection: float) -> ProtectionLevel:
    """Constants of the protection level for one healthy set.

    Parameters
    ----------
    U : ndarray, shape (df, m)
        Whitened parity columns of the healthy sensors (df may be 0).
    G : ndarray, shape (3, m)
        Reconstruction matrix restricted to the healthy sensors.
    noise_cov : ndarray, shape (m, m)
        Noise covariance of the healthy sensors.
    threshold1 : float
        Threshold of the single-sample test.
    f1 : float
        Variance factor of the single-sample scale.
    kappa : float
        Calibration-uncertainty constant of the set.
    missed_detection : float
    """
    df = U.shape[0]
    k = float(stats.norm.isf(missed_detection / 2.0))
    P = G @ noise_cov @ G.T
    # the noise term carries the same variance factor (an overbound of the measured
    # single-sample residual where the calibration holds one) as the detection term
    d = float(f1 * np.linalg.eigvalsh(P).max()) if G.size else float("inf")
    Gd = G @ np.diag(np.diag(noise_cov)) @ G.T
    e = float(np.linalg.eigvalsh(Gd).max()) if G.size else 0.0
    if df < 1:
        return ProtectionLevel(float("inf"), 0.0, k, d, e, ())
    lam = minimum_detectable_noncentrality(threshold1, df, missed_detection)
    un = np.linalg.norm(U, axis=0)
    gn = np.linalg.norm(G, axis=0)
    mdb = np.where(un > 1e-12, np.sqrt(lam * f1) / np.where(un > 1e-12, un, 1.0), np.inf)
    a = float(np.max(mdb * gn))
    return ProtectionLevel(a, kappa / f1, k, d, e, tuple(float(x) for x in mdb))
