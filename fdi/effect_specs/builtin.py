"""The built-in sensor effects, one :class:`~fdi.effect_specs.spec.EffectSpec` each.

This module is the only place a built-in effect's name is written (a test walks the product
code for it). The table (``s = h̃·x`` the input along the calibrated axis, SI; ``w`` the
table rate; ``t`` time from the start; ``T`` the session length; regressor × value = SI
output gained)::

    name                kinds  unit              session regressor   simulator  run-time
    g_sensitivity       gyro   deg/h per g       k·(h̃·f)/g0          yes        specific force
    scale_asymmetry     gyro   fraction          (a/2)·|s|           yes        rate sign
    scale_nonlinearity  gyro   fraction          k·s²/w              yes        rate squared
    warmup              gyro   deg/h             A·exp(−t/300 s)     yes        none (time)
    time_skew           both   s                 −τ·h̃·ẋ              yes        none
    bias_drift          gyro   deg/h             D·t/T               yes        none (session)
    no_earth_rate       gyro   fraction          −e·h̃·ω_earth        yes (flag) none (session)
    temperature         both   deg/h or mg /°C   k·(T − T̄)           gyro       temperature
    bias_step           both   deg/h or mg       c·[t ≥ t₀]          no         none (session)
    periodic_line       both   deg/h or mg       A·cos(2πf·t+φ)      no         none (session)
    misalignment        both   mrad              δ·(E·x)             no         none (session)

The in-flight diagnosis tests ``time_skew``, ``g_sensitivity``, ``temperature``, ``warmup``
(as ``warm_up``, τ = :data:`WARMUP_FLIGHT_TAU_S`), ``bias_drift`` (Legendre P1…P3) and
``periodic_line`` (as ``vibration_<f>Hz`` lines) on each IMU's three parity channels.

None of these effects is in the seed papers' error model (misalignment, bias and scale
factor, seed 001 Eq. 1): they are what :mod:`calibration.diagnose` tests that model against.

Adding an effect: one more :class:`EffectSpec` in :data:`BUILTIN` (``docs/effects.md``).
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Mapping
from typing import Any

from fdi.effect_specs.spec import (
    BIAS_UNITS,
    EffectSpec,
    FlightForm,
    FlightInputs,
    RuntimeForm,
    SimulatorForm,
)
from fdi.units import DPH, DPS, G0

__all__ = ["BIAS_DRIFT", "BUILTIN", "G_SENSITIVITY", "INPUT_LACKING", "RUNTIME_INPUTS",
           "TEMP_RISE_DEGC", "TEMP_START_DEGC", "TEMP_TAU_S", "WARMUP_FLIGHT_TAU_S",
           "WARMUP_TAU_S", "temperature_profile"]

G_SENSITIVITY = "g_sensitivity"
"""Name of the g-sensitivity effect; the flight simulators' truth files use it as a key."""
BIAS_DRIFT = "bias_drift"
"""Name of the linear bias drift; the flight simulator's truth file keys its drift by it."""

WARMUP_TAU_S = 300.0
"""Time constant of the ``warmup`` bias transient of a session (s): simulator and session
regressor."""
WARMUP_FLIGHT_TAU_S = 60.0
"""Time constant of the in-flight ``warm_up`` regressor (s). Shorter than
:data:`WARMUP_TAU_S` on purpose: the in-flight candidate is tested only on records longer
than its time constant, and flights are minutes long (a 300-s exponential over a 2-min
flight is a straight line, the drift polynomial's P1)."""
TEMP_START_DEGC = 20.0
"""Temperature at the start of a simulated session (°C), the reference of the knob."""
TEMP_RISE_DEGC = 15.0
"""Warm-up rise of the simulated temperature (°C)."""
TEMP_TAU_S = 600.0
"""Time constant of the simulated temperature warm-up (s)."""

RUNTIME_INPUTS = ("rate", "specific_force", "temperature")
"""Run-time inputs a term can need (the rate is the sensor's own output, always there)."""
INPUT_LACKING = {"specific_force": "no accelerometers in the stream",
                 "temperature": "the stream carries none for this sensor"}
"""What a term whose run-time input is missing is told, by default."""



class _Numpy:
    """numpy, imported at the first use: the CLI's help texts read the specs without it."""

    def __getattr__(self, name: str) -> Any:
        return getattr(importlib.import_module("numpy"), name)


np: Any = _Numpy()

_SESSION = "session-specific ({}), not a sensor property"


def temperature_profile(t_s: np.ndarray) -> np.ndarray:
    """Simulated temperature (°C) at times ``t_s`` (s) from the session start, same shape.

    ``T(t) = T₀ + ΔT·(1 − exp(−t/τ))`` with :data:`TEMP_START_DEGC`,
    :data:`TEMP_RISE_DEGC` and :data:`TEMP_TAU_S`.
    """
    t = np.asarray(t_s, float)
    return TEMP_START_DEGC + TEMP_RISE_DEGC * -np.expm1(-t / TEMP_TAU_S)


def _param(params: Mapping[str, Any], key: str) -> float | None:
    """A finite float parameter, or None."""
    try:
        v = float(params[key])
    except (KeyError, TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _bias_si(d: Any) -> float:
    return BIAS_UNITS[d.kind][1]


# -- what a session must have -------------------------------------------------------------
def _needs_rates(d: Any) -> str | None:
    return None if d.table_rate > 0 else "the session has no rate steps"


def _needs_temperature(d: Any) -> str | None:
    if d.temperature is None:
        return ("the session has no temperature column (add temp_degC, or "
                "temp_degC.<sensor>, to samples.csv)")
    return None


def _needs_force_change(d: Any) -> str | None:
    return None if np.ptp(d.force, axis=0).max() > 0.1 * G0 else \
        "the specific force does not change direction during the session"


def _needs_motion(d: Any) -> str | None:
    return None if np.max(np.abs(d.x_dot)) > 0 else "the input never changes within a step"


def _needs_mounts(d: Any) -> str | None:
    return None if d.mount.max() > 0 else "the session uses one mounting only"


def temperature_reference(d: Any, sensor: int) -> float:
    """The reference temperature of a ``temperature`` term (session mean, °C)."""
    return float(np.mean(d.temperature[:, sensor])) if d.temperature is not None else 0.0


# -- session regressors (SI output per unit of the value) ----------------------------------
def _line(d: Any, i: int, p: Mapping[str, Any]) -> np.ndarray:
    ph = 2 * np.pi * float(p["frequency_hz"]) * d.t
    return _bias_si(d) * np.column_stack([np.cos(ph), np.sin(ph)])


def _misalignment(d: Any, i: int, p: Mapping[str, Any]) -> np.ndarray:
    from fdi.calfile import tangent_basis

    m = d.mount == int(p["mount"])
    return 1e-3 * (d.x @ tangent_basis(d.H[i]).T) * m[:, None]


# -- in-flight regressors on an IMU's three channels, (N, 3, p) ---------------------------
def _per_axis(v: np.ndarray) -> np.ndarray:
    """(N,) regressor → (N, 3, 3): the same regressor on each channel, one parameter each."""
    X = np.zeros((v.shape[0], 3, 3))
    for k in range(3):
        X[:, k, k] = v
    return X


def _flight_force(fi: FlightInputs, p: Mapping[str, Any]) -> np.ndarray | str:
    f, keep = fi.force, fi.keep
    if f is None or f.shape[1] != 3 or not np.isfinite(f[keep]).all():
        return "no accelerometer logged beside the gyros"
    fc = f - f[keep].mean(axis=0)
    X = np.zeros((fc.shape[0], 3, 9))
    for k in range(3):
        X[:, k, 3 * k:3 * k + 3] = fc
    return X


def _flight_temperature(fi: FlightInputs, p: Mapping[str, Any]) -> np.ndarray | str:
    T, keep = fi.temperature, fi.keep
    if T is None:
        return "no temperature logged"
    if not (np.isfinite(T[keep, 0]).all() and np.std(T[keep, 0]) > 0.2):
        return "temperature does not vary (sd <= 0.2 degC)"
    return _per_axis(T[:, 0] - T[keep, 0].mean())


def _flight_warmup(fi: FlightInputs, p: Mapping[str, Any]) -> np.ndarray | str:
    t = fi.t
    if not t[-1] - t[0] > WARMUP_FLIGHT_TAU_S:
        return f"flight shorter than {WARMUP_FLIGHT_TAU_S:g} s"
    w = np.exp(-(t - t[0]) / WARMUP_FLIGHT_TAU_S)
    return _per_axis(w - w[fi.keep].mean())


def _flight_drift(fi: FlightInputs, p: Mapping[str, Any]) -> np.ndarray:
    from scipy.special import eval_legendre

    t = fi.t
    u = 2 * (t - t[0]) / max(t[-1] - t[0], 1e-9) - 1
    X = np.zeros((t.shape[0], 3, 9))
    for d in range(1, 4):
        P = eval_legendre(d, u)
        for k in range(3):
            X[:, k, 3 * (d - 1) + k] = P
    return X


def _flight_line(fi: FlightInputs, p: Mapping[str, Any]) -> np.ndarray:
    f1, t = float(p["frequency_hz"]), fi.t
    X = np.zeros((t.shape[0], 3, 6))
    for k in range(3):
        X[:, k, k] = np.cos(2 * np.pi * f1 * t)
        X[:, k, 3 + k] = np.sin(2 * np.pi * f1 * t)
    return X


# -- run-time forms --------------------------------------------------------------------------
def _needs_table_rate(p: Mapping[str, Any]) -> str | None:
    w = _param(p, "table_rate_dps")
    return None if w is not None and w > 0 else (
        "the term does not record the table rate (params.table_rate_dps); refit it with "
        "this version")


def _needs_reference(p: Mapping[str, Any]) -> str | None:
    return None if _param(p, "reference_degC") is not None else \
        "the term does not record its reference temperature (params.reference_degC)"


_FOG_MEMS = {"fog": 50.0, "mems": 3600.0 * 5}           # deg/h: warm-up, drift, step


# every effect here extends the error model of seed 001 Eq. 1 (misalignment, bias and scale
# factor only); none is in the seed papers
BUILTIN: tuple[EffectSpec, ...] = (
    EffectSpec(
        G_SENSITIVITY, ("gyro",), "gyro bias proportional to the specific force along the "
        "sensor axis", "deg/h per g", lambda d, i, p: DPH * (d.force @ d.H[i]) / G0,
        ("specific_force",), needs=_needs_force_change,
        could_absorb="a bias that follows the table's orientation for another reason (a "
                     "magnetic or thermal gradient)",
        bounds={"fog": {"gyro": 10.0}, "mems": {"gyro": 3600.0 * 2}},
        monitor_input="specific force (accelerometers)",
        simulator=SimulatorForm(
            "deg/h per g", ("gyro",),
            "gyro bias += k * (specific force along the sensor axis) / g0",
            lambda s, v, c: s + v * DPH * c.f_along / G0, order=2),
        runtime=RuntimeForm(
            "specific_force", "specific force", 2, ("gyro",),
            lambda est, p, kind: est * DPH / G0,
            lambda p, axis, var: (float(axis[0]), float(axis[1]), float(axis[2])),
            lambda k, x, e: k * (x[0] * e[0] + x[1] * e[1] + x[2] * e[2])),
        flight=FlightForm(G_SENSITIVITY, "(deg/s)/g", G0 / DPS, _flight_force, 1,
                          matrix=(("specific force x", "specific force y",
                                   "specific force z"), False))),
    EffectSpec(
        "scale_asymmetry", ("gyro",), "gain differs for positive and negative inputs "
        "(1 ± a/2)", "fraction", lambda d, i, p: 0.5 * np.abs(d.s[:, i]), ("rate_sign",),
        needs=_needs_rates,
        could_absorb="a dead zone or any other gain change even in the rate",
        bounds={"fog": {"gyro": 5e-3}, "mems": {"gyro": 0.05}}, monitor_input="rate sign",
        simulator=SimulatorForm(
            "fraction", ("gyro",), "gyro gain 1+a/2 for positive inputs, 1-a/2 for negative "
            "ones", lambda s, v, c: s * (1.0 + 0.5 * v * np.sign(s)), order=0),
        runtime=RuntimeForm("rate", "rate sign", 0, ("gyro",),
                            lambda est, p, kind: est * 0.5, lambda p, axis, var: 0.0,
                            lambda k, x, e: k * abs(x))),
    EffectSpec(
        "scale_nonlinearity", ("gyro",), "quadratic scale-factor term, k·s²/w (k·w at the "
        "table rate w)", "fraction",
        lambda d, i, p: d.s[:, i] ** 2 / max(d.table_rate, 1e-300), ("table_rate",),
        needs=_needs_rates,
        fixed_params=lambda d, i: {"table_rate_dps": d.table_rate / DPS},
        could_absorb="a gain that varies with |rate| in another law (at one table rate any "
                     "such law looks the same)",
        bounds={"fog": {"gyro": 5e-3}, "mems": {"gyro": 0.05}}, monitor_input="rate squared",
        simulator=SimulatorForm(
            "fraction at the table rate", ("gyro",),
            "gyro input += k * input^2 / table_rate (k*table_rate at the table rate)",
            lambda s, v, c: s + v * s**2 / c.table_rate, order=1,
            details=lambda m: {"table_rate_dps": m.get("table_rate_dps")}),
        runtime=RuntimeForm("rate", "rate squared", 1, ("gyro",),
                            lambda est, p, kind: est / (_param(p, "table_rate_dps") * DPS),
                            lambda p, axis, var: float(var),
                            lambda k, x, e: k * (x * x - e), check=_needs_table_rate)),
    EffectSpec(
        "warmup", ("gyro",), f"bias transient after switch-on, A·exp(-t/{WARMUP_TAU_S:g} s)",
        "deg/h", lambda d, i, p: DPH * np.exp(-d.t / WARMUP_TAU_S), ("time",),
        could_absorb="any early transient of another time constant, or a curved drift",
        bounds={c: {"gyro": b} for c, b in _FOG_MEMS.items()},
        monitor_input="time since switch-on",
        simulator=SimulatorForm(
            "deg/h", ("gyro",),
            f"gyro bias += A * exp(-t / {WARMUP_TAU_S:g} s), t from the session start",
            lambda s, v, c: s + v * DPH * np.exp(-c.t / WARMUP_TAU_S)[:, None], order=3,
            details=lambda m: {"tau_s": WARMUP_TAU_S}),
        no_runtime="needs the time since switch-on, which the stream does not carry",
        flight=FlightForm("warm_up", "deg/s", 1 / DPS, _flight_warmup, 3, time_only=True)),
    EffectSpec(
        "time_skew", ("gyro", "accel"), "the sensor samples its input tau late", "s",
        lambda d, i, p: -(d.x_dot @ d.H[i]), ("table_motion",), needs=_needs_motion,
        could_absorb="a low-pass lag (sensor bandwidth) at the table's accelerations",
        bounds={"*": {"gyro": 0.1, "accel": 0.1}},
        simulator=SimulatorForm(
            "s", ("gyro", "accel"),
            "the sensor samples its input this much late (input evaluated at t - skew)",
            stage="delay"),
        no_runtime="needs the input's rate of change (no run-time form)",
        flight=FlightForm("time_skew", "ms", 1e3, lambda fi, p: fi.rate_dot[:, :, None], 0,
                          role="skew")),
    EffectSpec(
        BIAS_DRIFT, ("gyro",), "bias drifts linearly by D over the session", "deg/h",
        lambda d, i, p: DPH * d.t / d.duration_s, ("time",),
        could_absorb="a curved or late-starting drift, a slow wander (measured: a quadratic "
                     "drift from 40 % of the session, absorbed with warmup; the held-out "
                     "check refuses that refit)",
        bounds={c: {"gyro": b} for c, b in _FOG_MEMS.items()},
        simulator=SimulatorForm(
            "deg/h", ("gyro",), "gyro bias drifts linearly from the truth bias at the start "
            "to truth + D at the end of the session",
            lambda s, v, c: s + v * DPH * (c.t / c.duration_s)[:, None], order=4,
            details=lambda m: {"session_duration_s": m["duration_s"]}),
        no_runtime=_SESSION.format("a drift over the calibration session's length"),
        flight=FlightForm(BIAS_DRIFT, "deg/s per Legendre term (P1, P2, P3 x axes)",
                          1 / DPS, _flight_drift, 4, time_only=True, role="drift",
                          matrix=(("Legendre P1", "Legendre P2", "Legendre P3"), True))),
    EffectSpec(
        "no_earth_rate", ("gyro",), "the Earth rate is missing from the output (1) or scaled "
        "wrongly (fraction missing)", "fraction", lambda d, i, p: -(d.earth @ d.H[i]),
        ("latitude",),
        could_absorb="a bias that depends on the heading or the table position",
        fraction_range=(-0.5, 1.5),
        simulator=SimulatorForm("flag (1 = on)", ("gyro",),
                                "Earth rate is not applied to the gyros", stage="earth_rate",
                                flag=True, all_sensors=True),
        no_runtime="a flaw of the session's Earth-rate model, not of the sensor"),
    EffectSpec(
        "temperature", ("gyro", "accel"), "bias proportional to the temperature, "
        "k·(T − T_ref), T_ref the session mean", "{bias} per degC",
        lambda d, i, p: _bias_si(d) * (d.temperature[:, i]
                                       - float(p.get("reference_degC", 0.0))),
        ("temperature",), needs=_needs_temperature,
        fixed_params=lambda d, i: {"reference_degC": temperature_reference(d, i)},
        could_absorb="any slow drift that correlates with the temperature profile "
                     "(warm-up, time)",
        bounds={"fog": {"gyro": 5.0, "accel": 0.5}, "mems": {"gyro": 3600.0 * 0.2,
                                                             "accel": 5.0}},
        monitor_input="temperature in the stream",
        simulator=SimulatorForm(
            "deg/h per degC", ("gyro",),
            f"gyro bias += k * (T - {TEMP_START_DEGC:g} degC), T warming up by "
            f"{TEMP_RISE_DEGC:g} degC with time constant {TEMP_TAU_S:g} s; the session "
            "records T as its temperature column",
            lambda s, v, c: s + v * DPH * (temperature_profile(c.t) - TEMP_START_DEGC)[:, None],
            order=5, column=True,
            details=lambda m: {"profile": "T0 + rise*(1 - exp(-t/tau))",
                               "start_degC": TEMP_START_DEGC, "rise_degC": TEMP_RISE_DEGC,
                               "tau_s": TEMP_TAU_S, "reference_degC": TEMP_START_DEGC}),
        runtime=RuntimeForm("temperature", "temperature", 3, ("gyro", "accel"),
                            lambda est, p, kind: est * BIAS_UNITS[kind][1],
                            lambda p, axis, var: _param(p, "reference_degC"),
                            lambda k, x, e: k * (x - e), check=_needs_reference),
        flight=FlightForm("temperature", "(deg/s)/degC", 1 / DPS, _flight_temperature, 2)),
    EffectSpec(
        "bias_step", ("gyro", "accel"), "bias jumps by c at an unknown time t0", "{bias}",
        lambda d, i, p: _bias_si(d) * (d.t >= float(p["time_s"])), ("time",),
        search="time_s",
        could_absorb="a fast ramp, several steps, or a transient that does not recover",
        bounds={c: {"gyro": b, "accel": a}
                for (c, b), a in zip(_FOG_MEMS.items(), (5.0, 300.0), strict=True)},
        no_runtime=_SESSION.format("a jump at a time of the calibration session")),
    EffectSpec(
        "periodic_line", ("gyro", "accel"), "sinusoid of amplitude A at an unknown frequency "
        "f", "{bias}", _line, ("time",), search="frequency_hz",
        could_absorb="a line whose amplitude or frequency varies, or a non-sinusoidal "
                     "periodic signal (measured: a line whose amplitude grows 7-fold, which "
                     "the held-out check does not see)",
        bounds={"fog": {"gyro": 20.0, "accel": 5.0}, "mems": {"gyro": 3600.0 * 2,
                                                              "accel": 100.0}},
        no_runtime="session-specific (a line whose phase at run time is unknown)",
        flight=FlightForm("vibration", "deg/s amplitude", 1 / DPS, _flight_line, 5,
                          searched=True)),
    EffectSpec(
        "misalignment", ("gyro", "accel"), "input axis tilted by two small angles in the "
        "steps of one mounting (re-mounting error; the first mounting is the reference)",
        "mrad", _misalignment, ("mounting",), needs=_needs_mounts, search="mount",
        could_absorb="a bias or gain that changes with the mounting",
        bounds={"*": {"gyro": 50.0, "accel": 50.0}},
        no_runtime="session-specific (a re-mounting on the turntable)"),
)
"""The built-in effects, in the diagnosis's order."""
