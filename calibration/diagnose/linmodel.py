"""One sensor's residual under a growing linear model, and nested-model F-tests on it.

The model starts from the calibration's own degrees of freedom that any effect test must
keep free (a bias and a scale correction along the calibrated axis: columns ``1`` and
``s = h̃·x``) and grows by the columns of the effects accepted so far. Testing a candidate
``Z`` (N, p) is the classical nested-model F-test for white noise::

    F = (ΔSS / r) / (RSS₁ / (N − k − r)),     r = rank of Z after projection on the model

(ΔSS the sum of squares ``Z`` explains beyond the current model). Exact for Gaussian white
noise. Where the calibration's noise-model selection reads a sensor set's residual as
coloured, :class:`calibration.diagnose.coloured.GlsModel` (same interface) replaces it: tests
against white + Gauss-Markov noise with the noise parameters profiled out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.special
import scipy.stats

__all__ = ["FTest", "LinModel", "projected_whitener"]

_RANK_TOL = 1e-6


@dataclass(frozen=True)
class FTest:
    """Result of one nested-model test.

    Attributes
    ----------
    rank : int
        Columns of ``Z`` left after projection (0: not identifiable beside the model).
    ss : float
        Sum of squares explained (SI²).
    F : float
    p_value : float
        Upper tail of F(rank, dof) (1 when rank is 0).
    log_p : float
        Its natural logarithm (ranks tests whose p-value underflows).
    Z : ndarray, shape (N, p)
        The regressor tested (``LinModel.basis(Z)`` gives its projected basis).
    """

    rank: int
    ss: float
    F: float
    p_value: float
    log_p: float
    Z: np.ndarray


def _log_sf(F: float, r: int, d2: int) -> float:
    """log of the F(r, d2) upper tail; where it underflows, the χ²_r tail of ``r·F``
    (d2 is the sample count, tens of thousands) by its leading asymptotic term."""
    v = float(scipy.stats.f.logsf(F, r, d2))
    if np.isfinite(v):
        return v
    x = r * F
    return float(-x / 2 + (r / 2 - 1) * np.log(x / 2) - scipy.special.gammaln(r / 2))


def projected_whitener(Z: np.ndarray, Q: np.ndarray, gram: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What a nested test of adding ``Z`` to the model spanned by ``Q`` needs, without
    forming the projected regressors.

    With ``s`` the column norms of ``Z`` and ``A = Qᵀ·Z/s``, the Gram matrix of the
    projected, scaled regressors is ``G/(s·sᵀ) − AᵀA = V·diag(λ)·Vᵀ``; ``W = V_k/√λ_k`` over
    the eigenvalues above the rank tolerance, so ``U = (I − QQᵀ)·(Z/s)·W`` is orthonormal
    (N, r) and ``Uᵀe = Wᵀ·(Zᵀe/s)`` for any ``e`` orthogonal to ``Q``.

    Returns
    -------
    Z : ndarray, shape (N, p)
    scale : ndarray, shape (p,)
    A : ndarray, shape (k, p)
    W : ndarray, shape (p, r)
    """
    G = Z.T @ Z if gram is None else gram
    scale = np.sqrt(np.diag(G)).copy()
    scale[scale == 0] = 1.0
    A = (Q.T @ Z) / scale
    lam, V = np.linalg.eigh(G / np.outer(scale, scale) - A.T @ A)
    keep = lam > _RANK_TOL**2
    return Z, scale, A, V[:, keep] / np.sqrt(lam[keep])


class LinModel:
    """Orthonormal basis ``Q`` of the current model and the residual ``e`` of ``y``."""

    def __init__(self, y: np.ndarray, X: np.ndarray) -> None:
        self.y = np.asarray(y, float)
        self.Q = np.zeros((self.y.size, 0))
        self.e = self.y.copy()
        self._update()
        self.add(X)

    @property
    def k(self) -> int:
        """Number of independent model columns."""
        return self.Q.shape[1]

    @property
    def rss(self) -> float:
        """Residual sum of squares."""
        return self._rss

    def _update(self) -> None:
        self._rss = float(self.e @ self.e)

    def project_out(self, Z: np.ndarray) -> np.ndarray:
        """``Z`` minus its projection on the model."""
        Z = np.asarray(Z, float).reshape(self.y.size, -1)
        return Z - self.Q @ (self.Q.T @ Z)

    def _basis(self, Z: np.ndarray, *, exact: bool = False) -> np.ndarray:
        Z = np.asarray(Z, float).reshape(self.y.size, -1)
        scale = np.linalg.norm(Z, axis=0)
        scale[scale == 0] = 1.0
        Zp = self.project_out(Z / scale)
        if Zp.shape[1] == 0:
            return Zp
        lam, V = np.linalg.eigh(Zp.T @ Zp)           # Gram: p×p, cheaper than an SVD
        keep = lam > _RANK_TOL**2
        U = (Zp @ V[:, keep]) / np.sqrt(lam[keep])
        if exact and U.shape[1]:                       # re-orthogonalise what is kept
            U, _ = np.linalg.qr(U - self.Q @ (self.Q.T @ U))
        return U

    def basis(self, Z: np.ndarray) -> np.ndarray:
        """Orthonormal basis (N, r) of ``Z`` projected off the model."""
        return self._basis(Z)

    def test(self, Z: np.ndarray, gram: np.ndarray | None = None) -> FTest:
        """F-test of adding ``Z`` (N, p) to the model.

        Only ``Qᵀ·Z``, ``Zᵀ·e`` and the Gram matrix ``Zᵀ·Z`` (pass it when several sensors
        share ``Z``) are formed: the projected regressors never are.
        """
        Z = np.asarray(Z, float).reshape(self.y.size, -1)
        Z, scale, _, W = projected_whitener(Z, self.Q, gram)
        r = W.shape[1]
        if r == 0:
            return FTest(0, 0.0, 0.0, 1.0, 0.0, np.zeros((self.y.size, 0)))
        c = W.T @ ((Z.T @ self.e) / scale)
        ss = float(c @ c)
        dof = self.y.size - self.k - r
        rss1 = max(self.rss - ss, 1e-300)
        F = (ss / r) / (rss1 / max(dof, 1))
        d2 = max(dof, 1)
        return FTest(r, ss, F, float(scipy.stats.f.sf(F, r, d2)),
                     _log_sf(F, r, d2), Z)

    def add(self, Z: np.ndarray) -> int:
        """Add the columns of ``Z`` to the model; returns the rank added."""
        U = self._basis(Z, exact=True)
        if U.shape[1]:
            self.Q = np.hstack([self.Q, U])
            self.e = self.e - U @ (U.T @ self.e)
            self._update()
        return U.shape[1]
