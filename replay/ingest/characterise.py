"""What the residual between IMUs holds: the statistics behind ``docs/findings.md``.

Plain functions on arrays (SI inside: rad/s, s, Hz), each returning its estimate with a
standard deviation. Where the samples are correlated (vibration, drift), the standard
deviation comes from the scatter of the estimate over ``blocks`` contiguous pieces of the
record (σ = sd / √blocks), not from formulas that assume independent samples.

- :func:`fit_alignment`: least-squares map of one IMU's rates onto another's
  (ω_ref ≈ A·ω + b), its rotation (polar factor of A), scale (singular values) and the
  residual before and after.
- :func:`time_offset`: lag of one IMU behind another from the regression of their
  difference on the angular acceleration (ω_ref − ω ≈ τ·ω̇, first order in τ).
- :func:`noise_density`: one-sided amplitude spectral density in a band (Welch).
- :func:`spectral_lines`: Welch bins that rise above a median-filtered floor by more than
  the χ² spread of the estimate allows (family-wise false-alarm ``alpha``).
- :func:`allan`: overlapping Allan deviation (allantools, rate data), its value at
  τ = 1 s (angle random walk N) and its minimum (bias instability as ADI datasheets
  state it, "in-run bias stability").
- :func:`excess_kurtosis`: heavy tails (0 for a Gaussian).
- :func:`noise_from_pairs`: noise of each of m ≥ 3 sensors from the variances of their
  pairwise differences (the "three-cornered hat": var(x_i − x_j) = σ_i² + σ_j²).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from itertools import combinations

import numpy as np
import scipy.ndimage
import scipy.signal
import scipy.stats

from fdi.errors import ConfigError

__all__ = [
    "Alignment",
    "Estimate",
    "allan",
    "block_estimate",
    "common_mode",
    "excess_kurtosis",
    "fit_alignment",
    "noise_density",
    "noise_from_pairs",
    "pair_report",
    "rate_derivative",
    "spectral_lines",
    "static_report",
    "time_offset",
]


@dataclass(frozen=True)
class Estimate:
    """A number with its standard deviation.

    Attributes
    ----------
    value : float or ndarray
    sd : float or ndarray
    n : int
        Number of blocks (or samples) the σ rests on.
    """

    value: float | np.ndarray
    sd: float | np.ndarray
    n: int

    def to_dict(self, scale: float = 1.0) -> dict:
        """JSON-able, values multiplied by ``scale`` (a unit change)."""
        v = np.asarray(self.value, float) * scale
        s = np.asarray(self.sd, float) * scale
        return {"value": v.tolist(), "sd": s.tolist(), "blocks": self.n}


def block_estimate(fn: Callable[[np.ndarray], np.ndarray | float], x: np.ndarray,
                   blocks: int = 10) -> Estimate:
    """``fn`` on the whole of ``x`` (axis 0 is time), σ from its scatter over blocks.

    Parameters
    ----------
    fn : callable
        Array of shape (n, ...) → float or array.
    x : ndarray, shape (N, ...)
    blocks : int
        Contiguous pieces (≥ 2).
    """
    if blocks < 2 or x.shape[0] < 2 * blocks:
        raise ConfigError(f"need at least {2 * blocks} samples for {blocks} blocks, "
                          f"got {x.shape[0]}")
    parts = np.array_split(x, blocks)
    vals = np.array([np.asarray(fn(p), float) for p in parts])
    return Estimate(np.asarray(fn(x), float), vals.std(axis=0, ddof=1) / np.sqrt(blocks),
                    blocks)


@dataclass(frozen=True)
class Alignment:
    """ω_ref ≈ A·ω + b fitted by least squares.

    Attributes
    ----------
    A : ndarray, shape (3, 3)
    b : ndarray, shape (3,)
        rad/s.
    rotation : ndarray, shape (3, 3)
        Polar (closest orthogonal) factor of A.
    angle_deg : float
        Angle of that rotation (degrees).
    scales : ndarray, shape (3,)
        Singular values of A (1 = same scale).
    rms_before : ndarray, shape (3,)
        RMS of ω_ref − ω per axis (rad/s).
    rms_after : ndarray, shape (3,)
        RMS of ω_ref − (A·ω + b) per axis (rad/s).
    residual : ndarray, shape (N, 3)
    """

    A: np.ndarray
    b: np.ndarray
    rotation: np.ndarray
    angle_deg: float
    scales: np.ndarray
    rms_before: np.ndarray
    rms_after: np.ndarray
    residual: np.ndarray


def fit_alignment(ref: np.ndarray, other: np.ndarray) -> Alignment:
    """Fit ω_ref ≈ A·ω_other + b (both (N, 3), rad/s) by least squares."""
    X = np.hstack([other, np.ones((other.shape[0], 1))])
    C, *_ = np.linalg.lstsq(X, ref, rcond=None)
    A, b = C[:3].T, C[3]
    U, S, Vt = np.linalg.svd(A)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    angle = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))
    res = ref - (other @ A.T + b)
    return Alignment(A, b, R, angle, S, np.sqrt(np.mean((ref - other) ** 2, axis=0)),
                     np.sqrt(np.mean(res**2, axis=0)), res)


def rate_derivative(w: np.ndarray, t: np.ndarray, *, max_dt_factor: float = 2.5
                    ) -> np.ndarray:
    """ω̇ (N, k) by the five-point central difference; NaN at the ends and next to gaps.

    Error O(h⁴): 1e-4 relative at 5 Hz motion sampled at 50 Hz, where the three-point
    difference would be 1 % off (and bias a lag estimate by as much).
    """
    dt = np.median(np.diff(t))
    wd = np.full(w.shape, np.nan)
    span = t[4:] - t[:-4]
    ok = span <= 4 * max_dt_factor * dt
    h = span[ok, None] / 4
    wd[2:-2][ok] = (-w[4:][ok] + 8 * w[3:-1][ok] - 8 * w[1:-3][ok] + w[:-4][ok]) / (12 * h)
    return wd


def time_offset(ref: np.ndarray, other: np.ndarray, t: np.ndarray, *, blocks: int = 10,
                max_dt_factor: float = 2.5) -> tuple[Estimate, np.ndarray]:
    """Lag τ of ``other`` behind ``ref`` (s): ω_ref(t) − ω(t) ≈ τ·ω̇(t) + c.

    ω̇ is the five-point central difference of the mean of the two rates; differences
    that span a gap in ``t`` (longer than ``max_dt_factor`` median intervals) are left
    out. First order in τ: fine while τ·(highest motion frequency) ≪ 1. One τ per
    block from all three axes together; the estimate is their mean, σ their scatter.

    Returns
    -------
    tau : Estimate
        Seconds; positive when ``other`` lags ``ref``.
    residual : ndarray, shape (N, 3)
        ω_ref − ω − τ·ω̇ − c, NaN where ω̇ is not defined.
    """
    wd = rate_derivative(0.5 * (ref + other), t, max_dt_factor=max_dt_factor)
    d = ref - other
    good = np.isfinite(wd).all(axis=1)

    def tau_of(idx: np.ndarray) -> float:
        dd = d[idx] - d[idx].mean(axis=0)
        ww = wd[idx] - wd[idx].mean(axis=0)
        return float(np.sum(ww * dd) / np.sum(ww * ww))

    idx = np.flatnonzero(good)
    parts = np.array_split(idx, blocks)
    vals = np.array([tau_of(p) for p in parts])
    tau = tau_of(idx)
    res = np.full_like(d, np.nan)
    r = d[idx] - tau * wd[idx]
    res[idx] = r - r.mean(axis=0)
    return Estimate(tau, float(vals.std(ddof=1) / np.sqrt(blocks)), blocks), res


def noise_density(x: np.ndarray, fs: float, band: tuple[float, float], *,
                  blocks: int = 10, nperseg: int = 512) -> Estimate:
    """One-sided amplitude spectral density (unit/√Hz) of ``x`` (N,) or (N, k) in a band.

    The mean of the Welch PSD over the band's bins, square-rooted, per column.
    """
    def dens(p: np.ndarray) -> np.ndarray:
        f, P = scipy.signal.welch(p - p.mean(axis=0), fs=fs, nperseg=min(nperseg, len(p)),
                                  axis=0)
        m = (f >= band[0]) & (f <= band[1])
        return np.sqrt(P[m].mean(axis=0))

    return block_estimate(dens, x, blocks)


def spectral_lines(x: np.ndarray, fs: float, *, nperseg: int = 256, alpha: float = 0.01,
                   floor_bins: int | None = None, min_ratio: float = 2.0
                   ) -> list[dict[str, float]]:
    """Frequencies where the PSD of ``x`` ((N,) or (N, k), summed over columns) stands out.

    The floor is a running median of the PSD over ``floor_bins`` bins (default: an
    eighth of the band, at least 15, so that a resonance a few bins wide stands out of
    it). A Welch estimate
    averaged over K segments (Hann window, 50 % overlap) is χ²-distributed around the
    true PSD with ν ≈ 2K/1.056 degrees of freedom (Welch 1967); the columns are summed
    but, as they may be correlated, ν is not multiplied by their number (conservative).
    A bin is a line when PSD/floor exceeds the χ²_ν/ν quantile at ``alpha / number of
    bins`` (family-wise false-alarm probability ``alpha`` for white noise) and
    ``min_ratio`` (3 dB by default: on long records the χ² bound alone would call a
    gentle bend of the noise floor a line).

    Returns
    -------
    list of dict
        ``{"f_hz", "ratio", "threshold"}``, strongest first.
    """
    x = np.atleast_2d(np.asarray(x, float).T).T
    n = min(nperseg, x.shape[0])
    f, P = scipy.signal.welch(x - x.mean(axis=0), fs=fs, nperseg=n, axis=0)
    Ps = P.sum(axis=1)
    nb = floor_bins if floor_bins is not None else max(15, len(f) // 8)
    floor = scipy.ndimage.median_filter(Ps, nb, mode="nearest")
    k_seg = max(1, (x.shape[0] - n) // (n // 2) + 1)
    dof = 2.0 * k_seg / 1.056
    thr = scipy.stats.chi2.isf(alpha / len(f), dof) / dof
    ratio = Ps / np.where(floor > 0, floor, np.inf)
    peaks, _ = scipy.signal.find_peaks(ratio)
    lines = [{"f_hz": float(f[i]), "ratio": float(ratio[i]), "threshold": float(thr)}
             for i in peaks if ratio[i] > max(thr, min_ratio) and f[i] > 0]
    return sorted(lines, key=lambda d: -d["ratio"])


def allan(x: np.ndarray, fs: float) -> dict[str, np.ndarray | float]:
    """Overlapping Allan deviation of rate samples ``x`` (N,) at octave τ.

    Returns
    -------
    dict
        ``tau_s``, ``adev`` and ``adev_sd`` (allantools' error bars), ``n_at_1s``
        (σ(τ = 1 s) by log-log interpolation: the angle random walk N in unit/√Hz,
        i.e. unit·√s), ``min`` and ``tau_min_s`` (the curve's minimum).
    """
    import allantools

    taus, ad, ade, _ = allantools.oadev(np.asarray(x, float), rate=fs, data_type="freq",
                                        taus="octave")
    n1 = float(np.exp(np.interp(0.0, np.log(taus), np.log(ad))))
    j = int(np.argmin(ad))
    return {"tau_s": taus, "adev": ad, "adev_sd": ade, "n_at_1s": n1,
            "min": float(ad[j]), "min_sd": float(ade[j]), "tau_min_s": float(taus[j])}


def excess_kurtosis(x: np.ndarray, blocks: int = 10) -> Estimate:
    """Excess kurtosis per column (0 for Gaussian), σ from blocks."""
    return block_estimate(lambda p: scipy.stats.kurtosis(p, axis=0), x, blocks)


def noise_from_pairs(x: np.ndarray) -> np.ndarray:
    """Noise variance of each of m ≥ 3 sensors from their pairwise differences.

    Parameters
    ----------
    x : ndarray, shape (N, m)
        Simultaneous outputs of m sensors that see the same input (static, or aligned).

    Returns
    -------
    ndarray, shape (m,)
        σ_i² solving var(x_i − x_j) = σ_i² + σ_j² over all pairs by least squares
        (independent noises assumed; a common-mode noise cancels in every difference and
        is not seen).
    """
    m = x.shape[1]
    if m < 3:
        raise ConfigError(f"need three or more sensors, got {m}")
    rows, rhs = [], []
    for i, j in combinations(range(m), 2):
        r = np.zeros(m)
        r[[i, j]] = 1.0
        rows.append(r)
        rhs.append(np.var(x[:, i] - x[:, j]))
    sol, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
    return sol


def common_mode(x: np.ndarray) -> dict[str, np.ndarray | float]:
    """Components shared by several sensors, from the correlation matrix of ``x`` (N, m).

    For independent noises the eigenvalues of the sample correlation matrix stay below
    the Marchenko-Pastur edge (1 + √(m/N))²; an eigenvalue above it is a signal that
    several sensors see together (motion, or a common disturbance).

    Returns
    -------
    dict
        ``eigenvalues`` (descending), ``edge`` (the bound), ``n_common`` (how many exceed
        it), ``vectors`` (columns, descending), ``parity`` (the data projected on the
        remaining directions, standardised units).
    """
    z = (x - x.mean(axis=0)) / x.std(axis=0)
    n, m = z.shape
    ev, V = np.linalg.eigh(np.corrcoef(z.T))
    ev, V = ev[::-1], V[:, ::-1]
    edge = (1 + np.sqrt(m / n)) ** 2
    k = int(np.sum(ev > edge))
    return {"eigenvalues": ev, "edge": float(edge), "n_common": k, "vectors": V,
            "parity": z @ V[:, k:]}


def _longest_run(t: np.ndarray, max_gap: float) -> np.ndarray:
    cut = np.flatnonzero(np.diff(t) > max_gap) + 1
    runs = np.split(np.arange(t.shape[0]), cut)
    return max(runs, key=len)


def pair_report(t: np.ndarray, ref: np.ndarray, other: np.ndarray, *, blocks: int = 10
                ) -> dict:
    """Residual between two three-axis IMUs in motion: lag, alignment, what is left.

    Steps: the lag τ of ``other`` behind ``ref`` (:func:`time_offset`); ``ref`` moved
    onto ``other``'s timing (ω_ref − τ·ω̇, ω̇ of the mean of the two); the least-squares
    map of ``other`` onto it (:func:`fit_alignment`, rotation and scale with block σ);
    then the residual's RMS
    after each step, heavy tails and spectral lines (on the longest gap-free run). All
    rates rad/s, times s. The scales carry the errors-in-variables attenuation of a noisy
    regressor (vibration seen by ``other`` alone pulls them below 1).
    """
    fs = 1.0 / float(np.median(np.diff(t)))
    tau, _ = time_offset(ref, other, t, blocks=blocks)
    wd = rate_derivative(0.5 * (ref + other), t)       # as time_offset: less noisy
    ok = np.isfinite(wd).all(axis=1)
    ref_s = ref[ok] - tau.value * wd[ok]
    oth = other[ok]
    al = fit_alignment(ref_s, oth)
    idx = np.arange(ref_s.shape[0])
    ang = block_estimate(lambda i: fit_alignment(ref_s[i.astype(int)],
                                                 oth[i.astype(int)]).angle_deg, idx, blocks)
    scales = block_estimate(lambda i: fit_alignment(ref_s[i.astype(int)],
                                                    oth[i.astype(int)]).scales, idx, blocks)
    res = al.residual
    tt = t[ok]
    run = _longest_run(tt, 2.5 / fs)

    def rms(x: np.ndarray) -> list[float]:
        return np.sqrt(np.mean(x**2, axis=0)).tolist()

    return {
        "samples": int(t.shape[0]), "sample_rate_hz": fs,
        "time_offset_s": tau.to_dict(),
        "rotation_deg": {"value": al.angle_deg, "sd": float(ang.sd), "blocks": blocks},
        "scales": {"value": al.scales.tolist(), "sd": np.asarray(scales.sd).tolist(),
                   "blocks": blocks},
        "bias_rps": al.b.tolist(),
        "rms_raw_rps": rms(ref[ok] - oth),
        "rms_lag_rps": rms(ref_s - oth),
        "rms_lag_aligned_rps": rms(res),
        "excess_kurtosis": excess_kurtosis(res, blocks).to_dict(),
        "lines": spectral_lines(res[run], fs)[:8],
        "longest_run_s": float(run.shape[0] / fs),
        "residual": res,
    }


def static_report(x: np.ndarray, fs: float, *, band: tuple[float, float],
                  blocks: int = 10) -> dict:
    """Noise of a resting three-axis gyro ``x`` (N, 3), rad/s: level, density, Allan,
    tails, lines."""
    xs = x - x.mean(axis=0)
    al = [allan(xs[:, k], fs) for k in range(x.shape[1])]
    return {
        "samples": int(x.shape[0]), "sample_rate_hz": fs,
        "mean_rps": x.mean(axis=0).tolist(),
        "std_rps": block_estimate(lambda p: p.std(axis=0), xs, blocks).to_dict(),
        "density_rps_rthz": noise_density(xs, fs, band, blocks=blocks,
                                          nperseg=1024).to_dict(),
        "band_hz": list(band),
        "allan_n_at_1s_rps_rthz": [a["n_at_1s"] for a in al],
        "allan_min_rps": [a["min"] for a in al],
        "allan_min_sd_rps": [a["min_sd"] for a in al],
        "allan_tau_min_s": [a["tau_min_s"] for a in al],
        "excess_kurtosis": excess_kurtosis(xs, blocks).to_dict(),
        "lines": spectral_lines(xs, fs, nperseg=1024)[:8],
        "allan": al,
    }
