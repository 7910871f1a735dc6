"""Adequacy probes: generic structure a residual must not have if the model is complete.

Each probe is a nested-model F-test of a block of generic regressors against the current
model of one sensor (:class:`calibration.diagnose.linmodel.LinModel`):

- ``step_means``: one indicator per step (per-step mean residuals);
- ``slow``: Legendre polynomials of degree 1-10 in time (trends, slow drifts);
- ``change_point``: a bias step at the best of the scanned times (Bonferroni over the scan);
- ``line``: a sinusoid at the periodogram peak (Bonferroni over the frequencies scanned);
- ``inputs``: the session inputs and their magnitudes (x, |x|, ẋ, specific force,
  temperature when present).

A probe that fails says where the structure sits: the steps whose mean residual is beyond
3 σ, the time of the step, the frequency band.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from calibration.diagnose.context import KindData
from calibration.diagnose.library import LINE_MIN_CYCLES, line_search, step_search
from calibration.diagnose.linmodel import LinModel

__all__ = ["PROBES", "run_probes", "shared_regressors"]

PROBES = ("step_means", "slow", "change_point", "line", "inputs")
SLOW_DEGREE = 10


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
    return out
