"""What a calibration keeps of its residual for the thresholds: tails and slow drift.

One function for every calibration that measures its own residual (the static bench
calibration, ``rimu calibrate static``, the in-flight calibration): the residual's tail
per window scale relative to the monitor's threshold inflation (:mod:`calibration.tails`,
``docs/noise-tails.md``) and the slow drift of its whitened parity (:mod:`calibration.drift`,
``docs/drift.md``), both measured on the calibration's own samples.

Conventions: residual (N, n) per sensor in SI (rad/s), NaN rows where a sample is not
used, in time order; raw (N, n) the raw outputs the monitor would see (for ρ).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calibration.drift import fit_drift_model
from calibration.tails import fit_tail_model
from fdi.calfile import SensorSet
from fdi.reconstruction import inflation_terms

__all__ = ["with_residual_models"]


def with_residual_models(s: SensorSet, residual: np.ndarray, raw: np.ndarray,
                         sample_rate_hz: float, *, source: str, tails: bool = True,
                         drift: bool = True, inflation: bool = True) -> SensorSet:
    """``s`` with its tail model and drift model measured on ``residual``.

    Parameters
    ----------
    s : SensorSet
        The calibrated set (axes, scale factors, biases and their sd, input-error
        covariances, timing jitter, noise covariance).
    residual : ndarray, shape (N, n)
        The calibration's residual per sensor (SI); NaN rows are not used.
    raw : ndarray, shape (N, n)
        Raw outputs of the same samples (the monitor's ρ, κ, β are computed from them).
    sample_rate_hz : float
    source : str
        What the residual is (recorded in both models).
    tails, drift : bool
        Which models to fit.
    inflation : bool
        Measure the tails relative to the monitor's threshold inflation (default); False:
        the tails of the bare statistic.

    Returns
    -------
    SensorSet
        With ``tails`` (relative to the monitor's threshold inflation) and ``drift`` set
        where asked (``drift`` None when the set has no parity space or too few samples).
    """
    out = s
    if tails:
        ctx: dict[str, object] = {}
        src = source
        if inflation:
            rho, kappa, beta = inflation_terms(
                s.H, s.scale_factors, s.biases, s.noise_covariance,
                np.array([c.input_error_cov for c in s.sensors]),
                np.array([c.bias_sd for c in s.sensors]),
                np.array([c.timing_jitter for c in s.sensors]), sample_rate_hz, raw)
            ctx = {"rho": rho, "kappa": kappa, "beta": beta}
            jit = any(c.timing_jitter > 0 for c in s.sensors)
            src += (", relative to the monitor's threshold inflation"
                    + (" (with timing jitter)" if jit else ""))
        out = replace(out, tails=fit_tail_model(residual, s.H, s.noise_covariance,
                                                sample_rate_hz, source=src, **ctx))
    if drift:
        out = replace(out, drift=fit_drift_model(residual, s.H, s.noise_covariance,
                                                 sample_rate_hz, source=source))
    return out
