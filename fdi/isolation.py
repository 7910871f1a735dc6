"""Generalised likelihood test for isolation and the fault-magnitude estimate.

In whitened parity coordinates (z = A·V·y, Cov z = I) a bias f on sensor i shifts z by
f·u_i, u_i the whitened parity column. Given a window sum ``s`` of w samples of z, the GLT
statistic of sensor i and the least-squares fault size are::

    L_i = (u_iᵀ s)² / (w · |u_i|²)            (= (v_iᵀ W p̄)²/(v_iᵀ W v_i) · w)
    f̂_i = u_iᵀ s / (w · |u_i|²)               (SI input units)

the sensor with the largest L_i best explains the parity vector.
"""

from __future__ import annotations

import numpy as np

__all__ = ["glt_scores", "isolate", "magnitude"]


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
