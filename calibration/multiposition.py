"""Accelerometer multi-position test by least squares (seed 001 Eqs. 5-10).

At each stationary position k the mean raw output of accelerometer i obeys
``ū_k = a·f̄_k + c`` with ``a = h̃/SF`` (raw per m/s²), ``c = b/SF`` and ``f̄_k`` the specific
force in the MB frame from the turntable attitude (seed 001 Eq. 6). Stacking the positions,
``S = [f̄, 1]`` (seed 001 Eq. 8) and ``[a; c] = (SᵀWS)⁻¹SᵀW·ū`` (seed 001 Eq. 7, weighted by
the samples per position; the unweighted formula when all positions are equally long).
``SF = 1/|a|``, ``h̃ = a/|a|`` (seed 001 Eq. 10) and ``b = c·SF``.

The estimate is linear in the position means, ``θ = op @ ū``, so with white per-sample noise
``cov θ = σ²·op·diag(1/N)·opᵀ`` = ``σ²(SᵀWS)⁻¹`` (seed 001 Eq. 19a).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fdi.errors import CalibrationError

__all__ = ["MultiPosition", "multiposition"]


@dataclass(frozen=True)
class MultiPosition:
    """Least-squares multi-position fit.

    Attributes
    ----------
    S : ndarray, shape (K, 4)
        ``[f̄, 1]`` per position (m/s², 1), seed 001 Eq. 8.
    op : ndarray, shape (4, K)
        ``[a; c] = op @ ū`` for one sensor's position means ``ū`` (K,).
    a : ndarray, shape (n, 3)
        ``h̃/SF`` per sensor (raw per m/s²).
    c : ndarray, shape (n,)
        ``b/SF`` (raw).
    """

    S: np.ndarray
    op: np.ndarray
    a: np.ndarray
    c: np.ndarray


def multiposition(step_mean_u: np.ndarray, step_counts: np.ndarray, step_mean_f: np.ndarray, *,
                  step_numbers: Sequence[int] | None = None,
                  source: str = "<memory>") -> MultiPosition:
    """Gains and offsets of accelerometers from stationary positions (seed 001 Eq. 7).

    Parameters
    ----------
    step_mean_u : ndarray, shape (K, n)
        Mean raw output per position.
    step_counts : ndarray, shape (K,)
    step_mean_f : ndarray, shape (K, 3)
        Mean specific force per position (m/s², MB frame).

    Raises
    ------
    CalibrationError
        Fewer than 4 positions, or positions that do not span three axes plus the offset
        (rank of S < 4).
    """
    U = np.asarray(step_mean_u, float)
    N = np.asarray(step_counts, float)
    F = np.asarray(step_mean_f, float)
    K = U.shape[0]
    nums = list(step_numbers) if step_numbers is not None else list(range(1, K + 1))
    S = np.column_stack([F, np.ones(K)])                             # seed 001 Eq. 8
    g = float(np.median(np.linalg.norm(F, axis=1))) if K else 1.0
    sv = np.linalg.svd(S * np.array([1, 1, 1, g if g > 0 else 1.0]), compute_uv=False)
    rank = int(np.sum(sv > 1e-2 * sv[0])) if K and sv[0] > 0 else 0
    if rank < 4:
        steps = ", ".join(str(k) for k in nums) or "none"
        raise CalibrationError(
            f"{source}: position steps {steps}: gravity spans only {max(rank - 1, 0)} "
            f"independent axis/axes (rank of S is {rank}); expected at least 4 positions "
            "with gravity along 3 independent body axes")
    Sw = S * N[:, None]
    op = np.linalg.solve(S.T @ Sw, Sw.T)                             # seed 001 Eq. 7
    theta = op @ U                                                   # (4, n)
    return MultiPosition(S=S, op=op, a=theta[:3].T, c=theta[3].copy())
