"""Generalised likelihood test for isolation and the fault-magnitude estimate.

In whitened parity coordinates (z = A·V·y, Cov z = I) a bias f on sensor i shifts z by
f·u_i, u_i the whitened parity column. Given a window sum ``s`` of w samples of z, the GLT
statistic of sensor i and the least-squares fault size are::

    L_i = (u_iᵀ s)² / (w · |u_i|²)            (= (v_iᵀ W p̄)²/(v_iᵀ W v_i) · w)
    f̂_i = u_iᵀ s / (w · |u_i|²)               (SI input units)

the sensor with the largest L_i best explains the parity vector. Whether that is enough to
exclude it is decided statistically by :func:`decide` (below).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

__all__ = ["IsolationDecision", "decide", "glt_scores", "isolate", "magnitude", "pair_sines",
           "rejection_level"]


def glt_scores(U: np.ndarray, s: np.ndarray, w: int) -> np.ndarray:
    """GLT statistic per healthy sensor, shape (m,).

    Parameters
    ----------
    U : ndarray, shape (df, m)
        Whitened parity columns.
    s : ndarray, shape (df,)
        Window sum of whitened parity over ``w`` samples.
    w : int
    """
    u2 = np.einsum("ij,ij->j", U, U)
    proj = U.T @ np.asarray(s, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(u2 > 0, proj**2 / (w * u2), 0.0)


def magnitude(U: np.ndarray, s: np.ndarray, w: int, k: int) -> float:
    """Least-squares size (SI) of a bias on healthy sensor ``k`` (column of U)."""
    u = U[:, k]
    u2 = float(u @ u)
    return float(u @ np.asarray(s, float)) / (w * u2) if u2 > 0 else float("nan")


def isolate(U: np.ndarray, s: np.ndarray, w: int) -> tuple[int, float]:
    """Best sensor (column index into U) and its GLT statistic."""
    sc = glt_scores(U, s, w)
    k = int(np.argmax(sc))
    return k, float(sc[k])


# -- statistical isolation (verified exclusion) --------------------------------------------
# In whitened parity coordinates a window sum s of w samples has, for healthy sensors,
# Cov s = w·f_w·g·I (f_w: the scale's variance factor, an overbound of the measured
# residual where the calibration holds one; g: the threshold inflation of the sample for the
# calibration and bias uncertainty, T/T_base). With ŝ = s/sqrt(w·f_w·g) and e_j = u_j/|u_j|,
# the hypothesis "a fault of any size on sensor j" leaves the residual
#
#     r_j = |ŝ|² − (e_jᵀŝ)²          ~ χ²(df − 1) under H_j, whatever the fault's size,
#
# (the parity left after removing sensor j; ARAIM's subset test). A fault on sensor i makes
# r_j non-central with λ = w·b²·|u_i|²·sin²θ_ij/f_w, θ_ij the angle between the whitened
# columns of i and j: two sensors whose columns are nearly parallel cannot be told apart.
#
# Decision (risk P_we of excluding a healthy sensor, per decision): exclude the best
# hypothesis i only when every other hypothesis j is rejected, r_j > c with
# c = χ²_{df−1} isf(P_we/(m − 1)) (Bonferroni over the m − 1 alternatives: under H_j the
# probability that r_j exceeds c is P_we/(m − 1)), and the exclusion is verified: the
# subset left after removing i passes its own test, r_i ≤ T_w(df − 1)·g (Blanch et al.,
# ARAIM baseline user algorithm: exclusion only with a passing subset test).


@dataclass(frozen=True)
class IsolationDecision:
    """Outcome of one isolation test on a window sum.

    Attributes
    ----------
    best : int
        Column (index into U) of the hypothesis with the smallest residual (the GLT sensor).
    residuals : ndarray, shape (m,)
        r_j per hypothesis (normalised: χ²(df − 1) under H_j).
    rejection_level : float
        c: residual above which a hypothesis is rejected.
    subset_threshold : float
        Level the residual of the excluded hypothesis must stay below (subset test).
    consistent : tuple of int
        Columns of the hypotheses not rejected (the sensors that cannot be told apart; the
        best one first when it is among them).
    exclude : int or None
        Column to exclude: only when ``consistent == (best,)`` and the subset test passes.
    """

    best: int
    residuals: np.ndarray
    rejection_level: float
    subset_threshold: float
    consistent: tuple[int, ...]
    exclude: int | None


def rejection_level(df: int, m: int, wrong_exclusion: float) -> float:
    """c = χ²_{df−1} isf(P_we/(m − 1)): the residual above which a hypothesis is rejected."""
    if df < 2 or m < 2:
        return float("inf")
    return float(stats.chi2.isf(wrong_exclusion / (m - 1), df - 1))


def decide(U: np.ndarray, s: np.ndarray, variance: float, wrong_exclusion: float,
           subset_threshold: float) -> IsolationDecision:
    """Test every single-sensor hypothesis on the window sum ``s``.

    Parameters
    ----------
    U : ndarray, shape (df, m)
        Whitened parity columns of the healthy sensors.
    s : ndarray, shape (df,)
        Window sum of the whitened parity.
    variance : float
        Variance of each component of ``s`` for healthy sensors (w·f_w·g).
    wrong_exclusion : float
        Probability that this decision excludes a healthy sensor when another is faulty.
    subset_threshold : float
        Level of the subset test on the normalised residual of the excluded hypothesis
        (the window's χ²(df − 1) threshold).
    """
    df, m = U.shape
    norms = np.linalg.norm(U, axis=0)
    ok = norms > 0
    E = np.where(ok, U / np.where(ok, norms, 1.0), 0.0)
    sn = np.asarray(s, float) / math.sqrt(variance) if variance > 0 else np.full(df, np.nan)
    proj = E.T @ sn
    res = np.where(ok, float(sn @ sn) - proj**2, np.inf)
    if not np.all(np.isfinite(sn)):
        res = np.full(m, np.nan)
    c = rejection_level(df, m, wrong_exclusion)
    best = int(np.nanargmin(res)) if np.isfinite(res).any() else 0
    keep = ~(res > c)                       # NaN residuals reject nothing
    order = [best] + [j for j in np.argsort(res) if j != best]
    consistent = tuple(int(j) for j in order if keep[j])
    exclude = None
    if consistent == (best,) and res[best] <= subset_threshold:
        exclude = best
    return IsolationDecision(best, res, c, float(subset_threshold), consistent, exclude)


def pair_sines(U: np.ndarray) -> np.ndarray:
    """sin θ_ij between the whitened parity columns of the healthy sensors, shape (m, m)
    (0 on the diagonal and for undetectable sensors)."""
    norms = np.linalg.norm(U, axis=0)
    ok = norms > 0
    E = np.where(ok, U / np.where(ok, norms, 1.0), 0.0)
    c = np.clip(np.abs(E.T @ E), 0.0, 1.0)
    s = np.sqrt(1.0 - c**2)
    s[~ok, :] = 0.0
    s[:, ~ok] = 0.0
    np.fill_diagonal(s, 0.0)
    return s
