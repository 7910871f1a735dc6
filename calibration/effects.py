"""Effects the default calibration model lacks, as simulator knobs (all off by default).

The list below is data: the CLI help text, the checks and the truth sidecar are generated
from it. Each effect has one value (same for every sensor it touches) and touches only the
sensors named with ``--effect-sensors`` (1-based, within each sensor kind; default: all
sensors of the kinds it acts on). Definitions, with ``s_i = h̃_i·x`` the input sensed along
the true axis (SI), ``w`` the sequence's table rate and ``t`` the time since the start of the
session:

- ``g_sensitivity`` k (°/h per g), gyros: ``s_i += k·(h̃_i·f_b)/g₀`` (bias proportional to
  the specific force along the sensor axis).
- ``scale_asymmetry`` a (fraction), gyros: ``s_i *= 1 + (a/2)·sign(s_i)`` (gains for + and −
  inputs differ by a).
- ``scale_nonlinearity`` k (fraction at the table rate), gyros: ``s_i += k·s_i²/w`` (quadratic
  term equal to k·w at the table rate).
- ``warmup`` A (°/h), gyros: ``s_i += A·exp(−t/τ)`` with τ = :data:`WARMUP_TAU_S` (the
  temperature-dependent bias of a sensor warming up after switch-on).
- ``time_skew`` τ (s), gyros and accelerometers: the sensor samples its input τ late,
  ``x(t − τ)``; the input is evaluated exactly from the step's table motion at ``t − τ``.
- ``bias_drift`` D (°/h), gyros: linear bias drift, ``s_i += D·t/T`` (T the session length):
  the bias is the truth bias at the start and truth + D at the end.
- ``no_earth_rate`` (flag, 1 = on), all gyros: Earth rate is not applied.
- ``temperature`` k (°/h per °C), gyros: ``s_i += k·(T(t) − T₀)`` with the session's
  temperature warming up from T₀ = :data:`TEMP_START_DEGC` by :data:`TEMP_RISE_DEGC` with
  time constant :data:`TEMP_TAU_S` (:func:`temperature_profile`); the simulated session
  carries ``T(t)`` as its per-set temperature column whenever the knob is given (also 0).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

from fdi.errors import ConfigError

if TYPE_CHECKING:
    import numpy as np

__all__ = [
    "EFFECTS",
    "TEMP_RISE_DEGC",
    "TEMP_START_DEGC",
    "TEMP_TAU_S",
    "WARMUP_TAU_S",
    "Effect",
    "effects_help",
    "parse_effect_sensors",
    "parse_effects",
    "resolve_effect_sensors",
    "temperature_profile",
]

WARMUP_TAU_S = 300.0
"""Time constant of the ``warmup`` bias transient (s)."""

TEMP_START_DEGC = 20.0
"""Temperature at the start of a simulated session (°C), the reference of ``temperature``."""
TEMP_RISE_DEGC = 15.0
"""Warm-up rise of the simulated temperature (°C)."""
TEMP_TAU_S = 600.0
"""Time constant of the simulated temperature warm-up (s)."""


def temperature_profile(t_s: np.ndarray) -> np.ndarray:
    """Simulated temperature (°C) at times ``t_s`` (s) from the session start, same shape.

    ``T(t) = T₀ + ΔT·(1 − exp(−t/τ))`` with :data:`TEMP_START_DEGC`,
    :data:`TEMP_RISE_DEGC` and :data:`TEMP_TAU_S`.
    """
    import numpy as np  # here: the help of rimu simulate calibration lists the effects

    t = np.asarray(t_s, float)
    return TEMP_START_DEGC + TEMP_RISE_DEGC * -np.expm1(-t / TEMP_TAU_S)


@dataclass(frozen=True)
class Effect:
    """One simulator effect.

    Attributes
    ----------
    name : str
    unit : str
        Unit of its value on the CLI and in the truth file.
    kinds : tuple of str
        Sensor kinds it acts on (``"gyro"``, ``"accel"``).
    doc : str
        One-line definition.
    flag : bool
        True when the value is only on/off.
    all_sensors : bool
        True when it ignores ``--effect-sensors`` (acts on every sensor of its kinds).
    """

    name: str
    unit: str
    kinds: tuple[str, ...]
    doc: str
    flag: bool = False
    all_sensors: bool = False


EFFECTS: dict[str, Effect] = {e.name: e for e in (
    Effect("g_sensitivity", "deg/h per g", ("gyro",),
           "gyro bias += k * (specific force along the sensor axis) / g0"),
    Effect("scale_asymmetry", "fraction", ("gyro",),
           "gyro gain 1+a/2 for positive inputs, 1-a/2 for negative ones"),
    Effect("scale_nonlinearity", "fraction at the table rate", ("gyro",),
           "gyro input += k * input^2 / table_rate (k*table_rate at the table rate)"),
    Effect("warmup", "deg/h", ("gyro",),
           f"gyro bias += A * exp(-t / {WARMUP_TAU_S:g} s), t from the session start"),
    Effect("time_skew", "s", ("gyro", "accel"),
           "the sensor samples its input this much late (input evaluated at t - skew)"),
    Effect("bias_drift", "deg/h", ("gyro",),
           "gyro bias drifts linearly from the truth bias at the start to truth + D at the "
           "end of the session"),
    Effect("no_earth_rate", "flag (1 = on)", ("gyro",),
           "Earth rate is not applied to the gyros", flag=True, all_sensors=True),
    Effect("temperature", "deg/h per degC", ("gyro",),
           f"gyro bias += k * (T - {TEMP_START_DEGC:g} degC), T warming up by "
           f"{TEMP_RISE_DEGC:g} degC with time constant {TEMP_TAU_S:g} s; the session "
           "records T as its temperature column"),
)}
"""The effects, by name."""


def effects_help() -> str:
    """Help text listing every effect with its unit and the sensors it touches."""
    lines = []
    for e in EFFECTS.values():
        who = " and ".join("gyros" if k == "gyro" else "accelerometers" for k in e.kinds)
        if e.all_sensors:
            who = "all " + who
        lines.append(f"{e.name} [{e.unit}; {who}]: {e.doc}")
    return "; ".join(lines)


def parse_effects(specs: str | Iterable[str] | None) -> dict[str, float]:
    """Parse ``NAME=VALUE[,NAME=VALUE]`` (or a list of such strings) into a dict.

    A flag may be given by its name alone (``no_earth_rate``).

    Raises
    ------
    ConfigError
        Unknown name, missing or non-numeric value.
    """
    if specs is None:
        return {}
    if isinstance(specs, str):
        specs = [specs]
    out: dict[str, float] = {}
    for spec in specs:
        for item in str(spec).split(","):
            item = item.strip()
            if not item:
                continue
            name, sep, val = item.partition("=")
            name = name.strip()
            if name not in EFFECTS:
                raise ConfigError(f"unknown effect {name!r}; expected one of "
                                  f"{', '.join(EFFECTS)}")
            e = EFFECTS[name]
            if not sep:
                if not e.flag:
                    raise ConfigError(f"effect {name!r} needs a value ({e.unit}): "
                                      f"{name}=VALUE")
                out[name] = 1.0
                continue
            try:
                v = float(val)
            except ValueError:
                raise ConfigError(f"effect {name!r}: expected a number ({e.unit}), "
                                  f"got {val!r}") from None
            if not math.isfinite(v):
                raise ConfigError(f"effect {name!r}: expected a finite number, got {val!r}")
            if e.flag and v not in (0.0, 1.0):
                raise ConfigError(f"effect {name!r} is a flag: 0 or 1, got {val!r}")
            out[name] = v
    return out


def parse_effect_sensors(spec: str | None) -> tuple[int, ...] | None:
    """Parse ``"1,3"`` into (1, 3) (1-based sensor numbers); None when not given."""
    if spec is None or str(spec).strip() == "":
        return None
    out = []
    for item in str(spec).split(","):
        item = item.strip()
        try:
            k = int(item)
        except ValueError:
            raise ConfigError(f"--effect-sensors: expected sensor numbers like 1,3, got "
                              f"{item!r}") from None
        if k < 1:
            raise ConfigError(f"--effect-sensors: sensors are numbered from 1, got {k}")
        out.append(k)
    return tuple(sorted(set(out)))


def resolve_effect_sensors(effects: Mapping[str, float],
                           effect_sensors: Mapping[str, Iterable[int]] | Iterable[int] | None,
                           n_sensors: Mapping[str, int]) -> dict[str, tuple[int, ...]]:
    """The 1-based sensors each active effect touches.

    Parameters
    ----------
    effects : mapping of name to value
        Effects with value 0 are off and get no entry.
    effect_sensors : mapping of name to sensors, or sensors for every effect, or None
        None (or a missing name) means every sensor of the effect's kinds.
    n_sensors : mapping of kind to count
        Sensors of each kind present (a kind with 0 sensors is skipped).

    Raises
    ------
    ConfigError
        Unknown effect, or a sensor number outside 1..n for a kind the effect touches.
    """
    out: dict[str, tuple[int, ...]] = {}
    for name, value in effects.items():
        if name not in EFFECTS:
            raise ConfigError(f"unknown effect {name!r}; expected one of {', '.join(EFFECTS)}")
        if value == 0.0:
            continue
        e = EFFECTS[name]
        n = max((n_sensors.get(k, 0) for k in e.kinds), default=0)
        if effect_sensors is None or e.all_sensors:
            chosen = None
        elif isinstance(effect_sensors, Mapping):
            chosen = effect_sensors.get(name)
        else:
            chosen = effect_sensors
        if chosen is None:
            out[name] = tuple(range(1, n + 1))
            continue
        sel = tuple(sorted({int(k) for k in chosen}))
        for k in sel:
            for kind in e.kinds:
                m = n_sensors.get(kind, 0)
                if m and not 1 <= k <= m:
                    raise ConfigError(f"effect {name!r}: sensor {k} does not exist; the "
                                      f"{kind}s are numbered 1..{m}")
        out[name] = sel
    return out
