"""The rimu.calibration/1 file: round trip and precise errors."""

import json

import numpy as np
import pytest

from fdi.calfile import (
    AllanTable,
    Calibration,
    SensorCal,
    SensorSet,
    load_calibration,
    misalignment_angles,
)
from fdi.errors import FileFormatError
from fdi.geometry import tetrad
from fdi.units import DPS, scale_factor_to_si


def _cal() -> Calibration:
    rng = np.random.default_rng(1)
    H = tetrad().H
    sensors = []
    for i, h0 in enumerate(H):
        h = h0 + rng.normal(0, 1e-3, 3)
        h /= np.linalg.norm(h)
        sensors.append(SensorCal(
            name=f"g{i + 1}", axis=h, axis_nominal=h0,
            scale_factor=scale_factor_to_si(26.0 + i, "mV/(deg/s)"), scale_factor_sd=1e-9,
            bias=0.002 * DPS, bias_sd=1e-6, input_error_cov=np.eye(3) * 1e-8,
            misalignment_sd=np.array([1e-5, 2e-5]), raw_unit="mV",
            scale_factor_unit="mV/(deg/s)", bias_unit="deg/s", residual_rms=1e-4))
    gyro = SensorSet("gyro", tuple(sensors), np.eye(4) * 1e-8, ((0, 1, 2), (3,)),
                     (np.eye(3), H[3:4]), AllanTable(np.array([0.01, 0.02]), np.ones((2, 4))))
    return Calibration("tetrad", {"gyro": gyro}, 100.0, earth_rate_dph=15.1,
                       earth_rate_dph_sd=0.2, latitude_deg=-23.2, extra={"steps": [1, 2]})


def test_round_trip(tmp_path):
    cal = _cal()
    p = tmp_path / "cal.json"
    cal.save(p)
    back = load_calibration(p)
    for a, b in zip(cal.gyro.sensors, back.gyro.sensors, strict=True):
        np.testing.assert_allclose(b.axis, a.axis, rtol=1e-12, err_msg=a.name + " axis")
        assert b.scale_factor == pytest.approx(a.scale_factor, rel=1e-12), a.name
        assert b.scale_factor_sd == pytest.approx(a.scale_factor_sd, rel=1e-9), a.name
        assert b.bias == pytest.approx(a.bias, rel=1e-12), a.name
        np.testing.assert_allclose(b.misalignment_sd, a.misalignment_sd, rtol=1e-12)
    np.testing.assert_allclose(back.gyro.noise_covariance, cal.gyro.noise_covariance)
    np.testing.assert_allclose(back.gyro.allan.adev, cal.gyro.allan.adev)
    assert back.earth_rate_dph == 15.1 and back.latitude_deg == -23.2
    doc = json.loads(p.read_text())
    assert doc["schema"] == "rimu.calibration/3"
    for key in ("name", "axis", "axis_nominal", "misalignment_mrad", "misalignment_mrad_sd",
                "scale_factor", "scale_factor_sd", "scale_factor_unit", "bias", "bias_sd",
                "bias_unit"):
        assert key in doc["sensors"]["gyro"][0], key
    assert set(doc["parity"]) == {"nominal", "calibrated"}
    np.testing.assert_allclose(doc["sensors"]["gyro"][0]["scale_factor"], 26.0)


def test_misalignment_angles_small_rotation():
    h0 = np.array([0.0, 0.0, 1.0])
    h = np.array([1e-3, -2e-3, 1.0])
    ang = misalignment_angles(h0, h)
    np.testing.assert_allclose(np.sort(np.abs(ang)), [1e-3, 2e-3], rtol=1e-5)


@pytest.mark.parametrize(("mutate", "field"), [
    (lambda d: d.update(schema="rimu.calibration/9"), "schema"),
    (lambda d: d.pop("sample_rate_hz"), "sample_rate_hz"),
    (lambda d: d["sensors"]["gyro"][1].update(scale_factor_unit="mV/(furlong/s)"),
     "sensors.gyro[2].scale_factor_unit"),
    (lambda d: d["sensors"]["gyro"][2].update(bias="x"), "sensors.gyro[3].bias"),
    (lambda d: d["sensors"]["gyro"][0].update(axis=[1, 0]), "sensors.gyro[1].axis"),
    (lambda d: d["noise_covariance"].update(gyro=[[1.0]]), "noise_covariance.gyro"),
])
def test_bad_fields_are_named(tmp_path, mutate, field):
    doc = _cal().to_dict()
    mutate(doc)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(FileFormatError) as err:
        load_calibration(p)
    assert field in str(err.value) and str(p) in str(err.value)


def test_not_json(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text("{\n  nope")
    with pytest.raises(FileFormatError, match=r"bad.json:2: not valid JSON"):
        load_calibration(p)


@pytest.mark.parametrize(("mutate", "field"), [
    (lambda d: d.update(earth_rate_dhp=15.0), "earth_rate_dhp"),
    (lambda d: d["sensors"]["gyro"][0].update(bias_units="deg/h"), "sensors.gyro[1].bias_units"),
    (lambda d: d["sensors"].update(gyros=d["sensors"]["gyro"]), "sensors.gyros"),
])
def test_unknown_keys_are_refused(tmp_path, mutate, field):
    """Issue 10: unknown keys are refused everywhere, with the closest known key."""
    doc = _cal().to_dict()
    mutate(doc)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(FileFormatError) as err:
        load_calibration(p)
    assert err.value.field == field and "unknown key; did you mean" in str(err.value)


def test_timing_jitter_round_trip_and_default(tmp_path):
    """``timing_jitter_ms`` (and its sd) round-trips in ms; a file without it loads with 0
    (older files), and the reference (τ = 0) writes no key."""
    import dataclasses

    cal = _cal()
    s = list(cal.gyro.sensors)
    s[1] = dataclasses.replace(s[1], timing_jitter=2.3e-3, timing_jitter_sd=0.25e-3)
    cal = dataclasses.replace(cal, sets={"gyro": dataclasses.replace(cal.gyro,
                                                                     sensors=tuple(s))})
    p = tmp_path / "cal.json"
    cal.save(p)
    doc = json.loads(p.read_text())
    assert doc["sensors"]["gyro"][1]["timing_jitter_ms"] == pytest.approx(2.3)
    assert doc["sensors"]["gyro"][1]["timing_jitter_ms_sd"] == pytest.approx(0.25)
    assert "timing_jitter_ms" not in doc["sensors"]["gyro"][0]
    back = load_calibration(p)
    assert back.gyro.sensors[1].timing_jitter == pytest.approx(2.3e-3, rel=1e-12)
    assert back.gyro.sensors[1].timing_jitter_sd == pytest.approx(0.25e-3, rel=1e-12)
    assert back.gyro.sensors[0].timing_jitter == 0.0
    del doc["sensors"]["gyro"][1]["timing_jitter_ms"], doc["sensors"]["gyro"][1][
        "timing_jitter_ms_sd"]
    p.write_text(json.dumps(doc))
    assert load_calibration(p).gyro.sensors[1].timing_jitter == 0.0


@pytest.mark.parametrize("value", [-1.0, "2 ms", float("inf")])
def test_bad_timing_jitter_is_named(tmp_path, value):
    doc = _cal().to_dict()
    doc["sensors"]["gyro"][2]["timing_jitter_ms"] = value
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc).replace("Infinity", "1e999"))
    with pytest.raises(FileFormatError) as err:
        load_calibration(p)
    assert "sensors.gyro[3].timing_jitter_ms" in str(err.value) and str(p) in str(err.value)


def _ranged() -> Calibration:
    import dataclasses

    cal = _cal()
    g = dataclasses.replace(cal.gyro, validated_rate=np.array([1.1, 2.2, 0.4]),
                            validated_specific_force=21.5, validated_jolt=0.75)
    return dataclasses.replace(cal, sets={"gyro": g})


def test_validated_range_round_trip_and_default(tmp_path):
    """``validated_range`` (the rate per body axis and the specific force the calibration's
    samples covered) round-trips in SI; a file without it states no range."""
    cal = _ranged()
    p = tmp_path / "cal.json"
    cal.save(p)
    doc = json.loads(p.read_text())
    assert doc["validated_range"]["gyro"]["rate_unit"] == "rad/s"
    back = load_calibration(p)
    np.testing.assert_allclose(back.gyro.validated_rate, [1.1, 2.2, 0.4], rtol=1e-15,
                               err_msg="validated_rate")
    assert back.gyro.validated_specific_force == 21.5
    assert back.gyro.validated_jolt == 0.75
    assert doc["validated_range"]["gyro"]["jolt_unit"] == "m/s^2 per sample"
    assert back.fingerprint() == cal.fingerprint() != _cal().fingerprint()
    del doc["validated_range"]
    p.write_text(json.dumps(doc))
    back = load_calibration(p)
    assert back.gyro.validated_rate is None and back.gyro.validated_specific_force is None
    assert back.gyro.validated_jolt is None


@pytest.mark.parametrize(("mutate", "field"), [
    (lambda r: r.update(rate_abs_max=[1.0, 2.0]), "validated_range.gyro.rate_abs_max"),
    (lambda r: r.update(rate_abs_max=[1.0, -2.0, 3.0]), "validated_range.gyro.rate_abs_max"),
    (lambda r: r.update(rate_unit="deg/s"), "validated_range.gyro.rate_unit"),
    (lambda r: r.update(specific_force_max=-1.0), "validated_range.gyro.specific_force_max"),
    (lambda r: r.update(specific_force_g=2.0), "validated_range.gyro.specific_force_g"),
    (lambda r: r.update(jolt_max=-0.1), "validated_range.gyro.jolt_max"),
    (lambda r: r.update(jolt_unit="m/s^3"), "validated_range.gyro.jolt_unit"),
])
def test_bad_validated_range_is_named(tmp_path, mutate, field):
    doc = _ranged().to_dict()
    mutate(doc["validated_range"]["gyro"])
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(FileFormatError) as err:
        load_calibration(p)
    assert field in str(err.value) and str(p) in str(err.value)
