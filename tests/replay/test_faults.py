"""Fault specification parser: every kind, every unit, and the errors."""

import math

import numpy as np
import pytest

from fdi.calfile import Calibration, SensorCal, SensorSet
from fdi.errors import ConfigError
from fdi.geometry import cone6
from fdi.units import DPH, DPS, G0, MG
from replay.faults import FAULT_KINDS, Fault, fault_from_dict, parse_fault

SIGMA = np.array([0.01, 0.02, 0.03, 0.04, 0.05, 0.06]) * DPS


def _cal(kind="gyro"):
    cfg = cone6()
    sens = tuple(SensorCal(name=f"s{i + 1}", axis=cfg.H[i], axis_nominal=cfg.H[i],
                           scale_factor=1e-3, scale_factor_sd=0.0, bias=0.0, bias_sd=0.0)
                 for i in range(6))
    return Calibration("cone6", {kind: SensorSet(kind, sens, np.diag(SIGMA ** 2))}, 100.0)


@pytest.mark.parametrize(("spec", "kind", "sensor", "size", "onset", "duration"), [
    ("step:3:15sigma:20", "step", 3, 15 * SIGMA[2], 20.0, None),
    ("step:1:0.02dps:1.5", "step", 1, 0.02 * DPS, 1.5, None),
    ("step:2:5dph:0", "step", 2, 5 * DPH, 0.0, None),
    ("step:2:1e-3rad/s:3", "step", 2, 1e-3, 3.0, None),
    ("step:2:2e-3rads:3:4", "step", 2, 2e-3, 3.0, 4.0),
    ("ramp:2:0.05sigma/s:10", "ramp", 2, 0.05 * SIGMA[1], 10.0, None),
    ("ramp:4:0.5dps/s:10", "ramp", 4, 0.5 * DPS, 10.0, None),
    ("ramp:4:36dph/s:10:5", "ramp", 4, 36 * DPH, 10.0, 5.0),
    ("stuck:1::30", "stuck", 1, 0.0, 30.0, None),
    ("noise:4:3x:12", "noise", 4, 3.0, 12.0, None),
    ("scale:5:1%:40", "scale", 5, 0.01, 40.0, None),
    ("scale:5:-500ppm:40", "scale", 5, -5e-4, 40.0, None),
    ("spike:2:50sigma:15", "spike", 2, 50 * SIGMA[1], 15.0, None),
    ("dropout:6::25:2", "dropout", 6, 0.0, 25.0, 2.0),
    (" STEP:6:-3sigma:7 ", "step", 6, -3 * SIGMA[5], 7.0, None),
])
def test_every_kind_and_gyro_unit(spec, kind, sensor, size, onset, duration):
    f = parse_fault(spec, _cal())
    assert f.kind == kind, spec
    assert f.sensor == sensor, spec
    np.testing.assert_allclose(f.size, size, rtol=1e-12, err_msg=f"size of {spec}")
    assert f.onset == onset, spec
    assert f.duration == duration, spec
    assert f.spec == spec.strip()
    assert math.isinf(f.end) == (duration is None)


@pytest.mark.parametrize(("spec", "size"), [
    ("step:1:0.1mps2:1", 0.1), ("step:1:2mg:1", 2 * MG), ("step:1:0.01g:1", 0.01 * G0),
    ("ramp:1:1mg/s:1", MG), ("step:1:4sigma:1", 4 * SIGMA[0]),
])
def test_accelerometer_units(spec, size):
    f = parse_fault(spec, _cal("accel"), kind="accel")
    np.testing.assert_allclose(f.size, size, rtol=1e-12, err_msg=spec)


def test_all_kinds_covered():
    assert set(FAULT_KINDS) == {"step", "ramp", "stuck", "noise", "scale", "spike", "dropout"}


@pytest.mark.parametrize(("spec", "words"), [
    ("step:3:15sigma", "3 field(s)"),
    ("step:3:15sigma:20:1:2", "6 field(s)"),
    ("jump:3:15sigma:20", "unknown KIND"),
    ("step:x:15sigma:20", "SENSOR 'x'"),
    ("step:0:15sigma:20", "out of range 1..6"),
    ("step:7:15sigma:20", "out of range 1..6"),
    ("step:3:15:20", "unit '(none)'"),
    ("step:3:15furlong:20", "unit 'furlong'"),
    ("step:3:0.1mps2:20", "unknown for gyro"),
    ("step:3:sigma:20", "not understood"),
    ("ramp:3:0.05sigma:20", "bias per second"),
    ("noise:3:3:20", "noise multiplier"),
    ("noise:3:-2x:20", "≥ 0"),
    ("scale:3:1x:20", "scale-factor change"),
    ("stuck:3:5sigma:20", "leave SIZE empty"),
    ("dropout:3:1x:20:2", "leave SIZE empty"),
    ("step:3:15sigma:soon", "ONSET 'soon'"),
    ("step:3:15sigma:-1", "negative"),
    ("step:3:15sigma:nan", "not finite"),
    ("dropout:3::20:0", "must be positive"),
    ("dropout:3::20:x", "DURATION 'x'"),
])
def test_errors_name_spec_and_expectation(spec, words):
    with pytest.raises(ConfigError) as ei:
        parse_fault(spec, _cal())
    msg = str(ei.value)
    assert spec.strip() in msg, msg
    assert words in msg, msg
    assert "KIND:SENSOR:SIZE:ONSET" in msg, msg


def test_dict_round_trip_and_errors():
    f = parse_fault("dropout:6::25:2", _cal())
    assert fault_from_dict(f.to_dict()) == f
    g = Fault("step", 2, 1e-3, 1.0)
    assert fault_from_dict(g.to_dict()) == g
    with pytest.raises(ConfigError, match="faults\\[3\\]"):
        fault_from_dict({"kind": "step"}, "faults[3]")
    with pytest.raises(ConfigError, match="unknown fault kind"):
        fault_from_dict({**g.to_dict(), "kind": "boom"})
    with pytest.raises(ConfigError, match="sensor must be"):
        fault_from_dict({**g.to_dict(), "sensor": 0})


def test_scenario_unknown_key_is_refused(tmp_path):
    """Every loader refuses keys it does not know (a typo would otherwise change nothing)."""
    from fdi.errors import FileFormatError
    from replay.scenario import load_scenario
    from studies.synthetic import synthetic_calibration

    cal = synthetic_calibration("tetrad", seed=1)
    p = tmp_path / "s.toml"
    p.write_text('schema = "rimu.scenario/1"\n[[faults]]\nsensor = 2\nkind = "step"\n'
                 'size = "1dps"\nonset = 1.0\nduraton = 2.0\n')
    with pytest.raises(FileFormatError) as e:
        load_scenario(p, cal)
    assert (e.value.field, e.value.line) == ("faults[1].duraton", 7), str(e.value)
    assert "did you mean 'duration'?" in str(e.value)
