"""Slow bias drift of the whitened parity, and the variance it adds to a window's mean.

A calibration states each sensor's bias as it was while the calibration data were taken.
Later the biases wander (MEMS gyros warm up and drift), so the parity of a healthy set
carries a slowly changing offset d(t) that no window averages down: a w-sample window sum
of the whitened parity z holds ``w·d`` on top of its noise. The monitor's variance factor
f_w (:mod:`fdi.detector`) describes the noise inside a window (Allan factor, tail
overbound); the offset grows with the time since calibration and is not in it.

The calibration measures the drift from its own residual (:mod:`calibration.drift`):
the Allan covariance of z at dyadic τ, ``C_A(τ) = ½·E[Δz̄_τ Δz̄_τᵀ]`` of adjacent
non-overlapping τ-means, and its excess over white noise summed over the parity
directions, ``e(τ) = tr C_A(τ) − df/(τ·fs)`` (z is white with unit covariance per sample by
construction of the whitening; an excess counts where it is significant,
:mod:`calibration.drift`). It keeps e(τ) for every τ with at least
:data:`MIN_BLOCKS` blocks (:class:`DriftModel`).

What the thresholds assume (:meth:`DriftModel.offset_variance`): the calibration stated
the mean over its span T_c; the monitor is meant to run on it for a *horizon* h after the
calibration data end (default h = T_c: the data speak for about as long as they last).
Beyond the longest resolved τ_L the drift is taken as a random walk (the rate random walk
term of the IEEE Std 952 gyro model: Allan variance ∝ τ), for which the offset at the end
of the horizon from the calibration's mean has variance ``K²(h + T_c/3) = 2·σ_A²(τ_h)``
with ``τ_h = 1.5·h + T_c/2``. So, per whitened direction, at most::

    δ²(h) = 2 · max( e(τ_L) · τ_h / τ_L,  max_{τ ≥ τ_L/4} e(τ) )

(never below what the long end, τ ≥ τ_L/4, measured). A drift that flattens out (bias
instability) makes this conservative; a drift that accelerates beyond τ_L (a rate ramp) is
not covered by the data and is not claimed.

How the thresholds cover it (:func:`drift_variance_factors` with the scales' α): at time t
after the calibration data ended the offset is a Gaussian of total variance δ²(t) over the
whitened directions; its shape is not known, so both extremes are covered. A w-sample
window statistic in units of its noise variance f_w is ``χ²(df−1) + c·χ²(1)`` when the
offset lies along one direction and ``(1 + (c−1)/df)·χ²(df)`` when it spreads evenly,
``c = 1 + w·δ²(t)/f_w`` (the upper tail of a weighted sum of χ²(1) with a given total
weight lies between the two; the one-direction shape is the heavier at small α). A
false-alarm rate per hour of the horizon is the time average of the rate at each t (the
expected count over the horizon over its length), so each shape's level is the q whose
exceedance probability, averaged over t ∈ [0, h] (8 Gauss–Legendre nodes), is α; the
window's variance factor becomes

    f'_w = f_w · max(q_one, q_spread) / χ²(df).isf(α_w)

so its threshold covers white noise, the tail and the expected drift, and the detectable
size ``rimu tune`` states grows with ``sqrt(f'_w / f_w)``: a fault that looks like a drift
slower and smaller than δ is given up, and the stated size says so. Without α the function
gives the bare rule ``f_w + w·δ²(h)``, the end-of-horizon offset put on every direction: an
upper bound of f'_w (the tests compare the two); ``tune`` and the default thresholds always
pass α.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from fdi.fileio import Fields

__all__ = ["DRIFT_METHOD", "MIN_BLOCKS", "DriftModel", "drift_model_from_fields",
           "drift_variance_factors"]

DRIFT_METHOD = "rimu.drift/1"
"""Version of the drift record inside a calibration file."""
MIN_BLOCKS = 8
"""Fewest non-overlapping τ-blocks (7 differences) for a τ to count as resolved."""
HORIZON_SLOPE = 1.5
"""τ_h = HORIZON_SLOPE·h + T_c/2: the τ whose random-walk Allan variance, doubled, is the
offset variance at the end of the horizon h (module docstring)."""


@dataclass(frozen=True)
class DriftModel:
    """Excess Allan variance of the whitened parity of one sensor set (kept in the calibration).

    Attributes
    ----------
    df : int
        Parity dimension of the full set.
    samples : int
        Residual samples used.
    sample_rate_hz : float
    span_s : float
        T_c, the time the residual spans (s).
    tau_s : tuple of float
        Resolved τ (s), increasing (each with at least :data:`MIN_BLOCKS` blocks).
    blocks : tuple of int
        Non-overlapping blocks at each τ.
    excess : tuple of float
        e(τ) = tr C_A(τ) − (white part), ≥ 0, in whitened per-sample variance units
        (1 = the white noise of one sample).
    source : str
        What residual was measured.
    method : str
        :data:`DRIFT_METHOD`.
    """

    df: int
    samples: int
    sample_rate_hz: float
    span_s: float
    tau_s: tuple[float, ...]
    blocks: tuple[int, ...]
    excess: tuple[float, ...]
    source: str = ""
    method: str = DRIFT_METHOD

    def horizon_tau_s(self, horizon_s: float | None = None) -> float:
        """τ_h = 1.5·h + T_c/2 (s); ``horizon_s`` None: h = T_c."""
        h = self.span_s if horizon_s is None else float(horizon_s)
        return HORIZON_SLOPE * h + 0.5 * self.span_s

    def offset_variance(self, horizon_s: float | None = None) -> float:
        """δ²(h): variance per whitened direction of the parity offset at the end of the
        horizon (module docstring); 0 for a horizon of 0 s and no measured excess.

        Parameters
        ----------
        horizon_s : float, optional
            Time after the calibration data end for which the thresholds must hold (s,
            ≥ 0); default the calibration's span T_c.
        """
        if not self.tau_s:
            return 0.0
        tau_l, e_l = self.tau_s[-1], self.excess[-1]
        rw = e_l * max(1.0, self.horizon_tau_s(horizon_s) / tau_l)
        floor = max(e for t, e in zip(self.tau_s, self.excess, strict=True)
                    if t >= tau_l / 4.0)
        return 2.0 * max(rw, floor)

    def offset_variances(self, horizon_s: float | None = None
                         ) -> tuple[np.ndarray, np.ndarray]:
        """δ²(t) over the horizon: at 8 Gauss–Legendre nodes t_j of [0, h] with weights
        summing to 1 (a horizon of 0 s: the one value δ²(0)).

        A false-alarm rate per hour of the horizon is the time average of the rate at each
        t, whose offset variance is δ²(t) (:meth:`offset_variance` of a horizon t).
        """
        h = self.span_s if horizon_s is None else float(horizon_s)
        if h <= 0.0:
            return np.array([self.offset_variance(0.0)]), np.ones(1)
        t = 0.5 * h * (_T_NODES + 1.0)
        return np.array([self.offset_variance(float(x)) for x in t]), 0.5 * _T_WEIGHTS

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready ``rimu.drift/1`` record."""
        return {"method": self.method, "df": self.df, "samples": self.samples,
                "sample_rate_hz": self.sample_rate_hz, "span_s": self.span_s,
                "tau_s": list(self.tau_s), "blocks": list(self.blocks),
                "excess": list(self.excess), "source": self.source,
                "unit": "whitened parity variance per sample (1 = white noise of one sample)"}


def drift_model_from_fields(r: Fields) -> DriftModel:
    """Build a :class:`DriftModel` from its JSON object (errors name the field).

    Raises
    ------
    FileFormatError
        A missing or malformed field, τ not increasing, a negative excess, fewer blocks
        than :data:`MIN_BLOCKS`, lists of different lengths.
    """
    method = r.string("method")
    if method != DRIFT_METHOD:
        raise r.error("method", f"expected {DRIFT_METHOD!r}, got {method!r}")
    r.string("unit", "", nonempty=False)
    df = r.integer("df", lo=1)
    samples = r.integer("samples", lo=1)
    fs = r.number("sample_rate_hz", positive=True)
    span = r.number("span_s", positive=True)
    tau = r.numbers("tau_s", positive=True)
    k = len(tau)
    if any(b <= a for a, b in itertools.pairwise(tau)):
        raise r.error("tau_s", f"expected increasing tau, got {list(tau)}")
    excess = r.numbers("excess", length=k)
    if any(e < 0 for e in excess):
        raise r.error("excess", "expected excess variances >= 0")
    bv = r.get("blocks")
    if not isinstance(bv, list) or len(bv) != k or any(
            isinstance(b, bool) or not isinstance(b, int) or b < MIN_BLOCKS for b in bv):
        raise r.error("blocks", f"expected {k} integers >= {MIN_BLOCKS}")
    source = r.string("source", "", nonempty=False)
    r.finish()
    return DriftModel(df=df, samples=samples, sample_rate_hz=fs, span_s=span,
                      tau_s=tuple(tau), blocks=tuple(int(b) for b in bv),
                      excess=tuple(float(e) for e in excess), source=source)


_S_NODES, _S_WEIGHTS = np.polynomial.legendre.leggauss(96)
_T_NODES, _T_WEIGHTS = np.polynomial.legendre.leggauss(8)


def _sf_one_direction(q: float, df: int, c: np.ndarray) -> np.ndarray:
    """``P(χ²(df−1) + c·χ²(1) > q)`` per c: the window statistic (in units of its noise
    variance) when the whole offset variance lies along one whitened direction.

    With Y = s², ``P = P(cY > q) + ∫_0^{s0} √(2/π)·e^{−s²/2}·P(χ²(df−1) > q − c·s²) ds``,
    s0 = √(q/c), by 96-point Gauss–Legendre in s.
    """
    from scipy import special  # not at import: loading a calibration stays scipy-free

    c = np.asarray(c, float)[:, None]
    tail = special.chdtrc(1, q / c[:, 0])
    if df <= 1:
        return tail
    s0 = np.sqrt(q / c)
    s = 0.5 * s0 * (_S_NODES + 1.0)
    inner = np.sqrt(2.0 / np.pi) * np.exp(-0.5 * s * s) * special.chdtrc(df - 1, q - c * s * s)
    return tail + 0.5 * s0[:, 0] * (inner @ _S_WEIGHTS)


def _level(sf, alpha: float, lo: float, hi: float) -> float:
    """The q in [lo, hi] with ``sf(q) = alpha`` (sf decreasing; brentq on the log)."""
    from scipy import optimize

    la = math.log(alpha)
    g = lambda q: math.log(max(float(sf(q)), 1e-300)) - la   # noqa: E731
    if g(lo) <= 0.0:
        return lo
    hi = max(hi, lo) * (1.0 + 1e-9)
    while g(hi) > 0.0:                  # rounding at the bracket's bound: widen it
        hi *= 1.5
    return float(optimize.brentq(g, lo, hi, xtol=1e-12 * hi, rtol=1e-10))


def offset_levels(alpha: float, df: int, d2: np.ndarray, weights: np.ndarray
                  ) -> tuple[float, float]:
    """Levels exceeded with probability α on average over the horizon by a window statistic
    with an offset, for the two extreme shapes of the offset (module docstring): along one
    direction and spread evenly.

    Parameters
    ----------
    alpha : float
        Exceedance probability per sample.
    df : int
        Parity dimension.
    d2 : ndarray, shape (m,)
        ``w·δ²(t_j)/f_w`` at the horizon's quadrature nodes t_j: the offset's total variance
        over the whitened directions in units of the window's noise variance.
    weights : ndarray, shape (m,)
        Quadrature weights over the horizon, summing to 1.

    Returns
    -------
    one, spread : float
        Levels on the window statistic in units of its noise variance (χ²(df) without
        drift: both equal ``χ²(df).isf(α)``).
    """
    from scipy import special, stats

    c = 1.0 + np.maximum(np.asarray(d2, float).reshape(-1), 0.0)
    wts = np.asarray(weights, float).reshape(-1)
    base = float(stats.chi2.isf(alpha, df))
    hi = (float(stats.chi2.isf(alpha / 2.0, max(df - 1, 1))) * (df > 1)
          + float(c.max()) * float(stats.chi2.isf(alpha / 2.0, 1)))
    one = _level(lambda q: float(_sf_one_direction(q, df, c) @ wts), alpha, base,
                 max(hi, base))
    cs = 1.0 + (c - 1.0) / df
    spread = _level(lambda q: float(special.chdtrc(df, q / cs) @ wts), alpha, base,
                    base * float(cs.max()))
    return one, spread


def drift_variance_factors(model: DriftModel | None, scales: tuple[int, ...],
                           factors: tuple[float, ...], horizon_s: float | None = None,
                           alpha: tuple[float, ...] | None = None) -> tuple[float, ...]:
    """Variance factors that cover the drift over the horizon (module docstring); ``factors``
    unchanged without a model.

    With the per-scale false-alarm probabilities (what ``tune`` and the default thresholds
    pass): the factor whose scaled χ²(df) level at α_w is the larger of the α_w-levels,
    averaged over the horizon (:meth:`DriftModel.offset_variances`), of the two extreme
    shapes of an offset of total variance δ²(t) (``c = 1 + w·δ²(t)/f_w``): along one
    direction, ``χ²(df−1) + c·χ²(1)``; spread evenly, ``(1 + (c−1)/df)·χ²(df)``. Without
    ``alpha``: the bare upper bound ``f_w + w·δ²(h)``, the end-of-horizon offset put on
    every direction.

    Parameters
    ----------
    model : DriftModel or None
    scales : tuple of int
        Window lengths w (samples).
    factors : tuple of float
        The variance factors without drift (Allan, tail overbound).
    horizon_s : float, optional
        See :meth:`DriftModel.offset_variance`.
    alpha : tuple of float, optional
        Per-scale exceedance probability of the thresholds the factors go with.
    """
    if model is None:
        return tuple(float(f) for f in factors)
    if alpha is None:
        d2 = model.offset_variance(horizon_s)
        return tuple(float(f) + int(w) * d2 for w, f in zip(scales, factors, strict=True))
    from scipy import stats

    d2_t, wts = model.offset_variances(horizon_s)
    out = []
    for w, f, a in zip(scales, factors, alpha, strict=True):
        f = float(f)
        one, spread = offset_levels(float(a), int(model.df), int(w) * d2_t / f, wts)
        out.append(f * max(one, spread) / float(stats.chi2.isf(float(a), int(model.df))))
    return tuple(out)
