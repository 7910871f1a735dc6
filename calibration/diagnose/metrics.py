"""Error before and after the refit: residual RMS, χ²/dof of per-step means, parity RMS,
and, with a truth sidecar, parameter errors in σ.

χ²/dof of the per-step means, per sensor::

    χ² = Σ_k N_k·r̄_k² / σ_w²,     dof = S − p

``r̄_k`` the mean residual of step k over its ``N_k`` samples, ``σ_w²`` the pooled
within-step variance (not inflated by step-to-step structure), ``S`` the steps and ``p``
the parameters of the sensor's model (4 for the plain model: bias and gain vector, plus the
effect columns; approximate, as not every parameter acts on the step means). About 1 when
the model is complete and the noise white.

Parity RMS: the parity vector of the residuals ``V·r`` (``V`` from the calibrated axes, so
the table motion drops out; seed 000 Eq. 21), RMS over samples per parity row.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from calibration.compare import compare
from calibration.diagnose.context import KindData
from fdi.calfile import Calibration
from fdi.parity import parity_matrix
from fdi.units import input_unit_factor

__all__ = ["RESIDUAL_UNITS", "error_summary", "step_chi2_dof"]

RESIDUAL_UNITS = {"gyro": "deg/s", "accel": "mg"}
"""Units of the residual and parity RMS in reports."""


def step_chi2_dof(d: KindData, r: np.ndarray, n_params: np.ndarray) -> np.ndarray:
    """χ²/dof of the per-step residual means per sensor (see the module docstring)."""
    out = np.zeros(r.shape[1])
    S = len(d.steps)
    means, counts, within = [], [], np.zeros(r.shape[1])
    for k in d.steps:
        m = d.step == k
        rk = r[m]
        means.append(rk.mean(axis=0))
        counts.append(m.sum())
        within += ((rk - rk.mean(axis=0)) ** 2).sum(axis=0)
    means, counts = np.array(means), np.array(counts)
    var_w = within / max(d.N - S, 1)
    chi2 = (counts[:, None] * means**2).sum(axis=0) / np.maximum(var_w, 1e-300)
    out = chi2 / np.maximum(S - np.asarray(n_params), 1)
    return out


def error_summary(datas: Mapping[str, KindData], residual: Mapping[str, np.ndarray],
                  n_params: Mapping[str, np.ndarray], cal: Calibration,
                  truth: tuple[Calibration, Mapping[str, float]] | None = None
                  ) -> dict[str, Any]:
    """Residual RMS, step χ²/dof and parity RMS per kind; parameter errors with a truth.

    Returns
    -------
    dict
        ``{"residual_rms": {kind: [..]}, "step_chi2_dof": {kind: [..]},
        "parity_rms": {kind: [..]}, "unit": {kind: unit}, "truth": {...}}`` (``truth``
        only with one: ``{"max_abs_z", "n_beyond_3", "rms_z", "parameters": [{"kind",
        "sensor", "parameter", "error", "sd", "z"}]}``).
    """
    out: dict[str, Any] = {"residual_rms": {}, "step_chi2_dof": {}, "parity_rms": {},
                           "unit": {}}
    for kind, d in datas.items():
        f = input_unit_factor(RESIDUAL_UNITS[kind])
        r = residual[kind]
        out["unit"][kind] = RESIDUAL_UNITS[kind]
        out["residual_rms"][kind] = (np.sqrt(np.mean(r**2, axis=0)) / f).tolist()
        out["step_chi2_dof"][kind] = step_chi2_dof(d, r, n_params[kind]).tolist()
        H = cal.sets[kind].H
        if H.shape[0] > 3:
            p = r @ parity_matrix(H).T
            out["parity_rms"][kind] = (np.sqrt(np.mean(p**2, axis=0)) / f).tolist()
    if truth is not None:
        rows = compare(cal, *truth)
        z = np.array([row.z for row in rows], float)
        ok = np.isfinite(z)
        out["truth"] = {
            "max_abs_z": float(np.max(np.abs(z[ok]))) if ok.any() else None,
            "n_beyond_3": int(np.sum(np.abs(z[ok]) > 3)),
            "rms_z": float(np.sqrt(np.mean(z[ok] ** 2))) if ok.any() else None,
            "parameters": [{"kind": row.kind, "sensor": row.sensor, "parameter": row.parameter,
                            "unit": row.unit, "error": row.error, "sd": row.sd,
                            "z": row.z if np.isfinite(row.z) else None} for row in rows]}
    return out
