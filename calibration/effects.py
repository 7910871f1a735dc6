"""Effects the default calibration model lacks, as simulator knobs (all off by default).

The knobs are the simulator forms of the effect specifications (:mod:`fdi.effect_specs`:
each spec's ``simulator`` gives its unit, the sensor kinds it acts on, its one-line
definition and its arithmetic; :mod:`fdi.effect_specs.builtin` tabulates them). The CLI help
text, the checks and the truth sidecar are generated from them. Each effect has one value
(same for every sensor it touches) and touches only the sensors named with
``--effect-sensors`` (1-based, within each sensor kind; default: all sensors of the kinds
it acts on).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

from fdi.effect_specs import (
    TEMP_RISE_DEGC,
    TEMP_START_DEGC,
    TEMP_TAU_S,
    WARMUP_TAU_S,
    SimulatorForm,
    effect_specs,
    temperature_profile,
)
from fdi.errors import ConfigError

__all__ = [
    "DELAY_KNOB",
    "EARTH_RATE_KNOB",
    "EFFECTS",
    "TEMPERATURE_KNOB",
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


@dataclass(frozen=True)
class Effect:
    """One simulator effect (a spec's :class:`~fdi.effect_specs.SimulatorForm`, named).

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
    form : SimulatorForm or None
        The spec's simulator form (its arithmetic).
    """

    name: str
    unit: str
    kinds: tuple[str, ...]
    doc: str
    flag: bool = False
    all_sensors: bool = False
    form: SimulatorForm | None = None


EFFECTS: dict[str, Effect] = {
    s.name: Effect(s.name, s.simulator.unit, s.simulator.kinds, s.simulator.doc,
                   s.simulator.flag, s.simulator.all_sensors, s.simulator)
    for s in effect_specs() if s.simulator is not None}
"""The effects, by name (the specs that have a simulator form, in their order)."""


def _knob(test: Callable[[SimulatorForm], bool]) -> str:
    return next(e.name for e in EFFECTS.values() if test(e.form))


DELAY_KNOB = _knob(lambda f: f.stage == "delay")
"""The knob that delays the inputs (the sensor samples late)."""
EARTH_RATE_KNOB = _knob(lambda f: f.stage == "earth_rate")
"""The knob that leaves the Earth rate out."""
TEMPERATURE_KNOB = _knob(lambda f: f.column)
"""The knob whose session carries a temperature column."""


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
