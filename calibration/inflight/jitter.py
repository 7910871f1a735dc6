"""Timing jitter of an IMU against the reference, from the in-flight fit's own residual.

Two IMUs are sampled at instants that differ by a constant offset (fitted,
:mod:`calibration.inflight.fit`) plus a random error δt per sample. A sampling-time error
δt makes IMU j's output err by ``a_t·δt`` with ``a_t = A·ω̇_ref(t)`` (the angular
acceleration seen by its axes), so its fit residual is modelled as::

    r_t ~ N(0, Σ + τ²·a_t·a_tᵀ)          (δt ~ N(0, τ²), the same δt on the three axes)

with Σ (3×3) the residual covariance at rest. Σ and τ² are fitted together by maximum
likelihood (``scipy.optimize.minimize``, Σ through its Cholesky factor); with the matrix
determinant lemma each sample costs O(1)::

    log|M_t| = log|Σ| + log(1 + τ²·c_t),   r_tᵀM_t⁻¹r_t = q_t − τ²·e_t²/(1 + τ²·c_t)

(c_t = a_tᵀΣ⁻¹a_t, e_t = a_tᵀΣ⁻¹r_t, q_t = r_tᵀΣ⁻¹r_t). The sd of τ² is the sandwich
(Huber–White) covariance with Newey–West weights over ``lags`` samples, so that a residual
that is heavier-tailed or coloured beyond the model does not make τ look better known than
it is; the sd of τ follows by the delta method, sd(τ) = sd(τ²)/(2τ), or ``sqrt(sd(τ²))``
where that is smaller (τ² within about one sd of 0, where the delta method fails).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize

__all__ = ["JitterFit", "fit_timing_jitter"]

_H = 1e-4
"""Relative step of the numerical derivatives (of the standardised parameters)."""


@dataclass(frozen=True, eq=False)
class JitterFit:
    """Timing jitter of one IMU (SI).

    Attributes
    ----------
    tau_s, tau_sd_s : float
        τ, the sd of the sampling-time error against the reference (s), and its sd.
    tau2_s2, tau2_sd_s2 : float
        τ² and its sd (s²).
    noise_cov : ndarray, shape (3, 3)
        Σ, the residual covariance without the jitter term (rad²/s²).
    samples : int
    """

    tau_s: float
    tau_sd_s: float
    tau2_s2: float
    tau2_sd_s2: float
    noise_cov: np.ndarray
    samples: int


def _unpack(theta: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, float]:
    """(L, τ²) from the standardised parameters: L lower triangular with log-diagonal."""
    x = theta * scale
    L = np.zeros((3, 3))
    L[0, 0], L[1, 1], L[2, 2] = np.exp(x[0]), np.exp(x[1]), np.exp(x[2])
    L[1, 0], L[2, 0], L[2, 1] = x[3], x[4], x[5]
    return L, float(x[6])


def _loglik(theta: np.ndarray, scale: np.ndarray, r: np.ndarray, a: np.ndarray
            ) -> np.ndarray:
    """Per-sample log-likelihood (N,) (without the constant)."""
    L, s = _unpack(theta, scale)
    ri = np.linalg.solve(L, r.T)                 # L⁻¹r: Σ⁻¹ = L⁻ᵀL⁻¹
    ai = np.linalg.solve(L, a.T)
    q = np.sum(ri * ri, axis=0)
    c = np.sum(ai * ai, axis=0)
    e = np.sum(ai * ri, axis=0)
    g = 1.0 + s * c
    with np.errstate(invalid="ignore", divide="ignore"):
        ll = -0.5 * (2.0 * np.sum(np.log(np.diag(L))) + np.log(g) + q - s * e * e / g)
    return np.where(g > 0, ll, -np.inf)


def fit_timing_jitter(residual: np.ndarray, accel: np.ndarray, *, lags: int = 0
                      ) -> JitterFit:
    """Fit τ (module docstring).

    Parameters
    ----------
    residual : ndarray, shape (N, 3)
        The fit residual of one IMU (rad/s); non-finite rows are left out.
    accel : ndarray, shape (N, 3)
        ``A·ω̇_ref`` on the same samples (rad/s²).
    lags : int
        Newey–West lag of the sd (the regression's own).

    Returns
    -------
    JitterFit
        NaN estimates with fewer than 50 usable samples.
    """
    r = np.asarray(residual, float)
    a = np.asarray(accel, float)
    ok = np.all(np.isfinite(r), axis=1) & np.all(np.isfinite(a), axis=1)
    r, a = r[ok], a[ok]
    N = r.shape[0]
    if N < 50:
        nan = float("nan")
        return JitterFit(nan, nan, nan, nan, np.full((3, 3), nan), N)
    S0 = np.cov(r.T)
    L0 = np.linalg.cholesky(S0 + 1e-12 * np.trace(S0) * np.eye(3))
    # τ² scale: the residual variance over the angular-acceleration variance
    s_scale = float(np.trace(S0) / max(float(np.mean(np.sum(a * a, axis=1))), 1e-300))
    lsd = float(np.sqrt(np.trace(S0) / 3.0))
    scale = np.array([1.0, 1.0, 1.0, lsd, lsd, lsd, s_scale])
    x0 = np.array([math.log(L0[0, 0]), math.log(L0[1, 1]), math.log(L0[2, 2]),
                   L0[1, 0] / lsd, L0[2, 0] / lsd, L0[2, 1] / lsd, 0.0])

    def nll(th: np.ndarray) -> float:
        v = float(np.sum(_loglik(th, scale, r, a)))
        return -v / N if math.isfinite(v) else 1e300

    best = None
    for s_init in (0.0, 0.01, 0.3):               # the likelihood can have a shoulder
        x = x0.copy()
        x[6] = s_init
        res = optimize.minimize(nll, x, method="L-BFGS-B",
                                bounds=[(None, None)] * 6 + [(0.0, None)])
        if best is None or res.fun < best.fun:
            best = res
    th = best.x
    L, s = _unpack(th, scale)
    cov = _sandwich(th, scale, r, a, lags)
    s_sd = float(math.sqrt(max(cov[6, 6], 0.0))) * scale[6]
    tau = math.sqrt(max(s, 0.0))
    # delta method; near τ² = 0 it diverges and sqrt(sd(τ²)) is the scale of τ instead
    tau_sd = min(s_sd / (2.0 * tau), math.sqrt(s_sd)) if tau > 0 else math.sqrt(s_sd)
    return JitterFit(tau_s=tau, tau_sd_s=float(tau_sd), tau2_s2=float(s), tau2_sd_s2=s_sd,
                     noise_cov=L @ L.T, samples=N)


def _scores(th: np.ndarray, scale: np.ndarray, r: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Per-sample scores (N, 7) by central differences (τ² at its bound 0: one-sided)."""
    G = np.empty((r.shape[0], th.size))
    for k in range(th.size):
        h = _H * max(1.0, abs(th[k]))
        up = th.copy()
        up[k] += h
        dn = th.copy()
        if k == 6 and th[k] - h < 0:
            G[:, k] = (_loglik(up, scale, r, a) - _loglik(th, scale, r, a)) / h
            continue
        dn[k] -= h
        G[:, k] = (_loglik(up, scale, r, a) - _loglik(dn, scale, r, a)) / (2 * h)
    return G


def _sandwich(th: np.ndarray, scale: np.ndarray, r: np.ndarray, a: np.ndarray,
              lags: int) -> np.ndarray:
    """H⁻¹·J·H⁻¹ of the standardised parameters (J with Newey–West weights)."""
    G = _scores(th, scale, r, a)
    p = th.size
    Hm = np.empty((p, p))
    for k in range(p):
        h = _H * max(1.0, abs(th[k]))
        up = th.copy()
        up[k] += h
        if k == 6 and th[k] - h < 0:
            Hm[:, k] = (_scores(up, scale, r, a).sum(axis=0) - G.sum(axis=0)) / h
            continue
        dn = th.copy()
        dn[k] -= h
        Hm[:, k] = (_scores(up, scale, r, a).sum(axis=0)
                    - _scores(dn, scale, r, a).sum(axis=0)) / (2 * h)
    Hm = 0.5 * (Hm + Hm.T)
    Gc = G - G.mean(axis=0)
    J = Gc.T @ Gc
    for k in range(1, int(max(lags, 0)) + 1):
        w = 1.0 - k / (lags + 1.0)
        C = Gc[k:].T @ Gc[:-k]
        J += w * (C + C.T)
    try:
        Hi = np.linalg.inv(-Hm)
    except np.linalg.LinAlgError:
        return np.full((p, p), np.nan)
    return Hi @ J @ Hi
