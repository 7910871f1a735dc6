"""Is a fitted periodic line the same line over the whole session?

The ``periodic_line`` candidate is a sinusoid of constant amplitude and phase. A line whose
amplitude grows (or whose phase wanders) over the session is outside the library, and the
constant line of mean amplitude fits it well enough to be claimed, to pass the probes and
the held-out check (which reads step means, and a line averages out over a step). Before a
line is called explained, this probe asks whether its in-phase and quadrature amplitudes
are the same in every segment of the session:

- the segments are the held-out check's folds (:func:`.holdout.folds`:
  :data:`.holdout.HOLDOUT_FOLDS` contiguous groups of whole steps);
- the sensor's model (which holds the line at its fitted frequency, common to the session)
  is extended by the line's two columns restricted to each segment but the first
  (``2·(K − 1)`` columns): together with the common line they give every segment its own
  in-phase and quadrature amplitude;
- the nested-model test of that extension is the sensor's own test: the F-test under white
  noise (:class:`.linmodel.LinModel`) or the profile-likelihood ratio under white +
  Gauss-Markov noise (:class:`.coloured.GlsModel`), i.e. a χ² test of equal amplitudes
  with ``2·(K − 1)`` degrees of freedom.

Under a line of constant amplitude the statistic is the ordinary nested-model statistic
(the fitted frequency minimises the residual, so the phase drift a frequency error would
leave is already taken out: the test is, if anything, conservative). The test joins the
adequacy probes' family (:func:`.selection.select`: Bonferroni at α/2 over probes ×
sensors plus the lines tested), and a failure makes the sensor "unexplained"
(``line_stationarity``), so the line becomes a partial fit and the verdict "effects
suspected" (:func:`.adequacy.decide`). The per-segment amplitudes it reports are ordinary
least-squares estimates (for reading, the test does not use them).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from calibration.diagnose.context import KindData
from calibration.diagnose.holdout import folds
from calibration.diagnose.library import BIAS_UNITS, Candidate, effect_searching

__all__ = ["LINE_EFFECT", "line_stationarity", "segments"]

LINE_EFFECT = effect_searching("frequency_hz")
"""The library effect this probe checks."""


def segments(d: KindData) -> list[np.ndarray]:
    """Sample masks of the segments (the held-out check's folds), shape (N,) each."""
    return [np.isin(d.step, fs) for fs in folds(d)]


def line_stationarity(d: KindData, i: int, model: Any, line: Candidate,
                      params: dict[str, Any],
                      others: Iterable[np.ndarray] = ()) -> dict[str, Any] | None:
    """The stationarity probe of one fitted line of sensor ``i`` (0-based).

    Parameters
    ----------
    d : KindData
    i : int
    model : :class:`.linmodel.LinModel` or :class:`.coloured.GlsModel`
        The sensor's current model, which holds the line (its test is used).
    line : Candidate
        The ``periodic_line`` candidate (its columns, shape (N, 2), cos and sin).
    params : dict
        The fitted line's parameters (``frequency_hz``).
    others : iterable of ndarray
        The model's other effect columns (for the per-segment amplitudes only).

    Returns
    -------
    dict or None
        ``{"test": "line_stationarity", "p_value", "statistic", "dof", "frequency_hz",
        "band_hz", "segments": [{"steps", "t0_s", "t1_s", "amplitude", "amplitude_sd",
        "phase_rad"}], "unit", "steps"}``; None when the session has one segment or the
        segment-wise columns add nothing beside the model.
    """
    segs = segments(d)
    if len(segs) < 2:
        return None
    Z0 = np.asarray(line.columns(d, i, params), float).reshape(d.N, -1)
    Z = np.column_stack([Z0 * m[:, None] for m in segs[1:]])
    ft = model.test(Z)
    if not ft.rank:
        return None
    f = float(params["frequency_hz"])
    df = 1.0 / max(d.duration_s, 1e-300)
    amps = _segment_amplitudes(d, i, Z0, segs, list(others))
    return {"test": "line_stationarity", "p_value": float(ft.p_value),
            "log_p": float(ft.log_p), "statistic": float(ft.F * ft.rank),
            "dof": int(ft.rank),
            "frequency_hz": f, "band_hz": [max(f - df, 0.0), f + df],
            "segments": amps, "unit": BIAS_UNITS[d.kind][0], "steps": []}


def _segment_amplitudes(d: KindData, i: int, Z0: np.ndarray, segs: list[np.ndarray],
                        others: list[np.ndarray]) -> list[dict[str, Any]]:
    """Per segment: in-phase/quadrature amplitudes of the line by ordinary least squares
    beside the calibration's columns ``[1, x]`` and the other effect columns, with the
    white-noise σ (for reading)."""
    base = [np.ones((d.N, 1)), d.x] + [np.asarray(o, float).reshape(d.N, -1) for o in others]
    seg_cols = [Z0 * m[:, None] for m in segs]
    X = np.column_stack(base + seg_cols)
    y = np.asarray(d.y[:, i], float)
    sc = np.linalg.norm(X, axis=0)
    sc[sc == 0] = 1.0
    Xs = X / sc
    Gi = np.linalg.pinv(Xs.T @ Xs, hermitian=True)     # normal equations: k × k
    beta = Gi @ (Xs.T @ y)
    resid = y - Xs @ beta
    rank = int(np.linalg.matrix_rank(Gi, hermitian=True))
    s2 = float(resid @ resid) / max(d.N - rank, 1)
    cov = s2 * Gi
    beta, cov = beta / sc, cov / np.outer(sc, sc)
    p = Z0.shape[1]
    k0 = X.shape[1] - p * len(segs)
    out = []
    for j, m in enumerate(segs):
        sl = slice(k0 + p * j, k0 + p * (j + 1))
        b, C = beta[sl], cov[sl, sl]
        amp = float(np.hypot(*b[:2])) if p >= 2 else float(abs(b[0]))
        g = b[:2] / amp if amp > 0 else np.zeros(2)
        sd = float(np.sqrt(max(g @ C[:2, :2] @ g, 0.0))) if p >= 2 else float(np.sqrt(C[0, 0]))
        t = d.t[m]
        out.append({"steps": sorted({int(s) for s in np.unique(d.step[m])}),
                    "t0_s": float(t[0]) if t.size else None,
                    "t1_s": float(t[-1]) if t.size else None,
                    # the candidate's columns are in bias units (deg/h, mg)
                    "amplitude": amp, "amplitude_sd": sd,
                    "phase_rad": float(np.arctan2(-b[1], b[0])) if p >= 2 else 0.0})
    return out
