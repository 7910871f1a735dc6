"""Adequacy probes: generic structure a residual must not have if the model is complete.

Each probe is a nested-model F-test of a block of generic regressors against the current
model of one sensor (:class:`calibration.diagnose.linmodel.LinModel`):

- ``step_means``: one indicator per step (per-step mean residuals);
- ``slow``: Legendre polynomials of degree 1-10 in time (trends, slow drifts);
- ``change_point``: a bias step at the best of the scanned times (Bonferroni over the scan);
- ``line``: a sinusoid at the periodogram peak (Bonferroni over the frequencies scanned);
- ``inputs``: the session inputs and their magnitudes (x, |x|, ẋ, specific force,
  temperature when present).

Two variance probes look at what a mean model cannot show (:func:`variance_probes`):

- ``transients``: the residual's mean square within :data:`TRANSIENT_S` of every step
  change against the rest (one-sided F test; the degrees of freedom of the windows are
  reduced by the design effect of the squared residual's autocorrelation within a
  window): a sensor that spikes or rings at every rate change;
- ``noise_growth``: the trend of the squared residual over the session (OLS with a HAC
  covariance, statsmodels): noise that grows (or shrinks) over time.

A probe that fails says where the structure sits: the steps whose mean residual is beyond
3 σ, the time of the step, the frequency band.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from calibration.diagnose.context import KindData
from calibration.diagnose.library import LINE_MIN_CYCLES, line_search, step_search
from calibration.diagnose.linmodel import LinModel

__all__ = ["PROBES", "TRANSIENT_S", "run_probes", "shared_regressors", "variance_probes"]

PROBES = ("step_means", "slow", "change_point", "line", "inputs", "transients",
          "noise_growth")
SLOW_DEGREE = 10
TRANSIENT_S = 0.1
"""Half-width (s) of the window around each step change the ``transients`` probe reads
(at least two samples)."""


def _step_dummies(d: KindData) -> np.ndarray:
    return (d.step[:, None] == np.array(d.steps)[None, :]).astype(float)


def _legendre(d: KindData) -> np.ndarray:
    u = 2 * d.t / max(d.t[-1], 1e-300) - 1
    return np.polynomial.legendre.legvander(u, SLOW_DEGREE)[:, 1:]


def _inputs(d: KindData) -> np.ndarray:
    cols = [d.x, np.abs(d.x), d.x_dot]
    if d.kind == "gyro":
        cols.append(d.force)
    if d.temperature is not None:
        cols.append(d.temperature)
    return np.column_stack(cols)


def _bad_steps(d: KindData, e: np.ndarray) -> list[int]:
    sd = float(np.std(e))
    out = []
    for k in d.steps:
        m = d.step == k
        z = float(np.mean(e[m])) / (sd / np.sqrt(m.sum()))
        if abs(z) > 3:
            out.append((abs(z), k))
    return [k for _, k in sorted(out, reverse=True)[:8]]


def shared_regressors(d: KindData) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The sensor-independent probe regressors of a kind and their Gram matrices."""
    out = {}
    for name, Z in (("step_means", _step_dummies(d)), ("slow", _legendre(d)),
                    ("inputs", _inputs(d))):
        out[name] = (Z, Z.T @ Z)
    return out


def run_probes(d: KindData, i: int, model: LinModel, threshold: float,
               shared: dict[str, tuple[np.ndarray, np.ndarray]] | None = None
               ) -> list[dict[str, Any]]:
    """Failing probes of sensor ``i`` (0-based) at a per-probe p threshold.

    Returns
    -------
    list of dict
        ``{"test", "p_value", "steps", "band_hz", "time_s"}`` per failing probe (keys that
        do not apply are omitted).
    """
    out = []
    T = d.duration_s
    shared = shared_regressors(d) if shared is None else shared
    for name in PROBES:
        if name in _VARIANCE:
            continue
        mult, extra, G = 1, {}, None
        if name in shared:
            Z, G = shared[name]
        if name == "slow":
            extra["band_hz"] = [0.0, SLOW_DEGREE / (2 * T)]
        elif name == "change_point":
            par, mult = step_search(d, i, model.Q, model.e)
            Z = (d.t >= par["time_s"]).astype(float)
            k = int(np.searchsorted(d.t, par["time_s"]))
            extra.update(time_s=par["time_s"], steps=[int(d.step[min(k, d.N - 1)])])
        elif name == "line":
            par, mult = line_search(d, i, model.Q, model.e)
            ph = 2 * np.pi * par["frequency_hz"] * d.t
            Z = np.column_stack([np.cos(ph), np.sin(ph)])
            df = 1.0 / T
            extra["band_hz"] = [max(par["frequency_hz"] - df, LINE_MIN_CYCLES / T / 2),
                                par["frequency_hz"] + df]
        ft = model.test(Z, G)
        p = min(1.0, ft.p_value * mult)
        if ft.rank and p < threshold:
            rec = {"test": name, "p_value": p, **extra}
            rec.setdefault("steps", _bad_steps(d, model.e))
            out.append(rec)
    out.extend(rec for rec in variance_probes(d, np.asarray(model.e, float))
               if rec["p_value"] < threshold)
    return out


_VARIANCE = ("transients", "noise_growth")


def _design_effect(e2: np.ndarray, w: int) -> float:
    """Variance inflation of a w-sample window mean of ``e2`` from its autocorrelation."""
    x = e2 - e2.mean()
    v = float(x @ x)
    if w <= 1 or v <= 0:
        return 1.0
    rho = [float(x[lag:] @ x[:-lag]) / v for lag in range(1, w)]
    return max(1.0, 1.0 + 2.0 * sum((1 - lag / w) * r
                                    for lag, r in zip(range(1, w), rho, strict=True)))


def variance_probes(d: KindData, e: np.ndarray) -> list[dict[str, Any]]:
    """The ``transients`` and ``noise_growth`` probes of one residual (module docstring):
    one record each, ``{"test", "p_value", "steps" | "time_s", ...}``."""
    import statsmodels.api as sm
    from scipy import stats

    out: list[dict[str, Any]] = []
    e2 = e * e
    N = e.shape[0]
    w = max(2, round(TRANSIENT_S * d.sample_rate_hz))
    edges = np.flatnonzero(np.diff(d.step)) + 1
    near = np.zeros(N, bool)
    for k in edges:
        near[max(0, k - w):min(N, k + w)] = True
    n1, n0 = int(near.sum()), int((~near).sum())
    if n1 >= 2 and n0 >= 2 and e2[~near].mean() > 0:
        deff = _design_effect(e2, 2 * w)
        F = float(e2[near].mean() / e2[~near].mean())
        p = float(stats.f.sf(F, max(n1 / deff, 1.0), n0 / deff))
        worst = sorted(((float(e2[max(0, k - w):k + w].mean()), int(d.step[k])) for k in edges),
                       reverse=True)[:8]
        out.append({"test": "transients", "p_value": p, "variance_ratio": F,
                    "steps": [s for _, s in worst]})
    else:
        out.append({"test": "transients", "p_value": 1.0})
    tt = (d.t - d.t.mean()) / max(float(np.ptp(d.t)), 1e-12)
    lag = max(1, int(np.ceil(4 * (N / 100) ** (2 / 9))))
    r = sm.OLS(e2, sm.add_constant(tt)).fit(cov_type="HAC", cov_kwds={"maxlags": lag})
    p = float(r.pvalues[1]) if np.isfinite(r.pvalues[1]) else 1.0
    growth = float(r.params[1] / max(r.params[0], 1e-300))
    out.append({"test": "noise_growth", "p_value": p, "relative_change": growth,
                "steps": []})
    return out
