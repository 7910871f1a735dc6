"""Thresholds that hold for any bias within a nominal bound (ARAIM's b_nom).

ARAIM carries, beside each satellite's σ, a nominal bias bound b_nom: the part of the error
known not to stay calibrated, and its thresholds and protection levels hold for *any* bias
within the bound, not on average over biases (Blanch et al., ION GNSS 2012; WG-C ARAIM
ADD v3.0). Here the bound covers the turn-on bias of a power-up the monitor could not
estimate (:mod:`replay.turn_on`): a bias error e with ``|e_i| ≤ B_i`` per sensor moves the
whitened parity by ``g = U·e`` (U = L⁻¹V, the whitened parity columns), so over a full
window of w samples the statistic of healthy noise is

    D_w ~ χ'²(df, λ_w),   λ_w = w·|g|²/f_w          (f_w the scale's variance factor)

and the threshold that holds for every such bias at the scale's per-sample probability α_w
is ``T'_w = ncx2.isf(α_w, df, λ_w*)`` with ``λ_w* = w·max_{|e_i|≤B_i} |U e|²/f_w``. The
maximum of the convex ``|U e|²`` over the box is at a vertex: enumerated exactly up to
:data:`EXACT_VERTICES_MAX_N` sensors, bounded by ``(Σ_i B_i·|u_i|)²`` beyond. The maximum is
taken over the full set and every set left after one exclusion (the thresholds serve them
all). The monitor recomputes each set's threshold from α, so the bound is carried as the
α_w' with ``χ²_df isf(α_w') = T'_w`` (:func:`bounded_thresholds`); where that would
underflow the variance factor carries the rest.

The protection level grows with the larger single-sample threshold (its MDB term); the
bias's own shift of ω̂, at most ``Σ_i B_i·|G e_i|``, is stated by :func:`rate_shift_bound`
beside it (the kernel's protection level has no additive term yet).
"""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
from scipy import linalg, stats

from fdi.calfile import Calibration
from fdi.detector import chi2_threshold
from fdi.parity import parity_matrix
from fdi.settings import Thresholds

__all__ = ["EXACT_VERTICES_MAX_N", "bounded_thresholds", "max_parity_offset", "rate_shift_bound"]

EXACT_VERTICES_MAX_N = 14
"""Sets of up to this many sensors get the exact vertex maximum (2^n vertices)."""
_ALPHA_FLOOR = 1e-280


def _whitened(cal: Calibration, kind: str, healthy: np.ndarray) -> np.ndarray:
    """Whitened parity columns U (df, n) of the healthy set (zero columns outside)."""
    s = cal.kind(kind)
    V = parity_matrix(s.H, healthy)
    S = np.asarray(s.noise_covariance, float)
    if V.shape[0] == 0:
        return np.zeros((0, s.n))
    L = np.linalg.cholesky(V @ S @ V.T)
    return linalg.solve_triangular(L, V, lower=True)


def _box_max(U: np.ndarray, B: np.ndarray) -> float:
    """max |U e|² over |e_i| ≤ B_i."""
    keep = B > 0
    Uk, Bk = U[:, keep] * B[keep], B[keep]
    m = Bk.size
    if m == 0 or U.shape[0] == 0:
        return 0.0
    if m > EXACT_VERTICES_MAX_N:
        return float(np.sum(np.linalg.norm(Uk, axis=0)) ** 2)
    signs = np.array(list(itertools.product((-1.0, 1.0), repeat=m - 1)))
    signs = np.hstack([np.ones((signs.shape[0], 1)), signs])      # ±e give the same |Ue|
    g = signs @ Uk.T
    return float(np.max(np.sum(g * g, axis=1)))


def max_parity_offset(cal: Calibration, bound: np.ndarray, kind: str = "gyro") -> float:
    """``max |U e|²`` over the box ``|e_i| ≤ bound_i`` (SI), over the full set and every set
    left after one exclusion (whitened units, per sample)."""
    s = cal.kind(kind)
    B = np.asarray(bound, float)
    best = 0.0
    masks = [np.ones(s.n, bool)]
    for i in range(s.n):
        m = np.ones(s.n, bool)
        m[i] = False
        masks.append(m)
    for m in masks:
        if int(m.sum()) < 4 or np.linalg.matrix_rank(s.H[m]) < 3:
            continue
        best = max(best, _box_max(_whitened(cal, kind, m), np.where(m, B, 0.0)))
    return best


def rate_shift_bound(cal: Calibration, bound: np.ndarray, kind: str = "gyro") -> float:
    """Largest shift of the reconstructed rate (SI, 2-norm bound) a bias within the box
    gives on the full set: ``Σ_i B_i·|G e_i|`` with G the weighted least-squares
    reconstruction."""
    s = cal.kind(kind)
    H = s.H
    W = np.linalg.inv(np.asarray(s.noise_covariance, float))
    G = np.linalg.solve(H.T @ W @ H, H.T @ W)
    return float(np.sum(np.asarray(bound, float) * np.linalg.norm(G, axis=0)))


def bounded_thresholds(thr: Thresholds, cal: Calibration, bound: np.ndarray,
                       kind: str = "gyro", source: str = "") -> Thresholds:
    """``thr`` raised to hold for any bias within ``|e_i| ≤ bound_i`` (module docstring).

    Parameters
    ----------
    thr : Thresholds
    cal : Calibration
    bound : ndarray, shape (n,)
        Nominal bias bound per sensor (SI).
    kind : str
    source : str
        Where the bound comes from, for the notes.
    """
    B = np.asarray(bound, float)
    if not np.any(B > 0):
        return thr
    df = thr.n - 3
    if df < 1:
        return thr
    g2 = max_parity_offset(cal, B, kind)
    alpha, vf, T = [], [], []
    t_cap = chi2_threshold(_ALPHA_FLOOR, df)
    for w, a, f in zip(thr.scales, thr.alpha, thr.variance_factor, strict=True):
        lam = w * g2 / f
        Tn = float(stats.ncx2.isf(a, df, lam)) if lam > 0 else chi2_threshold(a, df)
        if Tn <= t_cap:
            an = float(stats.chi2.sf(Tn, df))
            alpha.append(min(an, a))
            vf.append(f)
        else:                                   # beyond what α can carry: the factor does
            alpha.append(_ALPHA_FLOOR)
            vf.append(f * Tn / t_cap)
        T.append(chi2_threshold(alpha[-1], df))
    note = (f"; raised for a nominal bias bound up to {float(B.max()):.3g} SI per sensor "
            f"({source or 'given'}): max whitened parity offset {g2:.3g} per sample, "
            f"fdi.bias_bound")
    return replace(thr, alpha=tuple(alpha), variance_factor=tuple(vf), threshold=tuple(T),
                   notes=thr.notes + note)
