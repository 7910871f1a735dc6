"""Parity space of a redundant sensor set.

For measurement matrix ``H`` (n, 3) the parity matrix ``V`` (n-3, n) spans the left null
space of H: ``V·H = 0`` and ``V·Vᵀ = I`` (seed 000 Eqs. 6-11: V = U₂ᵀ of the SVD). The
parity vector ``p = V·y`` holds no trace of the body rate, only of errors and faults.

The null space fixes V only up to an orthogonal transformation; rimu makes it unique: the
rows are Gram-Schmidt orthonormalised projections of the unit vectors e_j onto the null
space, taking at each step the e_j with the largest remaining projection (ties to the
highest j), each row with its largest entry positive. For
the tetrad this gives seed 000 Eq. 24 exactly.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "calibrated_axes",
    "isolability",
    "parity_matrix",
    "reconstruction_matrix",
]


def parity_matrix(H: np.ndarray, healthy: np.ndarray | None = None) -> np.ndarray:
    """Deterministic parity matrix of ``H``.

    Parameters
    ----------
    H : ndarray, shape (n, 3)
        Measurement matrix (rows: input axes, MB frame).
    healthy : ndarray of bool, shape (n,), optional
        Sensors in use. Rows of excluded sensors are zeroed in H (seed 001 Eq. 21) and their
        columns of V are zero.

    Returns
    -------
    V : ndarray, shape (m - 3, n)
        m the number of healthy sensors; ``V·H = 0``, ``V·Vᵀ = I``. Shape (0, n) when no
        redundancy is left.
    """
    H = np.asarray(H, dtype=float)
    n = H.shape[0]
    use = np.ones(n, bool) if healthy is None else np.asarray(healthy, bool)
    Hu = H[use]
    m = Hu.shape[0]
    rank = np.linalg.matrix_rank(Hu) if m else 0
    k = m - rank
    V = np.zeros((max(k, 0), n))
    if k <= 0:
        return V
    # Orthogonal projector onto the null space of Huᵀ (seed 000 Eq. 11: U₂U₂ᵀ).
    U, _, _ = np.linalg.svd(Hu, full_matrices=True)
    U2 = U[:, rank:]
    P = U2 @ U2.T
    rows: list[np.ndarray] = []
    R = P.copy()                     # residuals of the projected unit vectors, as columns
    for _ in range(k):
        norms = np.linalg.norm(R, axis=0)
        # the best-conditioned candidate; ties (within 1e-9) go to the highest index
        j = int(np.flatnonzero(norms >= norms.max() - 1e-9)[-1])
        r = R[:, j] / norms[j]
        r = P @ r                    # re-project: keeps V·H = 0 to rounding
        for q in rows:
            r -= (q @ r) * q
        r /= np.linalg.norm(r)
        if r[np.argmax(np.abs(r))] < 0:
            r = -r
        rows.append(r)
        R -= np.outer(r, r @ R)
    V[:, use] = np.array(rows)
    return V


def reconstruction_matrix(H: np.ndarray, healthy: np.ndarray | None = None,
                          weights: np.ndarray | None = None) -> np.ndarray:
    """Weighted least-squares body-rate estimator ``ω̂ = G·y``.

    ``G = (Hᵀ W H)⁻¹ Hᵀ W`` with the rows of failed sensors zeroed (seed 000 Eq. 4,
    seed 001 Eqs. 20-21).

    Parameters
    ----------
    H : ndarray, shape (n, 3)
    healthy : ndarray of bool, shape (n,), optional
    weights : ndarray, shape (n, n), optional
        Inverse noise covariance W = Σ⁻¹; identity when omitted.

    Returns
    -------
    G : ndarray, shape (3, n)
        Columns of unhealthy sensors are zero. All zeros if fewer than 3 independent
        sensors remain.
    """
    H = np.asarray(H, dtype=float)
    n = H.shape[0]
    use = np.ones(n, bool) if healthy is None else np.asarray(healthy, bool)
    G = np.zeros((3, n))
    Hu = H[use]
    if Hu.shape[0] < 3 or np.linalg.matrix_rank(Hu) < 3:
        return G
    W = np.eye(n) if weights is None else np.asarray(weights, float)
    Wu = W[np.ix_(use, use)]
    A = Hu.T @ Wu @ Hu
    G[:, use] = np.linalg.solve(A, Hu.T @ Wu)
    return G


def calibrated_axes(H: np.ndarray, groups: tuple[tuple[int, ...], ...],
                    misalignments: list[np.ndarray]) -> np.ndarray:
    """Calibrated measurement matrix H̃ = blockdiag(M₁, M₂, ...)·H (seed 000 Eq. 14).

    Parameters
    ----------
    H : ndarray, shape (n, 3)
        Nominal axes.
    groups : tuple of tuple of int
        Sensors of each subsystem (0-based).
    misalignments : list of ndarray
        One ``M_j`` per group. A square M (k, k) acts on the group's rows of H; a
        ``(k, 3)`` matrix *is* the group's calibrated rows (seed 000's M₂ for gyro 4, whose
        H₂ = I₃).

    Returns
    -------
    ndarray, shape (n, 3)
    """
    H = np.asarray(H, dtype=float)
    Ht = H.copy()
    for g, M in zip(groups, misalignments, strict=True):
        M = np.atleast_2d(np.asarray(M, float))
        idx = list(g)
        if M.shape == (len(idx), len(idx)) and len(idx) == 3:
            Ht[idx] = M @ H[idx]
        elif M.shape == (len(idx), 3):
            Ht[idx] = M
        else:
            raise ValueError(f"misalignment of shape {M.shape} for a group of {len(idx)}")
    return Ht


def isolability(V: np.ndarray, noise_cov: np.ndarray | None = None,
                tol: float = 1e-6) -> dict[str, object]:
    """What the parity space can tell about each sensor and each pair.

    Two sensors can be told apart when their (whitened) parity columns are not collinear;
    a sensor is detectable when its column is non-zero.

    Returns
    -------
    dict
        ``"detectable"``: list of bool per sensor; ``"pair_cos"``: (n, n) |cos| between
        columns; ``"isolable_pairs"``: list of bool per sensor pair (i < j) in row order;
        ``"can_isolate"``: True when every pair of detectable sensors is isolable.
    """
    V = np.asarray(V, dtype=float)
    n = V.shape[1]
    if V.shape[0] == 0:
        return {"detectable": [False] * n, "pair_cos": np.zeros((n, n)),
                "isolable_pairs": [False] * (n * (n - 1) // 2), "can_isolate": False}
    if noise_cov is not None:
        C = V @ np.asarray(noise_cov, float) @ V.T
        L = np.linalg.cholesky(np.linalg.inv(C))
        Vw = L.T @ V
    else:
        Vw = V
    norms = np.linalg.norm(Vw, axis=0)
    det = norms > tol
    safe = np.where(det, norms, 1.0)
    c = np.abs((Vw / safe).T @ (Vw / safe))
    pairs = [bool(det[i] and det[j] and c[i, j] < 1 - 1e-9)
             for i in range(n) for j in range(i + 1, n)]
    can = all(pairs[k] for k, (i, j) in enumerate(
        (i, j) for i in range(n) for j in range(i + 1, n)) if det[i] and det[j])
    return {"detectable": det.tolist(), "pair_cos": c, "isolable_pairs": pairs,
            "can_isolate": bool(can and det.sum() >= 2)}
