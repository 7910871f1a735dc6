"""Stack repeated calibration sessions sample by sample into one mean session.

Sessions of the *same sequence* (same configuration, steps, sample times and table motion)
recorded at separate switch-ons are averaged output by output: ``ū(t) = (1/N)·Σ_j u_j(t)``.
What repeats at the same time after switch-on (a warm-up) stays in ``ū`` at full size; what
is independent between runs (white noise, a Gauss-Markov bias wander) drops by √N.

Why calibrating and checking the stack is valid
-----------------------------------------------
Per sensor and run the calibration model is linear in the raw output (seed 000 Eq. 19:
``u_j = a_j·x + c_j + n_j``, ``a_j = h̃_j/SF_j`` the gain vector in raw units per input,
``c_j`` the bias in raw units, ``x`` the exact input, the same for every run because the
sequence is the same). Averaging gives ``ū = ā·x + c̄ + n̄`` *exactly*: the stack is a
session of the same model whose gain vector and bias are the runs' means (so its bias is the
mean bias, its scale factor the harmonic mean ``1/mean(1/SF_j)``, its misalignment the mean
gain vector's), and whose noise ``n̄`` is the mean of independent noises:

- white noise of variance σ² → white noise of variance σ²/N;
- a first-order Gauss-Markov wander (σ_b, τc) → a Gauss-Markov process of the *same* τc and
  variance σ_b²/N (a sum of independent AR(1) processes with one φ is AR(1) with that φ);
- a repeating effect ``e(t)`` → ``e(t)``; one whose size varies between runs → its mean.

So the stacked noise is inside the family the adequacy check of
:func:`calibration.calibrate_checked.calibrate_checked` fits (white + Gauss-Markov, levels and τc
re-estimated), its tests keep their level on the stack, and the non-centrality of a
repeating effect grows N-fold (both noise variances /N, the effect unchanged). A
run-to-run difference of bias, scale factor or misalignment is not an effect: it only moves
the stack's parameters to the runs' mean. What stacking cannot remove: a structure shared
by the runs that the model lacks (it is then found, as it should be), and a wander slower
than the record, which stays a wander (/√N) — the stack's verdict reads it as noise as
before, with smaller σ.

The table record (time, angles, rates, steps) of the first session is kept; the others must
match it within tolerances (:func:`stack_mismatch`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from calibration.session import Session
from fdi.errors import ConfigError

__all__ = ["ANGLE_TOL_RAD", "RATE_TOL_RAD_S", "TIME_TOL_FRACTION", "stack_mismatch",
           "stack_sessions"]

TIME_TOL_FRACTION = 0.5
"""Sample times must agree within this fraction of a sample period."""
ANGLE_TOL_RAD = 1e-3
"""Table angles must agree within this (rad; wrapped difference)."""
RATE_TOL_RAD_S = 1e-4
"""Table rates must agree within this (rad/s)."""


def _config_key(c) -> tuple:
    return (tuple(c.sensor_names), np.round(np.asarray(c.H, float), 9).tobytes(),
            tuple(tuple(g) for g in c.groups))


def configuration_mismatch(ref: Session, s: Session) -> str | None:
    """Why two sessions cannot be compared parameter by parameter (None: they can).

    Same gyro configuration (names, nominal axes, groups), same accelerometers (or none),
    same raw units.
    """
    if _config_key(ref.gyro_config) != _config_key(s.gyro_config):
        return (f"{s.source}: gyro configuration (sensor names {list(s.gyro_config.sensor_names)}"
                f", nominal axes, groups) differs from {ref.source}")
    if (ref.accel_config is None) != (s.accel_config is None):
        return (f"{s.source}: accelerometers {'absent' if s.accel_config is None else 'present'}"
                f", {ref.source} has {'none' if ref.accel_config is None else 'them'}")
    if ref.accel_config is not None and \
            _config_key(ref.accel_config) != _config_key(s.accel_config):
        return f"{s.source}: accelerometer configuration differs from {ref.source}"
    for f in ("gyro_raw_unit", "accel_raw_unit"):
        if getattr(ref, f) != getattr(s, f):
            return f"{s.source}: {f} {getattr(s, f)!r}, expected {getattr(ref, f)!r} " \
                   f"as in {ref.source}"
    return None


def stack_mismatch(sessions: Sequence[Session]) -> str | None:
    """Why the sessions cannot be stacked sample by sample, or None when they can.

    The message names the first differing session (its ``source``) and field.
    """
    ref = sessions[0]
    for s in sessions[1:]:
        why = configuration_mismatch(ref, s)
        if why:
            return why
        if abs(s.sample_rate_hz - ref.sample_rate_hz) > 1e-9 * ref.sample_rate_hz:
            return (f"{s.source}: sample_rate_hz {s.sample_rate_hz:g}, expected "
                    f"{ref.sample_rate_hz:g} as in {ref.source}")
        if abs(s.latitude_deg - ref.latitude_deg) > 1e-6:
            return (f"{s.source}: latitude_deg {s.latitude_deg:g}, expected "
                    f"{ref.latitude_deg:g} as in {ref.source}")
        if len(s.steps) != len(ref.steps):
            return f"{s.source}: {len(s.steps)} steps, expected {len(ref.steps)} as in " \
                   f"{ref.source}"
        for a, b in zip(ref.steps, s.steps, strict=True):
            if (a.index, a.kind, a.pair) != (b.index, b.kind, b.pair) or \
                    not np.allclose(a.mat_pb, b.mat_pb, atol=1e-9):
                return (f"{s.source}: step {b.index} ({b.kind}, {b.label or 'no label'}) "
                        f"differs from step {a.index} of {ref.source}")
        if s.t.shape != ref.t.shape:
            return f"{s.source}: {s.t.shape[0]} samples, expected {ref.t.shape[0]} as in " \
                   f"{ref.source}"
        dt = TIME_TOL_FRACTION / ref.sample_rate_hz
        bad = np.abs((s.t - s.t[0]) - (ref.t - ref.t[0])) > dt
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            return (f"{s.source}: t at sample {i + 1} is {s.t[i] - s.t[0]:.6g} s after the "
                    f"start, expected {ref.t[i] - ref.t[0]:.6g} s within {dt:.3g} s")
        if not np.array_equal(s.step, ref.step):
            i = int(np.flatnonzero(s.step != ref.step)[0])
            return f"{s.source}: step at sample {i + 1} is {s.step[i]}, expected {ref.step[i]}"
        for f in ("inner", "outer"):
            d = np.abs(np.angle(np.exp(1j * (getattr(s, f) - getattr(ref, f)))))
            if (d > ANGLE_TOL_RAD).any():
                i = int(np.flatnonzero(d > ANGLE_TOL_RAD)[0])
                return (f"{s.source}: {f} angle at sample {i + 1} differs from {ref.source} "
                        f"by {d[i]:.3g} rad (tolerance {ANGLE_TOL_RAD:g})")
        for f in ("inner_rate", "outer_rate"):
            d = np.abs(getattr(s, f) - getattr(ref, f))
            if (d > RATE_TOL_RAD_S).any():
                i = int(np.flatnonzero(d > RATE_TOL_RAD_S)[0])
                return (f"{s.source}: {f} at sample {i + 1} differs from {ref.source} "
                        f"by {d[i]:.3g} rad/s (tolerance {RATE_TOL_RAD_S:g})")
        if (s.temperature_degC is None) != (ref.temperature_degC is None) or (
                s.temperature_degC is not None
                and s.temperature_degC.shape != ref.temperature_degC.shape):
            return f"{s.source}: temperature columns differ from {ref.source}"
    return None


def stack_sessions(sessions: Sequence[Session]) -> Session:
    """The sample-by-sample mean of sessions of one sequence (module docstring).

    Parameters
    ----------
    sessions : sequence of Session, length N ≥ 2
        Same configuration, steps, sample times and table motion (:func:`stack_mismatch`).

    Returns
    -------
    Session
        The first session's table record with the mean raw outputs (and mean temperatures);
        ``meta["stacked"]`` holds N and the sources.

    Raises
    ------
    ConfigError
        Fewer than two sessions, or sessions of different sequences (the message names the
        session and the field).
    """
    if len(sessions) < 2:
        raise ConfigError(f"stacking needs at least two sessions, got {len(sessions)}")
    why = stack_mismatch(sessions)
    if why:
        raise ConfigError(f"{why}; stacking needs identical sequences")
    ref = sessions[0]
    mean = lambda f: np.mean([np.asarray(getattr(s, f), float) for s in sessions], axis=0)  # noqa: E731
    return dataclasses.replace(
        ref, raw_gyro=mean("raw_gyro"),
        raw_accel=None if ref.raw_accel is None else mean("raw_accel"),
        temperature_degC=None if ref.temperature_degC is None else mean("temperature_degC"),
        source=f"stack of {len(sessions)} sessions",
        meta={"stacked": {"n": len(sessions), "sources": [s.source for s in sessions]},
              "sequence": ref.meta.get("sequence")})
