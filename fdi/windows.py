"""Dyadic windows over the whitened parity: one compiled update per complete sample.

The cumulative sums c_t = Σ_{s≤t} (z_s, ρ_s) since the healthy set began are kept in a
ring of the last R = 2^K + 1 of them; the sum over the last w samples is c_t − c_{t−w}
(O(1) per scale, seed 000's multi-resolution means as differences). Per scale::

    D_w = |Σ_w z|² / (w·f_w)                         (χ²(df) for healthy white noise)
    T_w = thr_w · (1 + w·β/f_w + κ/f_w · Σ_w ρ) · s  (calibration error does not average;
                                                       s: the in-flight noise scale)

an alarm is D_w > T_w; the detection clears only while every D_w is below its clearing
level C_w·g_w, with C_w = ``clear_ratio·thr_w`` (and the floor of
:func:`fdi.detector.clear_thresholds`) and g_w = T_w/thr_w the same inflation as the
threshold's: the calibration error that raises the healthy statistic in a manoeuvre raises
the level it must fall back below by as much (a fixed level under an inflated threshold
kept detections open through whole flights: healthy statistics far below T_w, never below
C_w).
``D`` is NaN and ``T`` the base threshold while fewer than w samples are in the windows.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fdi.state import (
    CHI2_SCALE,
    CLEAR_THRESHOLD,
    OFFSET_GAIN,
    RHO_GAIN,
    RING_POS,
    STATS0,
    THRESHOLD,
    WINDOW,
    WINDOW_COUNT,
)

__all__ = ["window_update"]


@njit(error_model="numpy", inline="always", _nrt=False)
def window_update(z: np.ndarray, rho: float, df: int, windows: np.ndarray,
                  counters: np.ndarray, scales: np.ndarray, K: int, out: np.ndarray,
                  r: int, ns: float = 1.0) -> tuple[bool, bool, int, float]:
    """Add one complete sample and test every window scale.

    Parameters
    ----------
    z : ndarray, shape (≥ df,)
        Whitened parity of the sample.
    rho : float
        Calibration-uncertainty ratio ρ of the sample.
    df : int
    windows : ndarray, shape (R + 1, df + 1)
        Ring of cumulative sums (row R: current), updated in place.
    counters : ndarray of int64
        Ring position and window count, updated in place.
    scales : ndarray, shape (K_w, 6)
        Per-scale constants (:mod:`fdi.state`).
    K : int
        Statistics per sample (K_w, plus one for the CUSUM bank).
    out : ndarray, shape (N, width)
        Output rows: statistics at STATS0 + k, thresholds at STATS0 + K + k.
    r : int
        Row of this sample.
    ns : float
        The in-flight noise scale s ≥ 1 (:func:`fdi.kernel.noise_scale`): thresholds and
        clearing levels are taken s times (1: the calibrated noise).

    Returns
    -------
    alarm, clear : bool
    fired : int
        Scale with the largest D/T among those over threshold (−1: none).
    best : float
        Its D/T.
    """
    R = windows.shape[0] - 1
    for j in range(df):
        windows[R, j] = windows[R, j] + z[j]
    windows[R, df] = windows[R, df] + rho
    count = counters[WINDOW_COUNT] + 1
    counters[WINDOW_COUNT] = count
    pos = counters[RING_POS] + 1
    if pos == R:
        pos = 0
    counters[RING_POS] = pos
    for j in range(df + 1):
        windows[pos, j] = windows[R, j]
    alarm = False
    clear = True
    fired = -1
    best = 0.0
    for k in range(scales.shape[0]):
        w = int(scales[k, WINDOW])
        if count >= w:
            o = pos - w + (R if pos < w else 0)     # a select, not a branch: pos < w
            d = windows[R, 0] - windows[o, 0]
            acc = d * d
            for j in range(1, df):
                d = windows[R, j] - windows[o, j]
                acc = acc + d * d
            D = acc * scales[k, CHI2_SCALE]
            g = scales[k, OFFSET_GAIN] + scales[k, RHO_GAIN] * (windows[R, df] - windows[o, df])
            g = g * ns
            T = scales[k, THRESHOLD] * g
            if D > T:
                alarm = True
                if D / T > best:
                    best = D / T
                    fired = k
            if D >= scales[k, CLEAR_THRESHOLD] * g:
                clear = False
        else:
            D = np.nan
            T = scales[k, THRESHOLD]
        out[r, STATS0 + k] = D
        out[r, STATS0 + K + k] = T
    return alarm, clear, fired, best
