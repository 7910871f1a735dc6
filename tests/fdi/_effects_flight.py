"""A simulated flight whose gyros carry scale asymmetry and g-sensitivity, with an
accelerometer triad beside it (shared by the effect tests).

The effects are added with the calibration simulator's own effect functions
(:mod:`calibration.simulate`) on the true axes: ``raw += (s_with_effect − s) / SF_true``.
"""

import dataclasses

import numpy as np

from calibration.simulate import EffectContext
from fdi.calfile import EffectTerm
from fdi.effect_specs import get_spec
from fdi.units import DPS
from replay.flight import simulate_flight
from replay.flight_data import AuxChannels
from replay.imu_set import attitude_gravity
from studies.synthetic import synthetic_calibration

__all__ = [
    "ACCEL_NOISE",
    "A_ASYM",
    "FLIGHT_S",
    "K_G",
    "effect_calibration",
    "flight_with_effects",
    "residual_z",
]

A_ASYM = 5e-3                   # fraction: 0.75 °/s at 300 °/s, 7.5 σ of one cone6 sample
K_G = 300.0                     # °/h per g: 0.083 °/s at 1 g, 0.8 σ of one cone6 sample
FLIGHT_S = 60.0
ACCEL_NOISE = 0.05              # m/s² per sample


def effect_calibration():
    """cone6 (0.1 °/s noise per sample) with the true effect terms: asymmetry on sensor 1,
    g-sensitivity +K on sensor 2 and −K on sensor 4."""
    cal = synthetic_calibration("cone6", seed=3)
    terms = (EffectTerm("scale_asymmetry", "gyro", 0, A_ASYM, 1e-5, "fraction",
                        ("rate_sign",)),
             EffectTerm("g_sensitivity", "gyro", 1, K_G, 1.0, "deg/h per g",
                        ("specific_force",)),
             EffectTerm("g_sensitivity", "gyro", 3, -K_G, 1.0, "deg/h per g",
                        ("specific_force",)))
    return dataclasses.replace(cal, effects=terms)


def flight_with_effects(cal, seed, *, truth=None, duration_s=FLIGHT_S, effects=None,
                        max_rate_dps=300.0, table_rate_dps=1.0):
    """A flight of ``cal``'s sensors (true model ``truth``, default ``cal`` itself) with
    ``effects`` ``{(name, sensor): value}`` (default: the terms of :func:`effect_calibration`)
    and an accelerometer triad ``accel:imu.x/y/z`` (gravity reaction plus noise);
    ``table_rate_dps``: the ``w`` of ``scale_nonlinearity``."""
    truth = cal if truth is None else truth
    if effects is None:
        effects = {("scale_asymmetry", 0): A_ASYM, ("g_sensitivity", 1): K_G,
                   ("g_sensitivity", 3): -K_G}
    fl = simulate_flight(cal, duration_s, seed=seed, truth=truth, max_rate_dps=max_rate_dps)
    g = truth.gyro
    s = fl.omega_true @ g.H.T
    f = attitude_gravity(fl.t, fl.omega_true)
    ctx = EffectContext(t=fl.t, duration_s=duration_s, table_rate=table_rate_dps * DPS,
                        f_along=f @ g.H.T)
    s2 = s.copy()
    for name in ("scale_asymmetry", "scale_nonlinearity", "g_sensitivity"):
        fn = get_spec(name).simulator.apply                  # the simulator's form
        for (nm, i), v in effects.items():                   # the simulator's order
            if nm == name:
                s2[:, [i]] = fn(s2[:, [i]], v,
                                dataclasses.replace(ctx, f_along=ctx.f_along[:, [i]]))
    raw = fl.raw + (s2 - s) / g.scale_factors
    fm = f + ACCEL_NOISE * np.random.default_rng([seed, 99]).standard_normal(f.shape)
    aux = AuxChannels(("accel",) * 3, ("imu.x", "imu.y", "imu.z"), ("",) * 3, fm,
                      np.ones(fm.shape, bool))
    return dataclasses.replace(fl, raw=raw, aux=aux)


def residual_z(cal, y):
    """Per-sensor parity residual mean over its standard deviation (white noise only)."""
    g = cal.gyro
    P = np.eye(g.n) - g.H @ np.linalg.pinv(g.H)
    e = y @ P.T
    sd = np.sqrt(np.diag(P @ g.noise_covariance @ P.T) / y.shape[0])
    return e.mean(axis=0) / sd
