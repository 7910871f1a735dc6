"""Unit conversions at the edges."""

import math

import pytest

from fdi.errors import ConfigError
from fdi.units import (
    DPH,
    EARTH_RATE_DPH,
    input_unit_factor,
    scale_factor_from_si,
    scale_factor_sd_from_si,
    scale_factor_sd_to_si,
    scale_factor_to_si,
)


def test_earth_rate_is_15_041_dph():
    assert abs(EARTH_RATE_DPH - 15.041) < 1e-3


@pytest.mark.parametrize("unit", ["mV/(deg/s)", "(deg/s)/LSB", "(g)/LSB", "LSB/(m/s^2)"])
def test_scale_factor_round_trip(unit):
    v = 26.6259
    si = scale_factor_to_si(v, unit)
    assert math.isclose(scale_factor_from_si(si, unit), v, rel_tol=1e-12)
    sd_si = scale_factor_sd_to_si(v, 0.01, unit)
    assert math.isclose(scale_factor_sd_from_si(si, sd_si, unit), 0.01, rel_tol=1e-12)


def test_raw_per_input_is_inverted():
    # 24 mV per deg/s (seed 000's nominal FOG) is (1/24) deg/s per mV
    assert math.isclose(scale_factor_to_si(24.0, "mV/(deg/s)"), math.radians(1 / 24.0))


@pytest.mark.parametrize("unit", ["furlong/fortnight", "mV/(deg/min)", "(deg/s)/widgets", ""])
def test_unknown_units_raise(unit):
    with pytest.raises(ConfigError, match="unknown"):
        scale_factor_to_si(1.0, unit)


def test_input_units():
    assert input_unit_factor("deg/h") == DPH
    with pytest.raises(ConfigError):
        input_unit_factor("knots")
