"""Fit the residual tail model a calibration keeps (:class:`fdi.tails.TailModel`).

Input: the calibration's residual per sensor (N, n) in SI, NaN where a sample was not used
(left-out segments, gaps). Since ``V·H̃ = 0`` the parity of the residual is the parity of
the compensated outputs: ``p = V·e``. With the calibration's V and Σ the monitor's
statistic at scale w with ``f_w = 1`` is ``S_w = |Σ_window z|²/w``, z the whitened parity,
over every window of w consecutive valid samples (a window never spans a left-out sample,
as the monitor restarts its windows).

Relative to the monitor's own threshold: the monitor widens its threshold at scale w by
``1 + w·β + κ·Σ_w ρ`` (:mod:`fdi.windows`, with f_w = 1: the calibration's bias and
calibration uncertainty, and the timing jitter at the current angular acceleration). Given
the per-sample ρ of the recording and κ, β (:func:`fdi.reconstruction.inflation_terms`),
every window statistic is divided by its window's inflation (the independent window sums
by its square root), so that the tails describe what the thresholds do not already
explain: a residual that is large only while the body accelerates hard, as a timing jitter
makes it, is not taken for a heavy tail everywhere.

Per scale:

1. **Normality check** on the non-overlapping windows (independent for white noise): the
   excess kurtosis of the standardised whitened window-mean components
   (``scipy.stats.kurtosistest``, one-sided, heavier than Gaussian) and the number of
   ``S_w/v_w`` beyond the χ²(df) 1 % point against Binomial(n, 0.01) (v_w = mean(S_w)/df,
   so colour alone does not fail it), each at ``level/(2K)`` for K scales (Bonferroni:
   a Gaussian white residual fails somewhere with probability at most ``level``). Fewer than
   :data:`MIN_TEST_WINDOWS` windows cannot be tested: the scale inherits the verdict of
   the longest tested scale below it. A scale with fewer than :data:`MIN_POWER_WINDOWS`
   windows that passes while a shorter scale failed is not taken as Gaussian (too few
   windows to show that the tails average out): it fails with the shorter one.
2. **Empirical tail** at half-decade probabilities p from 0.1 down to what the data
   resolve: the upper bound ``q⁺(p)`` is the empirical quantile whose exceedance count has a
   one-sided Clopper–Pearson upper limit p, counting exceedances in units of the
   non-overlapping windows (overlapping running means are correlated; n_eff = N/w). The
   smallest resolved p is ``1 − (1 − c)^(1/n_eff)`` (no exceedance at all).
3. **Peaks over threshold** below it: a generalised Pareto law (``scipy.stats.genpareto``,
   maximum likelihood, location 0) fitted to the exceedances of the (1 − p_u) quantile
   u (the top 2 %, at most 1000 values); runs of exceedances closer than w samples form
   one cluster. The upper bound of the quantile at p (down to
   :data:`SMALLEST_PROBABILITY`) is its profile-likelihood limit at one-sided confidence
   c, the log-likelihood scaled by clusters/exceedances (a dependence adjustment: each
   cluster counts once), with ζ_u at its Clopper–Pearson upper limit. Fewer than
   :data:`MIN_CLUSTERS` clusters: no fit; the scale carries the curve of the nearest
   shorter fitted scale over, scaled by the ratio of the measured variance ratios.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy import optimize, stats

from fdi.parity import parity_matrix
from fdi.tails import GpdFit, ScaleTail, TailModel

__all__ = ["CONFIDENCE", "LEVEL", "MIN_CLUSTERS", "MIN_POWER_WINDOWS", "MIN_TEST_WINDOWS",
           "SMALLEST_PROBABILITY",
           "fit_tail_model", "whitened_parity", "window_statistics"]

CONFIDENCE = 0.95
"""One-sided confidence of every upper bound."""
LEVEL = 0.01
"""Family-wise significance level of the normality check (all scales, both tests)."""
MIN_TEST_WINDOWS = 20
MIN_POWER_WINDOWS = 200
"""Independent windows below which a pass does not outweigh a shorter scale's failure."""
"""Non-overlapping windows below which a scale's normality cannot be tested."""
MIN_CLUSTERS = 10
"""Declustered exceedances below which no GPD is fitted."""
SMALLEST_PROBABILITY = 1e-10
"""Smallest per-sample probability the curve is extrapolated to."""
TAIL_FRACTION = 0.02
"""Share of the window statistics above the GPD threshold u (at most MAX_EXCEEDANCES)."""
MAX_EXCEEDANCES = 1000
"""Cap on the exceedances fitted (long recordings: u moves up instead)."""
_CAP = 1e15
"""Largest tabulated bound (a flat profile likelihood: the data bound nothing)."""


def whitened_parity(residual: np.ndarray, H: np.ndarray, noise_cov: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Whitened parity z (N, df) of a residual (N, n) SI and the valid rows (N,) bool.

    ``z = L⁻¹·V·e`` with ``L·Lᵀ = VΣVᵀ`` (|z|² does not depend on which whitening).
    """
    e = np.asarray(residual, float)
    valid = np.all(np.isfinite(e), axis=1)
    V = parity_matrix(np.asarray(H, float))
    S = np.asarray(noise_cov, float)
    L = np.linalg.cholesky(V @ S @ V.T)
    p = V @ np.where(valid[:, None], e, 0.0).T
    z = np.linalg.solve(L, p).T
    z[~valid] = 0.0
    return z, valid


def window_statistics(z: np.ndarray, valid: np.ndarray, w: int
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Window sums of z over every w consecutive valid samples.

    Returns
    -------
    S : ndarray, shape (M,)
        ``|Σ z|²/w`` per window.
    end : ndarray of int, shape (M,)
        Index of each window's last sample.
    independent : ndarray of bool, shape (M,)
        The non-overlapping windows (the first of each run, then every w-th).
    """
    N = z.shape[0]
    c = np.vstack([np.zeros((1, z.shape[1])), np.cumsum(z, axis=0)])
    cnt = np.concatenate([[0], np.cumsum(valid)])
    if N < w:
        return np.zeros(0), np.zeros(0, int), np.zeros(0, bool)
    full = (cnt[w:] - cnt[:-w]) == w
    sums = (c[w:] - c[:-w])[full]
    end = np.flatnonzero(full) + w - 1
    # run start of every sample: the last invalid index before it, + 1
    last_bad = np.maximum.accumulate(np.where(~valid, np.arange(N), -1))
    start = last_bad[end] + 1
    independent = ((end - start - (w - 1)) % w) == 0
    return np.sum(sums * sums, axis=1) / w, end, independent


def _cp_upper(k: float, n: float, conf: float) -> float:
    """One-sided Clopper–Pearson upper limit of a probability (k of n, k may be fractional)."""
    if k >= n:
        return 1.0
    return float(stats.beta.ppf(conf, k + 1.0, n - k))


def _grid() -> np.ndarray:
    """Half-decade probabilities 10^-1 ... SMALLEST_PROBABILITY."""
    k = round(-2 * math.log10(SMALLEST_PROBABILITY))
    return 10.0 ** (-np.arange(2, k + 1) / 2.0)


def _empirical(S: np.ndarray, n_eff: int, conf: float
               ) -> tuple[list[float], list[float], list[float], float]:
    """Resolved probabilities, point quantiles, upper bounds, and the smallest resolved p."""
    p_min = 1.0 - (1.0 - conf) ** (1.0 / max(n_eff, 1))
    ps, qs, qu = [], [], []
    Ss = np.sort(S)
    M = Ss.size
    for p in _grid():
        if p < p_min:
            break
        # fraction phi whose CP upper limit (in independent windows) is p
        if _cp_upper(0.0, n_eff, conf) >= p:
            phi = 0.0
        else:
            phi = optimize.brentq(lambda f, p=p: _cp_upper(f * n_eff, n_eff, conf) - p,
                                  0.0, p, xtol=1e-14)
        k = math.floor(phi * M)            # windows allowed above the bound
        ps.append(float(p))
        qs.append(float(np.quantile(Ss, 1.0 - p)))
        qu.append(float(Ss[max(M - 1 - k, 0)]))
    if not ps:                  # too few windows for 10 %: one point, the largest window
        ps, qs, qu = [min(p_min, 0.5)], [float("nan")], [float(Ss[-1])]
    return ps, qs, qu, p_min


def _loglik(y: np.ndarray, xi: float, sigma: float) -> float:
    if not sigma > 0:
        return -math.inf
    v = stats.genpareto.logpdf(y, xi, 0.0, sigma)
    s = float(np.sum(v))
    return s if math.isfinite(s) else -math.inf


def _sigma_for(xi: float, xp: float, u: float, ratio: float) -> float:
    """σ that puts the (ζ/p = ratio) quantile at xp."""
    if abs(xi) < 1e-9:
        return (xp - u) / math.log(ratio)
    return xi * (xp - u) / (ratio**xi - 1.0)


_XI_GRID = np.linspace(-0.45, 3.0, 139)
"""ξ values over which the profile likelihood of a quantile is maximised (step 0.025; the
maximum on the grid is at most the true one, so the limit it gives is slightly wider)."""


def _profile(y: np.ndarray, xp: float, u: float, ratio: float) -> float:
    """max over ξ (on :data:`_XI_GRID`) of the log-likelihood with the quantile at xp."""
    xi = _XI_GRID[:, None]
    small = np.abs(xi) < 1e-9
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        sig = np.where(small, (xp - u) / math.log(ratio),
                       xi * (xp - u) / (np.power(ratio, xi) - 1.0))
        t = 1.0 + xi * y[None, :] / sig
        ll = np.where(small, -np.log(sig) - y[None, :] / sig,
                      -np.log(sig) - (1.0 + 1.0 / xi) * np.log(t))
        ll = np.where((t > 0) & (sig > 0), ll, -np.inf)
    tot = ll.sum(axis=1)
    tot = tot[np.isfinite(tot)]
    return float(tot.max()) if tot.size else -math.inf


def _gpd(S: np.ndarray, end: np.ndarray, w: int, n_eff: int, conf: float,
         probs: list[float]) -> tuple[GpdFit | None, list[float], list[float], str]:
    """GPD fit above u and the point and upper quantiles at ``probs`` (module docstring)."""
    M = S.size
    frac = min(TAIL_FRACTION, MAX_EXCEEDANCES / max(M, 1))
    u = float(np.quantile(S, 1.0 - frac))
    over = S > u
    y = S[over] - u
    pos = end[over]
    if y.size == 0:
        return None, [], [], "no exceedances"
    order = np.argsort(pos)
    clusters = 1 + int(np.sum(np.diff(pos[order]) > w))
    if clusters < MIN_CLUSTERS:
        return None, [], [], f"{clusters} clusters of exceedances (< {MIN_CLUSTERS}): no GPD fit"
    xi, _, sigma = stats.genpareto.fit(y, floc=0.0)
    xi, sigma = float(xi), float(sigma)
    lmax = _loglik(y, xi, sigma)
    adj = clusters / y.size
    crit = float(stats.chi2.ppf(2 * conf - 1, 1)) / (2.0 * adj)     # deficit allowed
    zeta = y.size / M
    zeta_up = min(1.0, _cp_upper(zeta * n_eff, n_eff, conf))
    # profile-likelihood upper limit of ξ
    pxi = lambda x: -optimize.minimize_scalar(  # noqa: E731
        lambda ls: -_loglik(y, x, math.exp(ls)), bounds=(math.log(sigma) - 8,
                                                        math.log(sigma) + 8),
        method="bounded").fun
    xi_up = xi
    step = 0.05
    while xi_up < 5.0 and lmax - pxi(xi_up + step) < crit:
        xi_up += step
    if xi_up < 5.0:
        xi_up = optimize.brentq(lambda x: lmax - pxi(x) - crit, xi_up, xi_up + step,
                                xtol=1e-3)
    gpd = GpdFit(threshold=u, exceedance_probability=zeta, exceedance_probability_upper=zeta_up,
                 exceedances=int(y.size), clusters=clusters, shape=xi,
                 shape_sd=float((1.0 + max(xi, -0.49)) / math.sqrt(clusters)),
                 shape_upper=float(xi_up), scale_param=sigma)
    qs, qu = [], []
    for p in probs:
        r_hat = zeta / p
        qs.append(u + (sigma / xi * (r_hat**xi - 1.0) if abs(xi) > 1e-9
                       else sigma * math.log(r_hat)))
        ratio = zeta_up / p
        if ratio <= 1.0:
            qu.append(u)
            continue
        x0 = u + (sigma / xi * (ratio**xi - 1.0) if abs(xi) > 1e-9 else sigma * math.log(ratio))
        x0 = max(x0, u * (1 + 1e-9) + 1e-12)
        dev = lambda xp, ratio=ratio: lmax - _profile(y, xp, u, ratio) - crit  # noqa: E731
        hi = x0
        while dev(hi) < 0 and hi < _CAP:
            lo_ = hi
            hi = u + 2.0 * (hi - u)
        if hi >= _CAP:
            qu.append(_CAP)
            continue
        lo_ = x0 if hi == x0 else lo_
        qu.append(float(optimize.brentq(dev, lo_, hi, xtol=1e-3 * (hi - u))) if hi > lo_
                  else hi)
    return gpd, qs, qu, ""


def _normality(S: np.ndarray, sums_ind: np.ndarray, df: int, level: float
               ) -> tuple[float, float, float, bool | None]:
    n = sums_ind.shape[0]
    if n < MIN_TEST_WINDOWS:
        return float("nan"), float("nan"), float("nan"), None
    x = sums_ind / np.where(sums_ind.std(axis=0) > 0, sums_ind.std(axis=0), 1.0)
    flat = x.ravel()
    kurt = float(stats.kurtosis(flat, fisher=True))
    kp = float(stats.kurtosistest(flat, alternative="greater").pvalue)
    vr = float(np.mean(S)) / df
    Sn = np.sum(sums_ind**2, axis=1) / max(vr * df, 1e-300) * df
    k = int(np.sum(Sn > stats.chi2.isf(0.01, df)))
    ep = float(stats.binom.sf(k - 1, n, 0.01))
    return kurt, kp, ep, bool(kp > level / 2 and ep > level / 2)


def fit_tail_model(residual: np.ndarray, H: np.ndarray, noise_cov: np.ndarray,
                   sample_rate_hz: float, *, scales: tuple[int, ...] = tuple(2**k
                                                                              for k in range(8)),
                   source: str = "", confidence: float = CONFIDENCE,
                   level: float = LEVEL, rho: np.ndarray | None = None, kappa: float = 0.0,
                   beta: float = 0.0) -> TailModel | None:
    """The tail model of a calibration residual (module docstring).

    Parameters
    ----------
    residual : ndarray, shape (N, n)
        Residual per sensor (SI), NaN rows where a sample is not used.
    H : ndarray, shape (n, 3)
        Calibrated axes.
    noise_cov : ndarray, shape (n, n)
        The calibration's noise covariance (SI²).
    sample_rate_hz : float
    scales : tuple of int
        Window lengths (samples); the monitor's are 1, 2, ..., 128.
    source : str
        What the residual is (recorded).
    confidence, level : float
    rho : ndarray, shape (N,), optional
        The monitor's ρ per sample (:func:`fdi.reconstruction.inflation_terms`); with
        ``kappa`` and ``beta`` every window statistic is taken relative to the monitor's
        inflation ``1 + w·β + κ·Σ_w ρ`` (module docstring). Omitted: no inflation.
    kappa, beta : float

    Returns
    -------
    TailModel or None
        None without a parity space (n < 4), with a singular parity noise covariance (a
        noiseless simulated set) or with fewer than 64 valid samples.
    """
    H = np.asarray(H, float)
    if H.shape[0] < 4:
        return None
    try:
        z, valid = whitened_parity(residual, H, noise_cov)
    except np.linalg.LinAlgError:               # a noiseless (simulated) set: no tail to fit
        return None
    df = z.shape[1]
    if int(valid.sum()) < 64:
        return None
    out: list[ScaleTail] = []
    verdict: bool | None = None
    cq = None
    if rho is not None:
        r = np.where(valid & np.isfinite(np.asarray(rho, float)), np.asarray(rho, float), 0.0)
        cq = np.concatenate([[0.0], np.cumsum(r)])
    for w in sorted(int(x) for x in scales):
        S, end, ind = window_statistics(z, valid, w)
        if S.size < 2:
            break
        S, sums_ind = _independent_sums(z, S, end, ind, w, cq, kappa, beta)
        n_eff = int(ind.sum())
        kurt, kp, ep, ok = _normality(S, sums_ind, df, level / len(scales))
        ok, verdict, notes = _decide(ok, verdict, n_eff, out)
        vr = float(np.mean(S)) / df
        ps, qs, qu, src, gpd = _quantiles(S, end, w, n_eff, confidence, ok, vr, out, notes)
        out.append(ScaleTail(scale=w, windows=int(S.size), independent=n_eff,
                             variance_ratio=max(vr, 1e-300), excess_kurtosis=kurt,
                             kurtosis_p=kp, exceedance_p=ep, gaussian=bool(ok),
                             probability=tuple(ps), quantile=tuple(float(q) for q in qs),
                             quantile_upper=tuple(float(q) for q in qu), source=tuple(src),
                             gpd=gpd, notes="; ".join(notes)))
    if not out:
        return None
    return TailModel(df=df, samples=int(valid.sum()), sample_rate_hz=float(sample_rate_hz),
                     confidence=confidence, level=level, scales=tuple(out), source=source)


def _quantiles(S: np.ndarray, end: np.ndarray, w: int, n_eff: int, confidence: float,
               ok: bool, vr: float, out: list[ScaleTail], notes: list[str]
               ) -> tuple[list, list, list, list, GpdFit | None]:
    """The quantiles of one scale: empirical, then below the empirical tail a GPD fit
    where the scale is not Gaussian, or the tail carried from a shorter scale; the upper
    quantiles made non-decreasing and capped. Returns (p, q, q_upper, source, gpd)."""
    ps, qs, qu, p_min = _empirical(S, n_eff, confidence)
    src = ["empirical"] * len(ps)
    rest = [float(p) for p in _grid() if p < min(p_min, ps[-1])]
    gpd, gq, gu, why = None, [], [], ""
    if rest and not ok:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)   # degenerate likelihoods
            gpd, gq, gu, why = _gpd(S, end, w, n_eff, confidence, rest)
    if why:
        notes.append(why)
    if gpd is not None:
        ps, qs, qu, src = ps + rest, qs + gq, qu + gu, src + ["gpd"] * len(rest)
    elif rest and not ok and any(r.gpd is not None or "carried" in r.source for r in out):
        ps, qs, qu, src = _carry(out, rest, vr, p_min, ps, qs, qu, src, notes)
    qu = list(np.minimum(np.maximum.accumulate(np.maximum(qu, 1e-300)), _CAP))
    return ps, qs, qu, src, gpd


def _independent_sums(z: np.ndarray, S: np.ndarray, end: np.ndarray, ind: np.ndarray,
                      w: int, cq: np.ndarray | None, kappa: float, beta: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The window statistics ``S`` and the whitened sums of the independent windows
    (``ind``), both relative to the monitor's inflation when ``cq`` (the cumulative ρ) is
    given."""
    df = z.shape[1]
    c = np.vstack([np.zeros((1, df)), np.cumsum(z, axis=0)])
    sums_ind = (c[end[ind] + 1] - c[end[ind] + 1 - w]) / math.sqrt(w)
    if cq is not None:
        infl = 1.0 + w * float(beta) + float(kappa) * (cq[end + 1] - cq[end + 1 - w])
        S = S / infl
        sums_ind = sums_ind / np.sqrt(infl[ind])[:, None]
    return S, sums_ind


def _decide(ok: bool | None, verdict: bool | None, n_eff: int, out: list[ScaleTail]
            ) -> tuple[bool, bool | None, list[str]]:
    """Whether a scale is taken as Gaussian: its normality test; the verdict of the longest
    tested shorter scale where it cannot be tested; not Gaussian when it passes on too few
    windows after a shorter scale failed. Returns (gaussian, verdict carried on, notes)."""
    if ok is None:
        return (True if verdict is None else verdict), verdict, [
            f"{n_eff} independent windows: normality not testable, verdict of the longest "
            "tested shorter scale"]
    if ok and n_eff < MIN_POWER_WINDOWS and any(not r.gaussian for r in out):
        return False, verdict, [
            f"passes on {n_eff} independent windows (< {MIN_POWER_WINDOWS}) but a shorter "
            "scale fails: not taken as Gaussian"]
    return ok, ok, []


def _carry(out: list[ScaleTail], rest: list[float], vr: float, p_min: float, ps: list,
           qs: list, qu: list, src: list, notes: list[str]) -> tuple[list, list, list, list]:
    """The tail below the empirical one carried from the last shorter scale that had one,
    scaled by the variance ratio (a note added)."""
    prev = [r for r in out if r.gpd is not None or "carried" in r.source][-1]
    ratio = max(1.0, vr / prev.variance_ratio)
    pp = dict(zip(prev.probability, prev.quantile_upper, strict=True))
    add = [(p, pp[p] * ratio) for p in rest if p in pp]
    notes.append(f"tail below p={p_min:.2g} carried from scale {prev.scale} (x{ratio:.3g})")
    return (ps + [a for a, _ in add], qs + [float("nan")] * len(add),
            qu + [b for _, b in add], src + ["carried"] * len(add))
