"""Residual tail model per window scale, and the variance factors the monitor takes from it.

The monitor tests, per dyadic window of w samples, ``D_w = w/f_w · p̄ᵀ(VΣVᵀ)⁻¹p̄`` against
χ²(df) (:mod:`fdi.detector`). On measured residuals the law of ``S_w = w·p̄ᵀ(VΣVᵀ)⁻¹p̄``
(the statistic with ``f_w = 1``) has heavier tails than χ²(df): impacts, vibration bursts.
A calibration that measured its residual keeps, per scale, the upper tail of ``S_w`` as a
curve of per-sample exceedance probabilities p_j and quantiles q_j with a one-sided upper
confidence bound (:class:`ScaleTail`): empirical where the data resolve it, a generalised
Pareto (peaks-over-threshold) extrapolation below (:class:`GpdFit`). The fitting is in
:mod:`calibration.tails`; this module holds the typed record, its file form and the
arithmetic the runtime needs.

Overbound (in the spirit of DeCleene's CDF overbounding, as ARAIM uses it): the factor
``f_w(α)`` is the smallest variance inflation such that χ²(df) of ``S_w/f_w`` is at least
the measured upper bound of the tail at every probability from α up to the largest
tabulated one::

    f_w(α) = max_{p ∈ [α, p_0]} q⁺_w(p) / χ²_df.isf(p)

with ``q⁺`` interpolated log-log between tabulated points (and extended with the slope of
the last two below the smallest, stated in :func:`overbound_factor`). The monitor's
variance factor is ``max(Allan factor, f_w(α_w))`` where the scale failed its normality
check, the Allan factor alone where it passed (:func:`tail_variance_factors`).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from fdi.fileio import Fields

__all__ = [
    "TAIL_CHOICES",
    "TAIL_METHOD",
    "TAIL_SOURCES",
    "TAIL_UNIT",
    "GpdFit",
    "ScaleTail",
    "TailChoice",
    "TailModel",
    "measured_variance_factor",
    "overbound_factor",
    "tail_model_from_fields",
    "tail_variance_factors",
]

TAIL_UNIT = "dimensionless: S_w = w * mean parity' (V S V')^-1 mean parity (chi-square units)"
"""Unit of the tabulated quantiles."""
TAIL_METHOD = "rimu.tails/1"
"""Version of the tail record inside a calibration file."""
TAIL_SOURCES = ("empirical", "gpd", "carried")
"""Where a tabulated quantile comes from: the data, the GPD extrapolation, or a shorter
scale's curve carried over (the scale had too few independent windows)."""
TAIL_CHOICES = ("gaussian-white", "overbound", "allan", "measured-variance")
"""What a scale's variance factor rests on (see :class:`TailChoice`)."""


@dataclass(frozen=True)
class GpdFit:
    """Peaks-over-threshold fit of one scale's ``S_w`` (``scipy.stats.genpareto``).

    ``P(S_w > x) ≈ ζ_u · (1 + ξ (x − u)/σ)^(−1/ξ)`` for x > u.

    Attributes
    ----------
    threshold : float
        u (χ² units).
    exceedance_probability : float
        ζ_u, the per-sample probability of exceeding u (point estimate).
    exceedance_probability_upper : float
        Its one-sided upper confidence bound (Clopper–Pearson on the independent windows).
    exceedances : int
        Window statistics above u.
    clusters : int
        Declustered exceedances (runs closer than w samples merged): the effective count.
    shape : float
        ξ (maximum likelihood).
    shape_sd : float
        Standard error of ξ (observed information, scaled by exceedances/clusters).
    shape_upper : float
        Upper confidence bound of ξ (profile likelihood, dependence-adjusted).
    scale_param : float
        σ (χ² units).
    """

    threshold: float
    exceedance_probability: float
    exceedance_probability_upper: float
    exceedances: int
    clusters: int
    shape: float
    shape_sd: float
    shape_upper: float
    scale_param: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"threshold": self.threshold,
                "exceedance_probability": self.exceedance_probability,
                "exceedance_probability_upper": self.exceedance_probability_upper,
                "exceedances": self.exceedances, "clusters": self.clusters,
                "shape": self.shape, "shape_sd": self.shape_sd,
                "shape_upper": self.shape_upper, "scale_param": self.scale_param}


@dataclass(frozen=True)
class ScaleTail:
    """The measured tail of ``S_w`` at one window scale.

    Attributes
    ----------
    scale : int
        w (samples).
    windows : int
        Window statistics used (overlapping running means, inside valid runs).
    independent : int
        Non-overlapping windows (the effective sample size of the confidence bounds).
    variance_ratio : float
        mean(S_w)/df: the variance of the window mean relative to white noise, measured.
    excess_kurtosis : float
        Of the whitened window-mean components (non-overlapping windows); 0 for Gaussian.
    kurtosis_p : float
        One-sided p-value of the kurtosis test (heavier than Gaussian).
    exceedance_p : float
        One-sided binomial p-value of the count beyond the χ² 1 % point of
        ``S_w / variance_ratio`` (non-overlapping windows).
    gaussian : bool
        Passes both tests at the model's level (or inherits the verdict, see ``notes``).
    probability : tuple of float
        Per-sample exceedance probabilities p_j, decreasing.
    quantile : tuple of float
        Point estimate of the (1 − p_j) quantile of S_w (χ² units); NaN where only a bound
        is known.
    quantile_upper : tuple of float
        One-sided upper confidence bound of that quantile.
    source : tuple of str
        Per point, one of :data:`TAIL_SOURCES`.
    gpd : GpdFit or None
        The extrapolation's fit (None: too few clusters, see ``notes``).
    notes : str
    """

    scale: int
    windows: int
    independent: int
    variance_ratio: float
    excess_kurtosis: float
    kurtosis_p: float
    exceedance_p: float
    gaussian: bool
    probability: tuple[float, ...]
    quantile: tuple[float, ...]
    quantile_upper: tuple[float, ...]
    source: tuple[str, ...]
    gpd: GpdFit | None = None
    notes: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (NaN as null)."""
        return {"scale": self.scale, "windows": self.windows, "independent": self.independent,
                "variance_ratio": self.variance_ratio,
                "excess_kurtosis": _num(self.excess_kurtosis),
                "kurtosis_p": _num(self.kurtosis_p), "exceedance_p": _num(self.exceedance_p),
                "gaussian": self.gaussian, "probability": list(self.probability),
                "quantile": [_num(q) for q in self.quantile],
                "quantile_upper": list(self.quantile_upper), "source": list(self.source),
                "gpd": None if self.gpd is None else self.gpd.to_dict(), "notes": self.notes}


@dataclass(frozen=True)
class TailModel:
    """Residual tail model of one sensor set, per window scale (kept in the calibration).

    Attributes
    ----------
    df : int
        Parity dimension of the full set the statistic was computed for.
    samples : int
        Residual samples used (valid, whitened parity).
    sample_rate_hz : float
    confidence : float
        One-sided confidence of every upper bound (0.95).
    level : float
        Family-wise significance level of the normality check (every scale, kurtosis and
        tail tests, Bonferroni).
    scales : tuple of ScaleTail
        Increasing window lengths.
    source : str
        What residual was measured (``"in-flight alignment residual"``, ``"turntable
        rate-test residual"``).
    method : str
        :data:`TAIL_METHOD`.
    unit : str
        :data:`TAIL_UNIT`.
    """

    df: int
    samples: int
    sample_rate_hz: float
    confidence: float
    level: float
    scales: tuple[ScaleTail, ...]
    source: str = ""
    method: str = TAIL_METHOD
    unit: str = TAIL_UNIT

    def scale(self, w: int) -> ScaleTail | None:
        """The record of window length ``w`` (None when not tabulated)."""
        for s in self.scales:
            if s.scale == int(w):
                return s
        return None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"method": self.method, "unit": self.unit, "df": self.df,
                "samples": self.samples, "sample_rate_hz": self.sample_rate_hz,
                "confidence": self.confidence, "level": self.level, "source": self.source,
                "scales": [s.to_dict() for s in self.scales]}


@dataclass(frozen=True)
class TailChoice:
    """What one scale's variance factor rests on (``rimu tune`` prints it).

    Attributes
    ----------
    scale : int
    choice : str
        ``"gaussian-white"`` (no tail model, or the scale passes its normality check),
        ``"overbound"`` (fails it; the overbound factor is the largest), ``"allan"`` (fails
        it, but the Allan factor already covers the overbound) or ``"measured-variance"``
        (the measured variance of the window mean is significantly above the Allan factor,
        e.g. a slow offset the Allan variance differences away, and its upper bound is the
        largest candidate).
    allan_factor, overbound_factor, factor : float
        Two candidates and the one used.
    variance_factor_upper : float
        The measured variance ratio's upper bound where it is significantly above the Allan
        factor (the third candidate), NaN otherwise.
    excess_kurtosis, shape, shape_sd : float
        From the record (NaN when absent).
    """

    scale: int
    choice: str
    allan_factor: float
    overbound_factor: float
    factor: float
    excess_kurtosis: float = float("nan")
    shape: float = float("nan")
    shape_sd: float = float("nan")
    variance_factor_upper: float = float("nan")

    def text(self) -> str:
        """One line: ``scale 8: overbound f=3.2 (kurtosis 41, GPD ξ=0.30±0.10)``."""
        if self.choice == "measured-variance":
            return (f"scale {self.scale}: measured variance f={self.factor:.3g} (window-mean "
                    f"variance significantly above the Allan f={self.allan_factor:.3g}; "
                    f"kurtosis {self.excess_kurtosis:.3g}"
                    + (f", overbound f={self.overbound_factor:.3g})"
                       if math.isfinite(self.overbound_factor) else ")"))
        if self.choice == "gaussian-white":
            why = ("passes" if math.isfinite(self.excess_kurtosis)
                   else "no tail model in the calibration")
            return (f"scale {self.scale}: gaussian white: {why} (Allan f={self.allan_factor:.3g}"
                    + (f", kurtosis {self.excess_kurtosis:.3g})" if math.isfinite(
                        self.excess_kurtosis) else ")"))
        gpd = (f", GPD xi={self.shape:.2f}+-{self.shape_sd:.2f}" if math.isfinite(self.shape)
               else ", no GPD fit")
        return (f"scale {self.scale}: {self.choice} f={self.factor:.3g} (kurtosis "
                f"{self.excess_kurtosis:.3g}{gpd}; Allan f={self.allan_factor:.3g}, overbound "
                f"f={self.overbound_factor:.3g})")


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _curve(tail: ScaleTail) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(tail.probability, float)
    q = np.asarray(tail.quantile_upper, float)
    o = np.argsort(p)[::-1]
    return p[o], q[o]


def _interp_upper(lp: np.ndarray, lq: np.ndarray, la: float) -> float:
    """log q⁺ at log-probability ``la`` (lp decreasing); beyond the smallest tabulated p
    the slope of the last two points continues (never decreasing)."""
    if la >= lp[0]:
        return float(lq[0])
    if la >= lp[-1]:
        return float(np.interp(-la, -lp, lq))
    if lp.size < 2:
        return float(lq[-1])
    slope = (lq[-1] - lq[-2]) / (lp[-1] - lp[-2]) if lp[-1] != lp[-2] else 0.0
    return float(lq[-1] + min(slope, 0.0) * (la - lp[-1]))


def overbound_factor(tail: ScaleTail, alpha: float, df: int) -> float:
    """``f_w(α) = max_{p ∈ [α, p_0]} q⁺(p)/χ²_df.isf(p)`` (module docstring).

    Tabulated points with p ≥ α count as they are; the bound at α itself is interpolated
    log-log (beyond the smallest tabulated p, the last slope continues: stated, not
    measured). Never raises; returns 1 for an empty record, inf for df < 1 with data.

    Parameters
    ----------
    tail : ScaleTail
    alpha : float
        Per-sample exceedance probability of the scale's threshold.
    df : int
        Parity dimension of the statistic.
    """
    from scipy import stats  # here: loading a calibration needs no scipy

    p, q = _curve(tail)
    ok = (p > 0) & (p < 1) & np.isfinite(q) & (q > 0)
    p, q = p[ok], q[ok]
    if p.size == 0 or not (0.0 < alpha < 1.0):
        return 1.0
    if df < 1:
        return math.inf
    ratios = [qq / float(stats.chi2.isf(pp, df)) for pp, qq in zip(p, q, strict=True)
              if pp >= alpha]
    la = math.log(alpha)
    qa = math.exp(_interp_upper(np.log(p), np.log(q), la))
    ratios.append(qa / float(stats.chi2.isf(alpha, df)))
    f = max(ratios)
    return float(f) if math.isfinite(f) else math.inf


def tail_variance_factors(model: TailModel | None, scales: tuple[int, ...],
                          alphas: tuple[float, ...], allan_factors: tuple[float, ...]
                          ) -> tuple[tuple[float, ...], tuple[TailChoice, ...]]:
    """Variance factor per scale from the Allan factors and the tail model.

    ``f_w = max(Allan f_w, overbound f_w(α_w))`` where the scale's residual failed its
    normality check, the Allan factor where it passed or no model is kept. A window length
    the model does not tabulate takes the record of the longest tabulated one below it
    (the first when none is below).

    Parameters
    ----------
    model : TailModel or None
    scales : tuple of int
        Window lengths (samples).
    alphas : tuple of float
        Per-sample exceedance probability of each scale's threshold.
    allan_factors : tuple of float
        The Allan-variance factors (:func:`fdi.detector.variance_factors`).

    Returns
    -------
    factors : tuple of float
    choices : tuple of TailChoice
    """
    out, why = [], []
    n_scales = max(len(scales), 1)
    for w, a, fa in zip(scales, alphas, allan_factors, strict=True):
        rec = None if model is None else _record_for(model, int(w))
        if rec is None:
            out.append(float(fa))
            why.append(TailChoice(int(w), "gaussian-white", float(fa), float("nan"), float(fa)))
            continue
        g = rec.gpd
        xi = g.shape if g is not None else float("nan")
        xsd = g.shape_sd if g is not None else float("nan")
        fv = measured_variance_factor(rec, float(fa), model.df, model.confidence,
                                      model.level / n_scales)
        fo = float("nan") if rec.gaussian else overbound_factor(rec, float(a), model.df)
        cands = {"allan": float(fa)}
        if math.isfinite(fv):
            cands["measured-variance"] = fv
        if not rec.gaussian:
            cands["overbound"] = fo if not math.isnan(fo) else math.inf
        choice = max(cands, key=lambda k: cands[k])
        f = cands[choice]
        if choice == "allan":
            choice = "gaussian-white" if rec.gaussian else "allan"
        f = f if math.isfinite(f) else 1e300
        out.append(f)
        why.append(TailChoice(int(w), choice, float(fa), fo, f, rec.excess_kurtosis, xi, xsd,
                              fv))
    return tuple(out), tuple(why)


def measured_variance_factor(rec: ScaleTail, allan_factor: float, df: int, confidence: float,
                             level: float) -> float:
    """Upper bound of the measured variance ratio where it is significantly above Allan's.

    ``mean(S_w)/df`` over ``ν = independent·df`` degrees of freedom; significant when
    ``χ²_ν.sf(ν·ratio/f_Allan) < level``; the bound is ``ratio·ν/χ²_ν.ppf(1 − c)``. NaN
    when not significant or not measured.
    """
    from scipy import stats  # here: loading a calibration needs no scipy

    nu = rec.independent * df
    vr = rec.variance_ratio
    if nu < 1 or not (vr > 0 and math.isfinite(vr)) or not allan_factor > 0:
        return float("nan")
    if not float(stats.chi2.sf(nu * vr / allan_factor, nu)) < level:
        return float("nan")
    return float(vr * nu / stats.chi2.ppf(1.0 - confidence, nu))


def _record_for(model: TailModel, w: int) -> ScaleTail | None:
    if not model.scales:
        return None
    rec = model.scale(w)
    if rec is not None:
        return rec
    below = [s for s in model.scales if s.scale <= w]
    return max(below, key=lambda s: s.scale) if below else model.scales[0]


# -- reading ---------------------------------------------------------------------------
def tail_model_from_fields(r: Fields) -> TailModel:
    """Build a :class:`TailModel` from its JSON object (errors name the field).

    Raises
    ------
    FileFormatError
        A missing or malformed field, probabilities not in (0, 1) or not decreasing,
        quantile bounds not positive, scales not increasing.
    """
    method = r.string("method")
    if method != TAIL_METHOD:
        raise r.error("method", f"expected {TAIL_METHOD!r}, got {method!r}")
    r.string("unit")
    df = r.integer("df", lo=1)
    samples = r.integer("samples", lo=1)
    fs = r.number("sample_rate_hz", positive=True)
    conf = r.number("confidence", lo=0.5, hi=0.999999)
    level = r.number("level", positive=True, hi=0.5)
    source = r.string("source", "", nonempty=False)
    scales = tuple(_scale_from(e) for e in r.tables("scales"))
    ws = [s.scale for s in scales]
    if any(b <= a for a, b in itertools.pairwise(ws)):
        raise r.error("scales", f"expected increasing window lengths, got {ws}")
    r.finish()
    return TailModel(df=df, samples=samples, sample_rate_hz=fs, confidence=conf, level=level,
                     scales=scales, source=source)


def _maybe(r: Fields, key: str) -> float:
    v = r.number(key, None)
    return float("nan") if v is None else float(v)


def _scale_from(e: Fields) -> ScaleTail:
    w = e.integer("scale", lo=1, hi=1 << 20)
    p = e.numbers("probability")
    k = len(p)
    if any(not 0.0 < x < 1.0 for x in p):
        raise e.error("probability", "expected per-sample probabilities in (0, 1)")
    if any(b >= a for a, b in itertools.pairwise(p)):
        raise e.error("probability", "expected decreasing probabilities")
    qv = e.get("quantile")
    if not isinstance(qv, list) or len(qv) != k:
        raise e.error("quantile", f"expected {k} entries (numbers or null)")
    q = tuple(float("nan") if x is None else e._check_number(x, f"quantile[{j}]")
              for j, x in enumerate(qv, start=1))
    qu = e.numbers("quantile_upper", length=k, positive=True)
    src = e.get("source")
    if not isinstance(src, list) or len(src) != k or any(s not in TAIL_SOURCES for s in src):
        raise e.error("source", f"expected {k} entries among {', '.join(TAIL_SOURCES)}")
    g = e.mapping("gpd", None)
    gpd = None
    if g is not None:
        gpd = GpdFit(threshold=g.number("threshold", nonnegative=True),
                     exceedance_probability=g.number("exceedance_probability", positive=True,
                                                     hi=1.0),
                     exceedance_probability_upper=g.number("exceedance_probability_upper",
                                                           positive=True, hi=1.0),
                     exceedances=g.integer("exceedances", lo=1),
                     clusters=g.integer("clusters", lo=1), shape=g.number("shape"),
                     shape_sd=g.number("shape_sd", nonnegative=True),
                     shape_upper=g.number("shape_upper"),
                     scale_param=g.number("scale_param", positive=True))
        g.finish()
    out = ScaleTail(scale=w, windows=e.integer("windows", lo=0),
                    independent=e.integer("independent", lo=0),
                    variance_ratio=e.number("variance_ratio", positive=True),
                    excess_kurtosis=_maybe(e, "excess_kurtosis"),
                    kurtosis_p=_maybe(e, "kurtosis_p"), exceedance_p=_maybe(e, "exceedance_p"),
                    gaussian=e.boolean("gaussian"), probability=tuple(p), quantile=q,
                    quantile_upper=tuple(qu), source=tuple(src), gpd=gpd,
                    notes=e.string("notes", "", nonempty=False))
    e.finish()
    return out
