"""Stage 5 of the calibration: covariances of every estimate, white and coloured noise.

Every estimate is linear in segment means, ``θ = op @ ū_seg``, so under white per-sample
noise ``cov(θ_i, θ_j) = Σ_ij·op·diag(1/N)·opᵀ`` (Σ the per-sample raw noise covariance),
then first-order propagation through the unit-norm split (seed 000 Eq. 19,
:func:`calibration.rate_test.split_gain`).

Coloured noise (``noise_model="auto"``): a white + first-order Gauss-Markov model, the bias
process common to the set, is fitted to the residual spectrum
(:func:`calibration.residuals.fit_gauss_markov`, Whittle likelihood); when the
likelihood-ratio test keeps it, its exact covariance over the segment means
``(σ_b/SF_i)²·op·K(τc)·opᵀ`` is added to the white one (it only adds). The pair (σ_b², τc)
of that covariance is not the maximum-likelihood one but the one, among the correlation
times the profile likelihood does not exclude (90 % interval, cut at a quarter of the
record: :func:`calibration.residuals.gauss_markov_sigma_candidates`), that gives the
largest model-bias variance (:func:`coloured_noise`). Why, and what it does to the tails of
error/σ: ``tests/calibration/test_calibrate_coloured_holdout.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.rate_test import GainSplit, split_gain
from calibration.residuals import (
    GM_LR_THRESHOLD,
    GM_SIGMA_CAP_RECORDS,
    GM_SIGMA_DELTA_NLL,
    fit_gauss_markov,
    gauss_markov_segment_corr,
    gauss_markov_sigma_candidates,
)
from fdi.extras import SD_FACTOR_KEYS, NoiseFit
from fdi.parity import parity_matrix

__all__ = ["NOISE_METHOD", "ColouredNoise", "SensorEstimate", "Uncertainty", "coloured_noise",
           "noise_record", "parity_sd", "segment_times", "set_uncertainty", "split_all",
           "split_with_cov"]

NOISE_METHOD = {
    "white": "white: covariances sigma^2 op diag(1/N) op^T from the per-sample residual "
             "variance",
    "auto": "auto: white + first-order Gauss-Markov bias common to the set, Whittle "
            "maximum-likelihood fit to the residual spectrum, kept when its likelihood-ratio "
            f"statistic exceeds {GM_LR_THRESHOLD}; its exact covariance over the segment "
            "means is added, at the correlation time (sigma_correlation_s) with the largest "
            "bias variance within the 90 % profile-likelihood interval of the correlation "
            f"time (-log L within {GM_SIGMA_DELTA_NLL} of its minimum), cut at "
            f"{GM_SIGMA_CAP_RECORDS:g} of the record",
}
"""Text of ``extra["noise_model"]["method"]`` per noise model."""


@dataclass(frozen=True)
class SensorEstimate:
    """One sensor's scale factor, axis, bias and their uncertainties (SI).

    Attributes
    ----------
    split : GainSplit
        SF, h̃, misalignment angles and their first-order covariance.
    bias, bias_sd : float
        b = c·SF and its sd (input units).
    input_error_cov : ndarray, shape (3, 3)
        Covariance of the gain-normalised error of h̃/SF.
    """

    split: GainSplit
    bias: float
    bias_sd: float
    input_error_cov: np.ndarray


def split_all(a: np.ndarray, c: np.ndarray, Q: np.ndarray, Sigma_raw: np.ndarray,
              H0: np.ndarray, extra_cov: np.ndarray | None = None) -> list[SensorEstimate]:
    """Per sensor: SF, h̃, angles, bias and their sds from (a, c) and the factor ``Q``.

    Parameters
    ----------
    a : ndarray, shape (n, 3)
    c : ndarray, shape (n,)
    Q : ndarray, shape (k, k), k ≥ 4
        White covariance factor of ``(a, c, ...)``; the first four rows are used.
    Sigma_raw : ndarray, shape (n, n)
    H0 : ndarray, shape (n, 3)
        Nominal axes.
    extra_cov : ndarray, shape (n, k, k), optional
        Coloured-noise part of each sensor's covariance, added to ``Σ_ii·Q``.
    """
    C = np.array([Sigma_raw[i, i] * Q[:4, :4] for i in range(a.shape[0])])
    if extra_cov is not None:
        C = C + np.asarray(extra_cov)[:, :4, :4]
    return split_with_cov(a, c, C, H0)


def split_with_cov(a: np.ndarray, c: np.ndarray, C: np.ndarray,
                   H0: np.ndarray) -> list[SensorEstimate]:
    """Per sensor: SF, h̃, angles, bias and their sds from (a, c) and their covariance.

    Parameters
    ----------
    a : ndarray, shape (n, 3)
    c : ndarray, shape (n,)
    C : ndarray, shape (n, 4, 4)
        Covariance of each sensor's ``(a, c)`` (raw units).
    H0 : ndarray, shape (n, 3)
    """
    out = []
    for i in range(a.shape[0]):
        Ci = C[i]
        g = split_gain(a[i], Ci[:3, :3], H0[i])
        sf = g.scale_factor
        jb = np.concatenate([c[i] * g.jac[0], [sf]])                # b = c/|a|
        out.append(SensorEstimate(split=g, bias=c[i] * sf,
                                  bias_sd=float(np.sqrt(max(jb @ Ci @ jb, 0.0))),
                                  input_error_cov=Ci[:3, :3] * sf**2))
    return out


@dataclass(frozen=True)
class ColouredNoise:
    """The Gauss-Markov fit of one set and its covariance over each operator.

    Attributes
    ----------
    applied : bool
        The likelihood-ratio test kept the bias process.
    bias_instability : float
        σ_b (SI).
    correlation_s : float or None
    likelihood_ratio : float
    extra_cov : tuple of (ndarray, shape (n, k, k), or None)
        Per operator, the coloured part of each sensor's covariance (raw units).
    cov_log : ndarray, shape (2, 2), or None
        Observed-information covariance of the fitted ``(log σ_b², log τc)``
        (:attr:`calibration.residuals.GaussMarkovFit.cov_log`); None when not applied.
        Not used for the σ: on a 576 s session it understates the spread of the fit about
        2× (see ``tests/calibration/test_coloured_tails.py``).
    sigma_bias_instability : float or None
        σ_b (SI) of the pair ``extra_cov`` is computed with (profiled at
        ``sigma_correlation_s``); None when not applied.
    sigma_correlation_s : float or None
        The correlation time (s) ``extra_cov`` is computed with: the one with the largest
        model-bias variance among :func:`calibration.residuals.gauss_markov_sigma_candidates`.
    record_s : float
        Length of the residual record the fit saw (s); ``sigma_correlation_s`` is at most
        :data:`calibration.residuals.GM_SIGMA_CAP_RECORDS` of it.
    sigma_cut : bool
        The profile interval of τc reached beyond that cut: the data do not exclude a
        slower process, for which these σ would be too small (a process slower than a
        quarter of the record: τc 300 s in a 576 s record gives bias error/σ sd ≈ 1.7).
    """

    applied: bool
    bias_instability: float
    correlation_s: float | None
    likelihood_ratio: float
    extra_cov: tuple[np.ndarray | None, ...]
    cov_log: np.ndarray | None = None
    sigma_bias_instability: float | None = None
    sigma_correlation_s: float | None = None
    record_s: float = 0.0
    sigma_cut: bool = False


def coloured_noise(resid_si: np.ndarray, sf: np.ndarray, fs: float, seg_start: np.ndarray,
                   seg_len: np.ndarray, ops: list[np.ndarray]) -> ColouredNoise:
    """Coloured-noise part of the covariance of linear estimates ``θ = op @ ū_seg``.

    Parameters
    ----------
    resid_si : ndarray, shape (N_used, n)
        Residuals in input units.
    sf : ndarray, shape (n,)
        Scale factors (input per raw).
    fs : float
    seg_start, seg_len : ndarray, shape (n_seg,)
        Start time and duration of each segment (s).
    ops : list of ndarray, each (k, n_seg)
        The first one's row 3 (the offset c) chooses the pair: among the candidates of
        :func:`calibration.residuals.gauss_markov_sigma_candidates`, the (σ_b², τc) with the
        largest ``σ_b²·op₃·K(τc)·op₃ᵀ`` (the Gauss-Markov variance of every sensor's bias,
        up to its SF²). The bias variance grows with τc along the profile, so this is in
        effect the upper end of the interval.
    """
    fit = fit_gauss_markov(resid_si, fs)
    applied = fit.bias_var > 0
    outs: list[np.ndarray | None] = [None] * len(ops)
    sig_v = sig_tc = None
    cut = False
    if applied:
        tc_c, bv_c, cut = gauss_markov_sigma_candidates(fit)
        Ks = [gauss_markov_segment_corr(seg_start, seg_len, tc) for tc in tc_c]
        c_row = ops[0][3]
        j = int(np.argmax([bv * (c_row @ K @ c_row) for bv, K in zip(bv_c, Ks, strict=True)]))
        K, sig_v, sig_tc = Ks[j], float(bv_c[j]), float(tc_c[j])
        var_raw = sig_v / np.asarray(sf, float) ** 2
        outs = [var_raw[:, None, None] * (op @ K @ op.T)[None, :, :] for op in ops]
    return ColouredNoise(
        applied=bool(applied), bias_instability=float(np.sqrt(fit.bias_var)),
        correlation_s=float(fit.tau_c) if np.isfinite(fit.tau_c) else None,
        likelihood_ratio=float(fit.lr), extra_cov=tuple(outs), cov_log=fit.cov_log,
        sigma_bias_instability=None if sig_v is None else float(np.sqrt(sig_v)),
        sigma_correlation_s=sig_tc, record_s=float(fit.record_s), sigma_cut=cut)


def segment_times(t: np.ndarray, seg: np.ndarray, cnt_seg: np.ndarray,
                  fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Start time (s) and duration (N/fs) of each segment; duration 0 when empty."""
    start = np.zeros(cnt_seg.size)
    use = seg >= 0
    if use.any():
        tt = np.asarray(t, float)[use]
        first = np.full(cnt_seg.size, np.inf)
        np.minimum.at(first, seg[use], tt)
        start = np.where(np.isfinite(first), first, 0.0)
    return start, cnt_seg / fs


def noise_record(cn: ColouredNoise | None, parts: list[SensorEstimate], a: np.ndarray,
                 c: np.ndarray, Q: np.ndarray, Sigma_raw: np.ndarray, H0: np.ndarray,
                 extra_cov: np.ndarray | None) -> NoiseFit:
    """What the noise model did to one set: fit, and sd factors (auto/white) per sensor."""
    n = a.shape[0]
    if extra_cov is None:
        factors = dict.fromkeys(SD_FACTOR_KEYS, (1.0,) * n)
    else:
        white = split_all(a, c, Q, Sigma_raw, H0)
        pw = list(zip(parts, white, strict=True))
        factors = dict(zip(SD_FACTOR_KEYS, (
            tuple(p.bias_sd / max(w.bias_sd, 1e-300) for p, w in pw),
            tuple(p.split.scale_factor_sd / max(w.split.scale_factor_sd, 1e-300)
                  for p, w in pw),
            tuple(float(np.max(p.split.misalignment_sd
                               / np.maximum(w.split.misalignment_sd, 1e-300)))
                  for p, w in pw)), strict=True))
    if cn is None:
        return NoiseFit(applied=False, sd_factor=factors)
    return NoiseFit(applied=cn.applied, bias_instability=cn.bias_instability,
                    correlation_s=cn.correlation_s, likelihood_ratio=cn.likelihood_ratio,
                    sigma_bias_instability=cn.sigma_bias_instability,
                    sigma_correlation_s=cn.sigma_correlation_s, sigma_cut=cn.sigma_cut,
                    record_s=cn.record_s, sd_factor=factors)


def parity_sd(H: np.ndarray, axis_jac: list[np.ndarray], Sigma_raw: np.ndarray,
              Qa: np.ndarray, extra_cov: np.ndarray | None = None) -> np.ndarray:
    """First-order sd of the calibrated parity matrix V(H̃), shape (n-3, n)."""
    n = H.shape[0]
    V0 = parity_matrix(H)
    eps = 1e-7
    J = np.zeros((V0.size, 3 * n))
    for i in range(n):
        for k in range(3):
            Hp = H.copy()
            Hp[i, k] += eps
            J[:, 3 * i + k] = (parity_matrix(Hp) - V0).ravel() / eps
    C = np.zeros((3 * n, 3 * n))
    for i in range(n):
        for j in range(n):
            Cij = Sigma_raw[i, j] * Qa
            if i == j and extra_cov is not None:
                Cij = Cij + extra_cov[i][:3, :3]
            C[3 * i:3 * i + 3, 3 * j:3 * j + 3] = axis_jac[i] @ Cij @ axis_jac[j].T
    return np.sqrt(np.clip(np.diag(J @ C @ J.T), 0, None)).reshape(V0.shape)


@dataclass(frozen=True)
class Uncertainty:
    """Estimates of one sensor set with their uncertainties (calibrate stage 5).

    Attributes
    ----------
    estimates : tuple of SensorEstimate
        From the main operator (gyros: explicit Earth-rate model).
    estimates_turns : tuple of SensorEstimate or None
        Gyros: with seed 000's whole-turn offsets (None without whole turns).
    coloured : ColouredNoise or None
        The Gauss-Markov fit (None: ``noise_model="white"``).
    extra_cov : ndarray, shape (n, k, k), or None
        Coloured part of the main operator's covariance (raw units); None: white only.
    record : NoiseFit
        ``extra["noise_model"][kind]``: the fit and the sd factors over white noise.
    theta_sd : ndarray, shape (k, n)
        sd of every row of ``θ = op @ ū_seg`` (raw units; rows a, c and regressors).
    """

    estimates: tuple[SensorEstimate, ...]
    estimates_turns: tuple[SensorEstimate, ...] | None
    coloured: ColouredNoise | None
    extra_cov: np.ndarray | None
    record: NoiseFit
    theta_sd: np.ndarray


def set_uncertainty(theta: np.ndarray, op: np.ndarray, inv_count: np.ndarray,
                    noise_cov_raw: np.ndarray, H0: np.ndarray, resid_raw: np.ndarray,
                    seg_start: np.ndarray, seg_len: np.ndarray, sample_rate_hz: float,
                    noise_model: str, theta_turns: np.ndarray | None = None,
                    op_turns: np.ndarray | None = None) -> Uncertainty:
    """Covariances of a set's estimates, white or white + Gauss-Markov (calibrate stage 5).

    Parameters
    ----------
    theta : ndarray, shape (k, n)
        ``op @ ū_seg``: rows a (3), c, then any regressor coefficients.
    op : ndarray, shape (k, n_seg)
    inv_count : ndarray, shape (n_seg,)
        1/N per segment (0 when empty).
    noise_cov_raw : ndarray, shape (n, n)
    H0 : ndarray, shape (n, 3)
    resid_raw : ndarray, shape (N_used, n)
    seg_start, seg_len : ndarray, shape (n_seg,)
        See :func:`segment_times`.
    sample_rate_hz : float
    noise_model : {"auto", "white"}
    theta_turns, op_turns : optional
        A second operator (gyros: whole-turn offsets).
    """
    a, c = theta[:3].T, theta[3]
    Q = (op * inv_count) @ op.T
    cn = None
    ex = ex_t = None
    if noise_model == "auto":
        sf0 = 1.0 / np.linalg.norm(a, axis=1)
        ops = [op] + ([op_turns] if op_turns is not None else [])
        cn = coloured_noise(resid_raw * sf0, sf0, sample_rate_hz, seg_start, seg_len, ops)
        ex = cn.extra_cov[0]
        ex_t = cn.extra_cov[1] if op_turns is not None else None
    parts = split_all(a, c, Q, noise_cov_raw, H0, ex)
    parts_t = None
    if op_turns is not None and theta_turns is not None:
        Q_t = (op_turns * inv_count) @ op_turns.T
        parts_t = tuple(split_all(theta_turns[:3].T, theta_turns[3], Q_t, noise_cov_raw, H0,
                                  ex_t))
    var = np.diag(noise_cov_raw)[None, :] * np.diag(Q)[:, None]
    if ex is not None:
        var = var + np.diagonal(ex, axis1=1, axis2=2).T
    return Uncertainty(estimates=tuple(parts), estimates_turns=parts_t, coloured=cn,
                       extra_cov=ex,
                       record=noise_record(cn, parts, a, c, Q, noise_cov_raw, H0, ex),
                       theta_sd=np.sqrt(np.clip(var, 0.0, None)))
