"""The CUSUM bank on the unit whitened projections, one compiled update per sample.

For each healthy sensor i, r_i = u_iᵀz/|u_i| is N(0, 1) when healthy and shifts by
f·|u_i| under a bias f on sensor i. Two one-sided CUSUMs per sensor with allowance
ν + 3·sqrt(κρ + β) (the calibration's own error at this rate is not a fault)::

    S⁺_t = S⁺_{t−1} + (r_i − allowance),   g⁺ = S⁺_t − min_{s≤t} S⁺_s   (S⁺_0 = 0)
    S⁻_t = S⁻_{t−1} + (−r_i − allowance),  g⁻ = S⁻_t − min_{s≤t} S⁻_s

which is Page's recursion g_t = max(0, g_{t−1} + x_t) written with the running minimum.
The bank's statistic is max(0, max_i max(g⁺_i, g⁻_i)) against the threshold h.
"""

from __future__ import annotations

import math

from numba import njit

from fdi.state import BETA, IN_SET, KAPPA, MIN_DOWN, MIN_UP, NU, S_DOWN, S_UP

__all__ = ["cusum_update"]


@njit(error_model="numpy", inline="always", _nrt=False)
def cusum_update(z, rho: float, df: int, sensors, mats,
                 fconst, cusum) -> float:
    """Advance every sensor's two CUSUMs by one sample; returns the bank's statistic.

    Parameters
    ----------
    z : ndarray, shape (≥ df,)
    rho : float
    df : int
    sensors : ndarray, shape (SENSOR_COLS, n)
    mats : ndarray, shape (3·df + 3, n)
        Rows 2·df + 3 … hold the unit whitened parity columns.
    fconst : ndarray
    cusum : ndarray, shape (4, n)
        S⁺, min S⁺, S⁻, min S⁻ per sensor, updated in place.
    """
    u0 = 2 * df + 3
    allowance = fconst[NU] + 3.0 * math.sqrt(fconst[KAPPA] * rho + fconst[BETA])
    g = 0.0
    for i in range(sensors.shape[1]):
        if sensors[IN_SET, i] == 0.0:
            continue
        r = 0.0
        for j in range(df):
            r = r + mats[u0 + j, i] * z[j]
        a = cusum[S_UP, i] + (r - allowance)
        cusum[S_UP, i] = a
        if a < cusum[MIN_UP, i]:
            cusum[MIN_UP, i] = a
        g_up = a - cusum[MIN_UP, i]
        b = cusum[S_DOWN, i] + (-r - allowance)
        cusum[S_DOWN, i] = b
        if b < cusum[MIN_DOWN, i]:
            cusum[MIN_DOWN, i] = b
        g_down = b - cusum[MIN_DOWN, i]
        if g_up > g:
            g = g_up
        if g_down > g:
            g = g_down
    return g
