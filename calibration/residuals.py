"""Per-segment means and what is left over after the calibration model.

A *segment* is a set of samples whose mean enters the estimators: a whole step, or part of
one (the whole-turn window of an outer-axis step, seed 000 Eq. 20). Means are computed in
one vectorised pass (``np.add.reduceat`` on contiguous runs).

Residuals are the compensated outputs minus the fitted model,
``e_i = SF_i·u_i − b_i − h̃_i·x`` (SI, per sample). From them: the per-sample noise
covariance (n×n), residual statistics per step and the overlapping Allan deviation
(``allantools.oadev``) that the monitor's multi-scale thresholds use.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import allantools
import numpy as np
import scipy.optimize

from fdi.calfile import AllanTable
from fdi.extras import ResidualStep

__all__ = [
    "GM_SIGMA_CAP_RECORDS",
    "GM_SIGMA_DELTA_NLL",
    "GaussMarkovFit",
    "allan_table",
    "fit_gauss_markov",
    "gauss_markov_segment_corr",
    "gauss_markov_sigma_candidates",
    "noise_covariance",
    "residual_step_stats",
    "segment_means",
]


def segment_means(seg: np.ndarray, n_seg: int,
                  *columns: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """Sample counts and means of several arrays over segments.

    Parameters
    ----------
    seg : ndarray of int, shape (N,)
        Segment id (0..n_seg-1) of each sample; negative ids are ignored.
    n_seg : int
    *columns : ndarray, shape (N,) or (N, m)

    Returns
    -------
    counts : ndarray of int, shape (n_seg,)
    means : list of ndarray, each (n_seg,) or (n_seg, m); NaN for empty segments.
    """
    seg = np.asarray(seg)
    use = seg >= 0
    order = None
    s = seg[use]
    if s.size > 1 and np.any(np.diff(s) < 0):
        order = np.argsort(s, kind="stable")
        s = s[order]
    counts = np.bincount(s, minlength=n_seg)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    nonempty = counts > 0
    means = []
    for col in columns:
        v = np.asarray(col, float)[use]
        if order is not None:
            v = v[order]
        out = np.full((n_seg, *v.shape[1:]), np.nan)
        if v.shape[0]:
            sums = np.add.reduceat(v, starts[nonempty], axis=0)
            out[nonempty] = sums / counts[nonempty].reshape((-1,) + (1,) * (v.ndim - 1))
        means.append(out)
    return counts, means


def noise_covariance(residuals: np.ndarray, dof_used: int = 0) -> np.ndarray:
    """Per-sample noise covariance (n, n) of residuals (N, n), SI².

    ``dof_used`` is the number of fitted parameters per sensor, removed from the divisor.
    """
    r = np.asarray(residuals, float)
    r = r - r.mean(axis=0)
    return (r.T @ r) / max(r.shape[0] - 1 - dof_used, 1)


def residual_step_stats(residuals: np.ndarray, step: np.ndarray,
                        step_numbers: Sequence[int], labels: Sequence[str] = (),
                        kinds: Sequence[str] = ()) -> tuple[ResidualStep, ...]:
    """Mean, RMS and sample count of the residuals of each step.

    Parameters
    ----------
    residuals : ndarray, shape (N, n)
        SI.
    step : ndarray of int, shape (N,)
        1-based step number per sample (0 or negative: not used).
    step_numbers : sequence of int
        Steps to report, in order.

    Returns
    -------
    tuple of ResidualStep
        One per step (:class:`fdi.extras.ResidualStep`: step, label, kind, n, mean and RMS
        per sensor).
    """
    nums = list(step_numbers)
    lookup = {k: j for j, k in enumerate(nums)}
    uniq, inv = np.unique(step, return_inverse=True)
    seg = np.array([lookup.get(int(k), -1) for k in uniq])
    ids = seg[inv]
    r = np.asarray(residuals, float)
    counts, (m, m2) = segment_means(ids, len(nums), r, r**2)
    return tuple(ResidualStep(step=int(k), label=labels[j] if j < len(labels) else "",
                              kind=kinds[j] if j < len(kinds) else "", n=int(counts[j]),
                              mean=tuple(m[j].tolist()), rms=tuple(np.sqrt(m2[j]).tolist()))
                 for j, k in enumerate(nums))


def allan_table(residuals: np.ndarray, rate_hz: float) -> AllanTable | None:
    """Overlapping Allan deviation of each residual column at octave-spaced τ.

    Uses ``allantools.oadev(x, rate=fs, data_type="freq", taus="octave")`` (rate data).
    Returns None when there are too few samples (< 16).
    """
    r = np.asarray(residuals, float)
    if r.shape[0] < 16:
        return None
    taus, cols = None, []
    for i in range(r.shape[1]):
        t, ad, _, _ = allantools.oadev(r[:, i], rate=rate_hz, data_type="freq", taus="octave")
        if taus is None:
            taus = np.asarray(t, float)
        cols.append(np.asarray(ad, float)[: len(taus)])
    k = min(len(c) for c in cols)
    return AllanTable(tau_s=taus[:k], adev=np.column_stack([c[:k] for c in cols]))


# -- coloured noise: white + first-order Gauss-Markov bias, fitted to the residual spectrum ------

GM_TAU_GRID = 40
"""Correlation times tried by :func:`fit_gauss_markov` (log-spaced, 1 s to 4 records)."""
GM_LR_THRESHOLD = 2.71
"""Likelihood-ratio statistic ``2·Δ(−log L)`` the Gauss-Markov term must gain over white
noise alone to be kept (the χ²₁ 10 % point). With ``τc`` profiled over the grid the
statistic is heavier-tailed than χ²₁: on 100 white tetrad-paper sessions it exceeded 2.71 in
10 (the same 10 as 3.84, the statistic is either ≈ 0 or large); those sessions get slightly
wider σ, the other 90 keep the white covariance exactly."""
GM_SIGMA_DELTA_NLL = 1.35
"""Half the χ²₁ 90 % point: ``{τc : −log L(τc) ≤ min −log L + 1.35}`` (σ_b² profiled) is
the two-sided 90 % profile-likelihood interval of τc, so its upper end is a one-sided 95 %
upper limit (Wilks). The σ of a coloured-noise calibration come from the largest bias
variance over that interval (:func:`gauss_markov_sigma_candidates`)."""
GM_SIGMA_CAP_RECORDS = 0.25
"""The interval of :data:`GM_SIGMA_DELTA_NLL` is cut at this fraction of the record length
(a quarter of the record). Beyond it the record does not tell the correlation time: the
profile likelihood is flat while σ_b² grows with τc, a slow enough Gauss-Markov path is a
bias of its own, and the bias variance at the grid's end is 5-6× too wide (tetrad-paper,
τc 100 s, seeds 0-99: error/σ sd 0.16 in the 27 sessions whose τ̂c runs to 4 records).
Chosen on tetrad-paper seeds 0-99 (τc 100 s ≈ T/6): T/6 and T/5 leave 2-7 biases of 400
beyond 3σ, T/4 none. A process slower than T/4 gets σ too small (τc 300 s: error/σ sd
≈ 1.7, as without the cut)."""
_GM_BINS = 48


def gauss_markov_segment_corr(start_s: np.ndarray, length_s: np.ndarray,
                              tau_c: float) -> np.ndarray:
    """Covariance of the means of a unit-variance Gauss-Markov process over intervals.

    Parameters
    ----------
    start_s, length_s : ndarray, shape (S,)
        Start time and duration (s) of each interval (a segment's samples); intervals do
        not overlap. Zero length: an empty segment (row and column 0).
    tau_c : float
        Correlation time (s).

    Returns
    -------
    ndarray, shape (S, S)
        ``K_jk = (1/(L_j·L_k))·∫∫ exp(−|t − s|/τc) ds dt`` (closed form).
    """
    a0 = np.asarray(start_s, float)
    L = np.asarray(length_s, float)
    S = a0.size
    K = np.zeros((S, S))
    ok = np.flatnonzero(L > 0)
    tc = float(tau_c)
    for j in ok:
        x = L[j] / tc
        K[j, j] = 2.0 * (x - 1.0 + np.exp(-x)) / x**2
        for k in ok[ok > j]:
            (p0, pl), (q0, ql) = sorted([(a0[j], L[j]), (a0[k], L[k])])
            p1, q1 = p0 + pl, q0 + ql
            v = tc**2 * (np.exp(-max(q0 - p1, 0.0) / tc) - np.exp(-(q1 - p1) / tc)
                         - np.exp(-(q0 - p0) / tc) + np.exp(-(q1 - p0) / tc)) / (pl * ql)
            K[j, k] = K[k, j] = v
    return K


@dataclass(frozen=True)
class GaussMarkovFit:
    """White noise plus a Gauss-Markov bias common to a set of sensors.

    Attributes
    ----------
    white_var : ndarray, shape (n,)
        Per-sample white-noise variance of each sensor (unit²).
    bias_var : float
        Variance of the Gauss-Markov bias (unit², the same for every sensor of the set);
        0 when the likelihood-ratio test keeps white noise.
    tau_c : float
        Its correlation time (s); inf when ``bias_var`` is 0.
    lr : float
        Likelihood-ratio statistic ``2·Δ(−log L)`` of the Gauss-Markov term over white noise.
    cov_log : ndarray, shape (2, 2), or None
        Covariance of ``(log σ_b², log τc)``: the inverse of the observed Fisher
        information (Hessian of the Whittle ``−log L`` at the fit, central differences,
        ``q_i`` held fixed). None when the term is not kept; ``inf`` entries when the
        Hessian is not positive definite (the likelihood does not bound the pair).
    profile_tau_s, profile_bias_var, profile_nll : ndarray, shape (GM_TAU_GRID,), or None
        The profile likelihood over the τc grid: each grid τc (s), the σ_b² that maximises
        the likelihood there (unit²) and the binned Whittle ``−log L`` at that pair. None
        when the term is not kept.
    record_s : float
        Length of the record (N/fs, s).
    """

    white_var: np.ndarray
    bias_var: float
    tau_c: float
    lr: float
    cov_log: np.ndarray | None = None
    profile_tau_s: np.ndarray | None = None
    profile_bias_var: np.ndarray | None = None
    profile_nll: np.ndarray | None = None
    record_s: float = 0.0


def fit_gauss_markov(x: np.ndarray, fs: float) -> GaussMarkovFit:
    """Whittle maximum-likelihood fit of white + Gauss-Markov noise to residuals.

    The periodogram of each column (mean removed, zero and Nyquist frequencies left out) is
    averaged in log-spaced frequency bins; the model spectrum per sensor is
    ``q_i + σ_b²·(1 − φ²)/|1 − φ·e^{−2πif/fs}|²`` (discrete first-order Gauss-Markov,
    ``φ = exp(−1/(fs·τc))``). ``q_i`` is the mean periodogram above ``fs/8`` (white there);
    ``σ_b²`` and ``τc`` are *common to the set* (identical sensors): one bias process
    amplitude seen by n sensors gives n times the spectral degrees of freedom, which a
    single sensor of a short session does not have (its record holds only a few correlation
    times). For each ``τc`` of a log grid ``σ_b²`` maximises the binned Whittle likelihood
    (bounded scalar search); the best ``τc`` wins, and the term is kept only when its
    likelihood-ratio statistic exceeds :data:`GM_LR_THRESHOLD`.

    Parameters
    ----------
    x : ndarray, shape (N,) or (N, n)
        Residual rate samples of the set, uniform in time, same unit for every column.
    fs : float
        Sample rate (Hz).
    """
    x = np.asarray(x, float)
    x = x.reshape(x.shape[0], -1)
    N, n = x.shape
    q_all = np.var(x, axis=0, ddof=1) if N > 1 else np.zeros(n)
    if N < 64:
        return GaussMarkovFit(q_all, 0.0, np.inf, 0.0)
    P = np.abs(np.fft.rfft(x - x.mean(axis=0), axis=0)) ** 2 / N    # E[P] = S (q for white)
    f = np.fft.rfftfreq(N, 1.0 / fs)
    P, f = P[1:-1], f[1:-1]
    edges = np.unique(np.geomspace(1, P.shape[0], _GM_BINS).astype(int))
    edges[-1] = P.shape[0]
    idx = np.repeat(np.arange(edges.size - 1), np.diff(edges))
    cnt = np.diff(edges).astype(float)
    Pm = np.stack([np.bincount(idx, P[:idx.size, i]) for i in range(n)], axis=1) / cnt[:, None]
    fm = np.bincount(idx, f[:idx.size]) / cnt
    hi = fm > fs / 8
    q = (cnt[hi] @ Pm[hi]) / cnt[hi].sum() if hi.any() else q_all
    q = np.maximum(q, 1e-300)
    nll0 = float(np.sum(cnt[:, None] * (np.log(q)[None, :] + Pm / q[None, :])))
    best = (nll0, 0.0, np.inf)
    lo, up = np.log(q.min()) - 30.0, np.log(q.max()) + 10.0

    def nll_tc(lv: float, tc: float) -> float:
        """Binned Whittle −log L at log σ_b² and τc."""
        phi = np.exp(-1.0 / (fs * tc))
        g = (1 - phi**2) / np.abs(1 - phi * np.exp(-2j * np.pi * fm / fs)) ** 2
        S = q[None, :] + np.exp(lv) * g[:, None]
        return float(np.sum(cnt[:, None] * (np.log(S) + Pm / S)))

    taus = np.geomspace(1.0, 4.0 * N / fs, GM_TAU_GRID)
    prof_v, prof_nll = np.zeros(taus.size), np.zeros(taus.size)
    for j, tc in enumerate(taus):
        r = scipy.optimize.minimize_scalar(lambda lv, tc=tc: nll_tc(lv, tc),
                                           bounds=(lo, up), method="bounded")
        prof_v[j], prof_nll[j] = float(np.exp(r.x)), float(r.fun)
        if r.fun < best[0]:
            best = (float(r.fun), float(np.exp(r.x)), float(tc))
    lr = 2.0 * (nll0 - best[0])
    if lr <= GM_LR_THRESHOLD or best[1] <= 0:
        return GaussMarkovFit(q, 0.0, np.inf, max(lr, 0.0), record_s=N / fs)
    cov = _log_param_cov(lambda lv, lt: nll_tc(lv, float(np.exp(lt))), np.log(best[1]),
                         np.log(best[2]))
    return GaussMarkovFit(q, best[1], best[2], lr, cov, taus, prof_v, prof_nll, N / fs)


def gauss_markov_sigma_candidates(fit: GaussMarkovFit
                                  ) -> tuple[np.ndarray, np.ndarray, bool]:
    """The (τc, σ_b²) pairs over which a coloured-noise σ is taken as the largest.

    The grid τc whose profile ``−log L`` lies within :data:`GM_SIGMA_DELTA_NLL` of the
    minimum (the 90 % profile-likelihood interval of τc, Wilks), cut at
    :data:`GM_SIGMA_CAP_RECORDS` of the record, each with its profiled σ_b². When the whole
    interval lies beyond the cut, the best pair at or below it. Empty when the term is not
    kept.

    Why. On a record of a few correlation times (tetrad-paper: 576 s, τc 100 s) the fitted
    τc is badly determined (profile ``−log L`` within 1-2 units from 40 s to the grid's
    end in most sessions) and the bias variance grows with it (≈ ∝ σ_b²·τc, the spectrum
    at zero frequency, which the residuals never see: the fit removes it). The σ at the
    maximum-likelihood τc is then a scale mixture: 2× too small where τ̂c came out short
    (< 60 s; all the biases beyond 3σ), 2-6× too large where it ran long. Taking the largest
    variance over the τc the likelihood cannot exclude removes the short tail; the cut
    keeps the flat long side from running to the grid's end.

    Returns
    -------
    tau_s : ndarray, shape (k,)
    bias_var : ndarray, shape (k,)
    cut : bool
        The interval reaches beyond the cut: the likelihood does not exclude a slower
        process, whose bias σ would be larger than the ones these candidates give.
    """
    if fit.bias_var <= 0 or fit.profile_tau_s is None or fit.profile_nll is None \
            or fit.profile_bias_var is None:
        return np.zeros(0), np.zeros(0), False
    tau, nll, bv = fit.profile_tau_s, fit.profile_nll, fit.profile_bias_var
    below = tau <= GM_SIGMA_CAP_RECORDS * fit.record_s
    if not below.any():
        below = tau <= tau.min()
    inside = nll <= nll.min() + GM_SIGMA_DELTA_NLL
    keep = below & inside
    if not keep.any():
        keep = np.zeros_like(below)
        keep[np.flatnonzero(below)[np.argmin(nll[below])]] = True
    return tau[keep], bv[keep], bool(np.any(inside & ~below))


_HESS_STEP = 0.05
"""Central-difference step (in log σ_b² and log τc) of the observed information."""


def _log_param_cov(nll: Any, lv: float, lt: float) -> np.ndarray:
    """Inverse Hessian of ``nll(lv, lt)`` at a point (central differences); ``inf`` when the
    Hessian is not positive definite."""
    h = _HESS_STEP
    f0 = nll(lv, lt)
    hvv = (nll(lv + h, lt) - 2 * f0 + nll(lv - h, lt)) / h**2
    htt = (nll(lv, lt + h) - 2 * f0 + nll(lv, lt - h)) / h**2
    hvt = (nll(lv + h, lt + h) - nll(lv + h, lt - h) - nll(lv - h, lt + h)
           + nll(lv - h, lt - h)) / (4 * h**2)
    H = np.array([[hvv, hvt], [hvt, htt]])
    if not (np.all(np.isfinite(H)) and hvv > 0 and np.linalg.det(H) > 0):
        return np.full((2, 2), np.inf)
    return np.linalg.inv(H)
