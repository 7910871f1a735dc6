"""Units at the edges of rimu.

Inside rimu everything is SI: rad/s, m/s², s. Files and the CLI may use other units; they
are converted here, through named constants, and nowhere else.

Scale factors follow the seed papers' model ``SF·u = h̃·ω + b`` (seed 000 Eq. 13,
seed 001 Eq. 1): internally ``SF`` is *input per raw unit* (rad/s per mV, m/s² per LSB).
Datasheets (and seed 000 Table 2) print the inverse, raw per input (mV/(°/s)); a unit string
says which: ``"mV/(deg/s)"`` is raw per input, ``"(deg/s)/LSB"`` is input per raw.
"""

from __future__ import annotations

import math
import re

from fdi.errors import ConfigError

__all__ = [
    "DEG",
    "DPH",
    "DPS",
    "EARTH_RATE",
    "EARTH_RATE_DPH",
    "G0",
    "INPUT_UNITS",
    "MG",
    "MS",
    "RAW_UNITS",
    "TIME_UNITS",
    "input_unit_factor",
    "scale_factor_from_si",
    "scale_factor_sd_from_si",
    "scale_factor_sd_to_si",
    "scale_factor_to_si",
]

DEG = math.pi / 180.0
"""One degree in radians."""
DPS = DEG
"""One degree per second in rad/s."""
DPH = DEG / 3600.0
"""One degree per hour in rad/s."""
EARTH_RATE = 7.2921150e-5
"""Earth's sidereal rotation rate in rad/s (WGS-84)."""
EARTH_RATE_DPH = EARTH_RATE / DPH
"""Earth rate in °/h (15.041 °/h)."""
G0 = 9.80665
"""Standard gravity in m/s²."""
MG = G0 / 1000.0
"""One milli-g in m/s²."""
MS = 1e-3
"""One millisecond in s."""

INPUT_UNITS: dict[str, float] = {
    "rad/s": 1.0,
    "deg/s": DPS,
    "deg/h": DPH,
    "m/s^2": 1.0,
    "g": G0,
    "mg": MG,
}
"""Physical input units: value in SI = value in unit × factor."""

TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
"""Time units of logged time stamps: value in s = value in unit × factor."""

RAW_UNITS: frozenset[str] = frozenset({"mV", "V", "LSB", "count", "raw", "uA"})
"""Names accepted for a sensor's raw output unit (the value is not converted)."""

_SF_RAW_PER_INPUT = re.compile(r"^\s*(\w+)\s*/\s*\(\s*([\w/^]+)\s*\)\s*$")
_SF_INPUT_PER_RAW = re.compile(r"^\s*\(\s*([\w/^]+)\s*\)\s*/\s*(\w+)\s*$")


def input_unit_factor(unit: str) -> float:
    """SI factor of a physical input unit (``"deg/h"`` → 4.85e-6).

    Raises
    ------
    ConfigError
        For a unit rimu does not know.
    """
    try:
        return INPUT_UNITS[unit.strip()]
    except (KeyError, AttributeError):
        known = ", ".join(sorted(INPUT_UNITS))
        raise ConfigError(f"unknown unit {unit!r}; expected one of {known}") from None


def _parse_sf_unit(unit: str) -> tuple[bool, float, str]:
    """Return (raw_per_input, input factor, raw unit name) of a scale-factor unit."""
    m = _SF_RAW_PER_INPUT.match(unit or "")
    if m and m.group(1) in RAW_UNITS:
        return True, input_unit_factor(m.group(2)), m.group(1)
    m = _SF_INPUT_PER_RAW.match(unit or "")
    if m and m.group(2) in RAW_UNITS:
        return False, input_unit_factor(m.group(1)), m.group(2)
    raise ConfigError(
        f"unknown scale-factor unit {unit!r}; expected RAW/(INPUT) such as 'mV/(deg/s)' "
        f"or (INPUT)/RAW such as '(deg/s)/LSB', RAW one of {', '.join(sorted(RAW_UNITS))}")


def scale_factor_to_si(value: float, unit: str) -> float:
    """Convert a scale factor from a file unit to SI input per raw unit."""
    raw_per_input, factor, _ = _parse_sf_unit(unit)
    if raw_per_input:
        return factor / value
    return value * factor


def scale_factor_from_si(sf_si: float, unit: str) -> float:
    """Convert an SI scale factor (input per raw unit) to a file unit."""
    raw_per_input, factor, _ = _parse_sf_unit(unit)
    if raw_per_input:
        return factor / sf_si
    return sf_si / factor


def scale_factor_sd_to_si(value: float, sd: float, unit: str) -> float:
    """Standard deviation of a scale factor, converted like its value (first order)."""
    raw_per_input, factor, _ = _parse_sf_unit(unit)
    if raw_per_input:
        return factor * sd / value**2
    return sd * factor


def scale_factor_sd_from_si(sf_si: float, sd_si: float, unit: str) -> float:
    """Inverse of :func:`scale_factor_sd_to_si`."""
    raw_per_input, factor, _ = _parse_sf_unit(unit)
    if raw_per_input:
        return factor * sd_si / sf_si**2
    return sd_si / factor

