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
instability)
makes this conservative; a drift that accelerates beyond τ_L (a rate ramp) is not
covered by the data and is not claimed. The offset is treated as an isotropic Gaussian
offset of variance δ² per whitened direction, as the bias uncertainty β is
(:mod:`fdi.reconstruction`): the whole measured excess is put on every direction, which is
right for a drift along one direction (the scaled χ²(df) threshold then over-covers its
χ²(1) law) and conservative for one spread over several. The window's variance factor becomes
(:func:`drift_variance_factors`)::

    f'_w = f_w + w · δ²(h)

so a w-sample window's threshold covers white noise, the tail and the expected drift, and
the detectable size ``rimu tune`` states grows with ``sqrt(f'_w / f_w)``: a fault that
looks like a drift slower and smaller than δ is given up, and the stated size says so.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

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


def drift_variance_factors(model: DriftModel | None, scales: tuple[int, ...],
                           factors: tuple[float, ...], horizon_s: float | None = None
                           ) -> tuple[float, ...]:
    """``f_w + w·δ²(h)`` per scale (module docstring); ``factors`` unchanged without a model.

    Parameters
    ----------
    model : DriftModel or None
    scales : tuple of int
        Window lengths w (samples).
    factors : tuple of float
        The variance factors without drift (Allan, tail overbound).
    horizon_s : float, optional
        See :meth:`DriftModel.offset_variance`.
    """
    if model is None:
        return tuple(float(f) for f in factors)
    d2 = model.offset_variance(horizon_s)
    return tuple(float(f) + int(w) * d2 for w, f in zip(scales, factors, strict=True))
