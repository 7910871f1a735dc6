"""Sessions for the diagnose tests: presets with undeclared effects, with the simulator's
knobs or with signals added here (temperature, bias step, line, effects outside the library).

Signals are added in SI to the raw output of one sensor: ``raw += signal / SF_true``, which
is exactly what the simulator's sensor model does with its own effects.
"""

import dataclasses

import numpy as np
from _sessions import session
from threadpoolctl import threadpool_limits

from calibration.calibrate import calibrate
from fdi.units import DPH

__all__ = ["add_signal", "calibrate_fast", "clean_fast", "session", "with_temperature"]

_BASE: dict = {}


def calibrate_fast(s, **kw):
    """The calibration's estimates without the Allan table and the Earth-rate fit."""
    kw.setdefault("noise_model", "white")
    with threadpool_limits(limits=1, user_api="blas"):   # tall-thin products: 1 thread
        return calibrate(s, allan=False, earth_rate=False, **kw)


def clean_fast(name, seed):
    """A clean session of a preset: the noise-free session plus white noise from the truth
    (the simulator's model; faster for 100-seed runs)."""
    if name not in _BASE:
        _BASE[name] = session(name, 0, white=False)
    s0, truth = _BASE[name]
    rng = np.random.default_rng(10_000 + seed)
    out = {}
    for kind, raw in (("gyro", s0.raw_gyro), ("accel", s0.raw_accel)):
        if raw is None:
            continue
        t = truth.sets[kind]
        L = np.linalg.cholesky(t.noise_covariance)
        out[kind] = raw + (rng.standard_normal(raw.shape) @ L.T) / t.scale_factors
    return dataclasses.replace(s0, raw_gyro=out["gyro"], raw_accel=out.get("accel")), truth


def add_signal(s, truth, sensor, signal_si, kind="gyro"):
    """The session with ``signal_si`` (N,) added to one sensor (0-based) of a kind."""
    sf = truth.sets[kind].scale_factors[sensor]
    if kind == "gyro":
        raw = s.raw_gyro.copy()
        raw[:, sensor] += signal_si / sf
        return dataclasses.replace(s, raw_gyro=raw)
    raw = s.raw_accel.copy()
    raw[:, sensor] += signal_si / sf
    return dataclasses.replace(s, raw_accel=raw)


def with_temperature(s, truth, k_dph_per_degC, sensor, seed=0, per_sensor=True):
    """A temperature column (slow swing plus a warm-up, °C) and a gyro bias
    ``k·(T − mean T)`` on one sensor (0-based)."""
    rng = np.random.default_rng(seed)
    t = s.t - s.t[0]
    T = 25 + 8 * (1 - np.exp(-t / 200)) + 2 * np.sin(2 * np.pi * t / t[-1] * 1.3
                                                      + rng.uniform(0, 6))
    n = s.raw_gyro.shape[1]
    TT = np.repeat(T[:, None], n, axis=1) + rng.normal(0, 0.5, n)[None, :]
    col = TT[:, sensor]
    s = add_signal(s, truth, sensor, k_dph_per_degC * DPH * (col - col.mean()))
    return dataclasses.replace(s, temperature_degC=TT if per_sensor else T)
