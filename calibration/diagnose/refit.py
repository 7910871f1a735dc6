"""Refit the sensors that carry effects: calibration parameters and effects jointly.

Per sensor with at least one effect, ordinary least squares over every sample of the
session on the raw output (seed 000 Eq. 13 with the effect terms added)::

    u_i = a_i·x + c_i + Σ_k β_k·g_k / SF_i + η_i ,     a_i = h̃_i/SF_i,  c_i = b_i/SF_i

``g_k`` the effect regressors (SI output per unit of the effect,
:mod:`calibration.diagnose.library`). The covariance ``σ²·(XᵀX)⁻¹`` (σ² from the residual,
white noise; for a set tested against white + Gauss-Markov noise, the least-squares
sandwich with the fitted Gauss-Markov term added, :meth:`.coloured.NoiseSet.gm_cov`) holds
the correlations between the effects and the bias / gain they share columns with (a bias
drift and the bias, a g-sensitivity and the bias), so the refit σ are those of the
extended model. ``a`` is split into SF, axis and misalignment with the
calibration's own first-order propagation (:func:`calibration.rate_test.split_gain`, seed 000
Eq. 19). Sensors without effects keep the calibration's values.

A ``misalignment`` effect (axis tilt in one mounting) adds its two columns; the reported
estimate is the tilt magnitude (mrad) with its first-order sd.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from calibration.diagnose.coloured import NoiseSet
from calibration.diagnose.context import KindData
from calibration.diagnose.selection import Selected
from calibration.rate_test import group_misalignment_matrices, split_gain
from fdi.calfile import Calibration, EffectTerm, SensorCal, SensorSet

__all__ = ["Refit", "refit"]

_STALE_EXTRA = ("gyro_bias", "parity_calibrated_sd", "parity_accel_calibrated_sd",
                "residual_steps", "noise_model", "rate_test", "step_residual_chi2_dof")


@dataclasses.dataclass(frozen=True)
class Refit:
    """Result of :func:`refit`.

    Attributes
    ----------
    calibration : Calibration
        With refit sensors and ``effects`` filled.
    residual : dict of kind to ndarray, shape (N, n)
        Residual of the extended model (SI); the calibration's residual for untouched
        sensors.
    n_params : dict of kind to ndarray of int, shape (n,)
        Parameters of each sensor's model (4 + effect columns).
    """

    calibration: Calibration
    residual: dict[str, np.ndarray]
    n_params: dict[str, np.ndarray]


def _estimate(beta: np.ndarray, C: np.ndarray) -> tuple[float, float, dict[str, Any]]:
    """Value and sd of an effect from its coefficient(s): the coefficient itself for one
    column, the magnitude (amplitude, tilt) for several."""
    if beta.size == 1:
        return float(beta[0]), float(np.sqrt(max(C[0, 0], 0.0))), {}
    amp = float(np.linalg.norm(beta))
    g = beta / max(amp, 1e-300)
    sd = float(np.sqrt(max(g @ C @ g, 0.0))) if amp > 0 else float(np.sqrt(np.trace(C)))
    return amp, sd, {"components": beta.tolist(), "components_sd":
                     np.sqrt(np.clip(np.diag(C), 0, None)).tolist()}


def refit(datas: Mapping[str, KindData], cal: Calibration, chosen: Sequence[Selected], *,
          adequacy: Mapping[str, Any] | None = None,
          noise: Mapping[str, NoiseSet] | None = None) -> Refit:
    """The calibration with the chosen effects fitted jointly (see the module docstring).

    ``noise``: per kind whose tests ran against white + Gauss-Markov noise, the set's
    fitted noise (:class:`.coloured.NoiseSet`); the refit covariance is then the sandwich
    ``σ_w²·(XᵀX)⁻¹·(XᵀX + ρ·(DX̄)ᵀ·S(τ)·(DX̄))·(XᵀX)⁻¹`` at the fitted ``(ρ, τ)``."""
    noise = dict(noise or {})
    by_sensor: dict[tuple[str, int], list[Selected]] = {}
    for s in chosen:
        by_sensor.setdefault((s.kind, s.sensor), []).append(s)
    sets = dict(cal.sets)
    terms: list[EffectTerm] = []
    resid, npar = {}, {}
    for kind, d in datas.items():
        old = cal.sets[kind]
        sensors = list(old.sensors)
        r = d.y.copy()
        k = np.full(d.n, 4)
        for i in range(d.n):
            sel = by_sensor.get((kind, i))
            if not sel:
                continue
            Zs = [s.candidate.columns(d, i, s.params) for s in sel]
            X = np.column_stack([d.x, np.ones(d.N), *Zs])
            scale = np.linalg.norm(X, axis=0)
            scale[scale == 0] = 1.0
            coef, *_ = np.linalg.lstsq(X / scale, d.raw[:, i], rcond=None)
            coef = coef / scale
            e = d.raw[:, i] - X @ coef
            dof = max(d.N - X.shape[1], 1)
            s2 = float(e @ e) / dof
            Xs = X / scale
            Pinv = np.linalg.pinv(Xs.T @ Xs)
            if kind in noise:                   # white + Gauss-Markov: sandwich
                Pinv = Pinv + Pinv @ noise[kind].gm_cov(Xs) @ Pinv
            C = s2 * Pinv / np.outer(scale, scale)
            g = split_gain(coef[:3], C[:3, :3], old.sensors[i].axis_nominal)
            sf = g.scale_factor
            jb = np.concatenate([coef[3] * g.jac[0], [sf]])
            bias_sd = float(np.sqrt(max(jb @ C[:4, :4] @ jb, 0.0)))
            r[:, i] = e * sf
            k[i] = X.shape[1]
            sensors[i] = dataclasses.replace(
                old.sensors[i], axis=g.axis, scale_factor=sf, scale_factor_sd=g.scale_factor_sd,
                bias=float(coef[3] * sf), bias_sd=bias_sd, input_error_cov=C[:3, :3] * sf**2,
                misalignment_sd=g.misalignment_sd,
                residual_rms=float(np.sqrt(np.mean(r[:, i] ** 2))))
            col = 4
            for s, Z in zip(sel, Zs, strict=True):
                p = Z.shape[1]
                est, sd, more = _estimate(coef[col:col + p] * sf, C[col:col + p, col:col + p]
                                          * sf**2)
                col += p
                terms.append(EffectTerm(
                    name=s.candidate.name, kind=kind, sensor=i, estimate=est, estimate_sd=sd,
                    unit=s.candidate.unit_for(kind), inputs=s.candidate.inputs,
                    params={**s.params, **more, "p_value": s.p_value}))
        resid[kind], npar[kind] = r, k
        if any(by_sensor.get((kind, i)) for i in range(d.n)):
            cov = old.noise_covariance.copy()
            touched = [i for i in range(d.n) if by_sensor.get((kind, i))]
            full = (r.T @ r) / max(d.N - 4, 1)
            for i in touched:
                cov[i, :] = full[i, :]
                cov[:, i] = full[:, i]
            sets[kind] = _with_sensors(old, sensors, cov)
    extra = {k: v for k, v in dict(cal.extra).items() if k not in _STALE_EXTRA}
    if terms:
        extra["refit"] = ("sensors with effects refit jointly with them (ordinary least "
                          "squares over every sample; covariance for white noise"
                          + (", plus the fitted Gauss-Markov term for the "
                             + ", ".join(sorted(noise)) + " set" if noise else "")
                          + "); their per-step statistics and coloured-noise record from the "
                          "plain calibration were dropped")
    new = dataclasses.replace(cal, sets=sets, effects=tuple(terms), extra=extra,
                              adequacy=dict(adequacy) if adequacy is not None else cal.adequacy)
    return Refit(new, resid, npar)


def _with_sensors(old: SensorSet, sensors: list[SensorCal], cov: np.ndarray) -> SensorSet:
    H = np.array([c.axis for c in sensors])
    return dataclasses.replace(
        old, sensors=tuple(sensors), noise_covariance=cov,
        misalignment_matrices=group_misalignment_matrices(old.H_nominal, H, old.groups))
