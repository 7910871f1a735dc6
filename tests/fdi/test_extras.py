"""The typed entries of ``Calibration.extra`` (:mod:`fdi.extras`).

The two files in ``tests/fdi/data`` were written by rimu before the types existed (commit
3746783: a simulated tetrad turntable session through ``calibrate_checked`` with the
default noise model, and a simulated three-IMU flight through the in-flight calibration,
offsets 0, +5 and -3 ms; written compact). They must load as they did: same fingerprint
(computed by that commit on the loaded file), the same ``extra`` written back, and typed
values equal to the file's numbers in SI.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from fdi.calfile import calibration_from_dict, load_calibration
from fdi.errors import FileFormatError
from fdi.extras import CalibrationExtras, extras_from_dict
from fdi.units import MS

DATA = Path(__file__).parent / "data"
OLD = {"turntable": ("calibration3_turntable.json", "af2580e47e0cafa8"),
       "inflight": ("calibration3_inflight.json", "83a1ec72fc6479a7")}


def _doc(name: str) -> dict:
    return json.loads((DATA / OLD[name][0]).read_text(encoding="utf-8"))


@pytest.mark.parametrize("name", sorted(OLD))
def test_old_file_loads_with_its_fingerprint_and_writes_the_same_extra(name, tmp_path):
    cal = load_calibration(DATA / OLD[name][0])
    assert cal.fingerprint() == OLD[name][1]
    assert cal.to_dict()["extra"] == _doc(name)["extra"]
    cal.save(tmp_path / "again.json")
    again = load_calibration(tmp_path / "again.json")
    assert again.fingerprint() == OLD[name][1]
    assert again.extras == cal.extras


def test_inflight_timing_is_the_file_in_si():
    doc = _doc("inflight")
    rec = doc["extra"]["inflight"]
    inf = load_calibration(DATA / OLD["inflight"][0]).extras.inflight
    assert inf is not None and inf.reference == rec["reference"] == "imu1"
    assert inf.time_offset_sign == rec["time_offset_sign"]
    assert inf.flight.to_dict() == rec["flight"]
    assert sorted(inf.imus) == sorted(rec["imus"]) == ["imu2", "imu3"]
    for g, t in inf.imus.items():
        r = rec["imus"][g]
        assert t.time_offset_s == r["time_offset_ms"] * MS
        assert t.time_offset_sd_s == r["time_offset_ms_sd"] * MS
        assert t.timing_jitter_s == r["timing_jitter_ms"] * MS
        assert t.timing_jitter_sd_s == r["timing_jitter_ms_sd"] * MS
        chk = r["time_offset_check"]
        assert t.check.sd_s == chk["sd_ms"] * MS and t.check.block_s == chk["block_s"]
        assert t.check.consistent is chk["consistent"]
        assert [p.offset_s for p in t.check.pieces] == [
            None if p["offset_ms"] is None else p["offset_ms"] * MS for p in chk["pieces"]]
        assert t.check.consistency.p_value == chk["consistency"]["p_value"]
    # the simulated offsets (+5 ms, -3 ms) within 5 sd of the fit: the fixture is what it says
    offs = inf.time_offsets_s()
    for g, true in (("imu2", 5e-3), ("imu3", -3e-3)):
        assert abs(offs[g] - true) < 5 * inf.imus[g].time_offset_sd_s


def test_turntable_file_has_no_inflight_timing():
    cal = load_calibration(DATA / OLD["turntable"][0])
    assert cal.extras.inflight is None and cal.extras.time_offsets_s() == {}


def test_no_extra_gives_empty_extras():
    assert extras_from_dict({}) == CalibrationExtras()


@pytest.mark.parametrize(("where", "value", "field"), [
    (("inflight", "imus", "imu2", "time_offset_ms"), "5",
     "extra.inflight.imus.imu2.time_offset_ms"),
    (("inflight", "imus", "imu2"), 3, "extra.inflight.imus.imu2"),
    (("inflight", "imus"), [1], "extra.inflight.imus"),
    (("inflight", "flight", "samples"), 1.5, "extra.inflight.flight.samples"),
    (("inflight", "reference"), 1, "extra.inflight.reference"),
    (("inflight", "imus", "imu3", "time_offset_check", "pieces"), {},
     "extra.inflight.imus.imu3.time_offset_check.pieces"),
    (("inflight", "imus", "imu3", "time_offset_check", "consistent"), "yes",
     "extra.inflight.imus.imu3.time_offset_check.consistent"),
])
def test_loader_names_the_bad_field(where, value, field):
    doc = copy.deepcopy(_doc("inflight"))
    node = doc["extra"]
    for k in where[:-1]:
        node = node[k]
    node[where[-1]] = value
    with pytest.raises(FileFormatError) as err:
        calibration_from_dict(doc, "cal.json")
    assert err.value.field == field and err.value.path == "cal.json"


def test_records_built_in_memory_read_as_their_json():
    ex = {"inflight": {"reference": "imu1", "imus": {
        "imu2": {"time_offset_ms": np.float32(2.5), "time_offset_ms_sd": np.float64(0.1)},
        "imu3": {"timing_jitter_ms": np.array(0.2)}}}}
    inf = extras_from_dict(ex).inflight
    assert inf.imus["imu2"].time_offset_s == pytest.approx(2.5e-3)
    assert inf.imus["imu3"].time_offset_s is None
    assert inf.imus["imu2"].timing_jitter_s is None
    assert inf.imus["imu3"].timing_jitter_s == pytest.approx(0.2e-3)
    assert inf.time_offsets_s() == {"imu2": pytest.approx(2.5e-3)}


def test_provenance_and_noise_model_are_the_file():
    doc = _doc("turntable")["extra"]
    ex = load_calibration(DATA / OLD["turntable"][0]).extras
    assert ex.source == doc["source"] and ex.warnings == tuple(doc["warnings"])
    assert ex.method.text == "" and dict(ex.method.parts) == doc["method"]
    assert ex.method.part("bias") == "model" and ex.method.part("accel", "?") == "?"
    nm = ex.noise_model
    assert nm.method == doc["noise_model"]["method"] and sorted(nm.sets) == ["gyro"]
    g, rec = nm.sets["gyro"], doc["noise_model"]["gyro"]
    assert g.applied is rec["applied"] and g.likelihood_ratio == rec["likelihood_ratio"]
    assert g.record_s == rec["record_s"] and g.correlation_s is rec["correlation_s"] is None
    assert {k: list(v) for k, v in g.sd_factor.items()} == rec["sd_factor"]
    inf = load_calibration(DATA / OLD["inflight"][0]).extras
    assert inf.method.text.startswith("in-flight alignment") and inf.noise_model is None
    assert inf.static is None


def test_warnings_static_and_an_applied_noise_fit_from_a_dict():
    ex = extras_from_dict({
        "warnings": ("one", "two"), "static": {"reference": "imu3", "imus": {}},
        "noise_model": {"method": "auto", "accel": {
            "applied": np.bool_(True), "bias_instability": 2e-4, "correlation_s": 40.0,
            "likelihood_ratio": 12.0, "sigma_bias_instability": 3e-4,
            "sigma_correlation_s": 90.0, "sigma_cut": True, "record_s": 576.0,
            "sd_factor": {"bias": np.array([1.5, 2.0])}}}})
    assert ex.warnings == ("one", "two") and ex.static.reference == "imu3"
    a = ex.noise_model.sets["accel"]
    assert a.applied is True and a.bias_instability == 2e-4 and a.sigma_cut is True
    assert a.sd_factor == {"bias": (1.5, 2.0)}


@pytest.mark.parametrize(("extra", "field"), [
    ({"warnings": "careful"}, "extra.warnings"),
    ({"warnings": ["ok", 3]}, "extra.warnings[2]"),
    ({"source": 5}, "extra.source"),
    ({"method": {"bias": 1}}, "extra.method.bias"),
    ({"method": 2}, "extra.method"),
    ({"static": {"reference": 2}}, "extra.static.reference"),
    ({"noise_model": {"gyro": {"applied": 1}}}, "extra.noise_model.gyro.applied"),
    ({"noise_model": {"gyro": {"sd_factor": {"bias": ["x"]}}}},
     "extra.noise_model.gyro.sd_factor.bias"),
    ({"noise_model": {"method": "auto", "gyro": 1.0}}, "extra.noise_model.gyro"),
])
def test_typed_entries_name_the_bad_field(extra, field):
    with pytest.raises(FileFormatError) as err:
        extras_from_dict(extra, "cal.json")
    assert err.value.field == field


def test_turntable_checks_are_the_file_in_si():
    from fdi.units import DEG, DPH, input_unit_factor

    doc = _doc("turntable")["extra"]
    ex = load_calibration(DATA / OLD["turntable"][0]).extras
    rt = doc["rate_test"]
    assert [list(p) for p in ex.rate_test.pairs] == rt["pairs"]
    assert [list(r) for r in ex.rate_test.rates] == rt["R_rad_s"]
    assert list(ex.rate_test.chi2_dof) == rt["chi2_dof"]
    assert list(ex.step_residual_chi2_dof) == doc["step_residual_chi2_dof"]
    er, fe = ex.earth_rate_fit, doc["earth_rate_fit"]
    assert er.horizontal == fe["horizontal_dph"] * DPH
    assert er.scatter_sd == fe["scatter_sd_dph"] * DPH
    assert er.heading_offset == fe["heading_offset_deg"] * DEG
    assert list(er.steps) == fe["steps"] and er.n_samples == fe["n_samples"]
    gb, fb = ex.gyro_bias, doc["gyro_bias"]
    f = input_unit_factor(fb["unit"])
    assert gb.unit == "deg/h" and list(gb.model) == [x * f for x in fb["model"]]
    assert list(gb.turns_sd) == [x * f for x in fb["turns_sd"]]
    assert [list(r) for r in ex.parity_sd["gyro"]] == doc["parity_calibrated_sd"]
    rows = doc["residual_steps"]["gyro"]
    assert len(ex.residual_steps["gyro"]) == len(rows) == 16
    assert [(r.step, r.label, r.kind, r.n, list(r.mean), list(r.rms))
            for r in ex.residual_steps["gyro"]] == [
        (r["step"], r["label"], r["kind"], r["n"], r["mean"], r["rms"]) for r in rows]


def test_a_bias_record_without_turns_and_a_set_of_three():
    ex = extras_from_dict({"gyro_bias": {"unit": "deg/s", "model": [1.0], "model_sd": [0.5]},
                           "parity_accel_calibrated_sd": []})
    assert ex.gyro_bias.turns is None and ex.gyro_bias.model == (np.deg2rad(1.0),)
    assert ex.parity_sd == {"accel": ()}


@pytest.mark.parametrize(("extra", "field"), [
    ({"rate_test": {"pairs": [[1, 2.5]]}}, "extra.rate_test.pairs"),
    ({"rate_test": {"chi2_dof": ["a"]}}, "extra.rate_test.chi2_dof"),
    ({"rate_test": {"R_rad_s": [[0.1, "x", 0]]}}, "extra.rate_test.R_rad_s[1]"),
    ({"step_residual_chi2_dof": 1.0}, "extra.step_residual_chi2_dof"),
    ({"earth_rate_fit": {"horizontal_dph": "15"}}, "extra.earth_rate_fit.horizontal_dph"),
    ({"earth_rate_fit": {"steps": [1.5]}}, "extra.earth_rate_fit.steps"),
    ({"gyro_bias": {"unit": "furlong/h", "model": []}}, "extra.gyro_bias.unit"),
    ({"gyro_bias": {"model": [1.0]}}, "extra.gyro_bias.unit"),
    ({"parity_calibrated_sd": [[1.0, True]]}, "extra.parity_calibrated_sd[1]"),
    ({"residual_steps": {"gyro": [{"n": 3}]}}, "extra.residual_steps.gyro[1].step"),
])
def test_fit_checks_name_the_bad_field(extra, field):
    with pytest.raises(FileFormatError) as err:
        extras_from_dict(extra, "cal.json")
    assert err.value.field == field


def test_inflight_alignment_is_the_file_in_si():
    from fdi.units import DPH, DPS

    rec = _doc("inflight")["extra"]["inflight"]
    al = load_calibration(DATA / OLD["inflight"][0]).extras.inflight_alignment
    assert (al.samples_used, al.samples, al.samples_nonfinite, al.left_out) == (
        rec["samples_used"], rec["samples"], rec["samples_nonfinite"], ())
    for g, a in al.imus.items():
        r = rec["imus"][g]
        assert a.model == r["model"] and [list(x) for x in a.A] == r["A"]
        assert list(a.rotation) == r["rotation"] and list(a.scale_sd) == r["scale_sd"]
        assert list(a.bias) == [x * DPH for x in r["bias_dph"]]
        assert list(a.residual_rms) == [x * DPS for x in r["residual_rms_dps"]]
        assert (a.hac_lags, a.samples, a.notes) == (r["hac_lags"], r["samples"],
                                                    tuple(r["notes"]))


@pytest.mark.parametrize(("where", "value", "field"), [
    (("left_out",), [{"t0_s": "a", "t1_s": 1.0}], "extra.inflight.left_out[1].t0_s"),
    (("samples_used",), 1.5, "extra.inflight.samples_used"),
    (("imus", "imu2", "bias_dph"), [1.0, "x", 2.0], "extra.inflight.imus.imu2.bias_dph"),
    (("imus", "imu2", "A"), [[1.0, 0.0, 0.0], "row", [0.0, 0.0, 1.0]],
     "extra.inflight.imus.imu2.A[2]"),
    (("imus", "imu2", "notes"), ["fine", None], "extra.inflight.imus.imu2.notes[2]"),
])
def test_alignment_entries_name_the_bad_field(where, value, field):
    doc = copy.deepcopy(_doc("inflight"))
    node = doc["extra"]["inflight"]
    for k in where[:-1]:
        node = node[k]
    node[where[-1]] = value
    with pytest.raises(FileFormatError) as err:
        calibration_from_dict(doc, "cal.json")
    assert err.value.field == field


def test_offset_check_from_its_record_equals_the_loaded_one():
    from fdi.extras import offset_check_from_dict

    rec = _doc("inflight")["extra"]["inflight"]["imus"]["imu3"]["time_offset_check"]
    loaded = load_calibration(DATA / OLD["inflight"][0]).extras.inflight.imus["imu3"].check
    assert offset_check_from_dict(rec) == loaded and offset_check_from_dict({}) is None


def test_ferraris_record_in_si_and_its_bad_fields():
    from fdi.units import DEG

    rec = {"rotation_deg": -360.0, "gravity_m_s2": 9.81, "position_sd_deg": 1.0,
           "angle_sd_deg": 0.5, "earth_rate_in_sd": True, "latitude_deg": 49.6,
           "g_sensitivity_raw_per_m_s2": [[0.1, 0.2, 0.3]],
           "g_sensitivity_raw_per_m_s2_sd": [[0.01, 0.02, 0.03]],
           "chi2_dof": {"accel": [1.1], "gyro": [0.9], "dof": 2},
           "imucal": {"gyro": {}, "accel": {}}, "rotation_dof": 0}
    fe = extras_from_dict({"ferraris": rec}).ferraris
    assert fe.rotation == -360.0 * DEG and fe.angle_sd == 0.5 * DEG
    assert fe.latitude == 49.6 * DEG and fe.gravity == 9.81
    assert fe.g_sensitivity_raw_per_m_s2 == ((0.1, 0.2, 0.3),)
    assert fe.chi2_dof == {"accel": (1.1,), "gyro": (0.9,)} and fe.chi2_dof_dof == 2
    for key, bad, field in (("gravity_m_s2", -1.0, "extra.ferraris.gravity_m_s2"),
                            ("rotation_deg", None, "extra.ferraris.rotation_deg"),
                            ("chi2_dof", {"dof": 1.5}, "extra.ferraris.chi2_dof.dof")):
        with pytest.raises(FileFormatError) as err:
            extras_from_dict({"ferraris": {**rec, key: bad}}, "cal.json")
        assert err.value.field == field


def test_static_record_in_si_and_its_bad_fields():
    from fdi.units import DEG, DPS

    rec = {"reference": "imu1", "imus": {"imu2": {
        "rotation_deg": [1.0, 2.0, 3.0], "rotation_deg_sd": [0.1, 0.1, 0.1],
        "relative_bias_dps": [0.5, 0.0, -0.5], "relative_drift_dps": [0.01, 0.0, 0.0],
        "relative_drift_dps_sd": [0.003, 0.003, 0.003], "relative_drift_z": [3.3, 0.0, 0.0],
        "relative_drift_p": [0.001, 1.0, 1.0], "drift_block_s": 10.0, "drift_hac_lags": 4}},
        "alignment_full": True, "notes": ["n"], "alpha": 0.01,
        "drift_attribution": {"common": [0.01, 0, 0], "common_sd": [0.003, 0.003, 0.003],
                              "common_p": 0.01, "consistent_chi2": 0.0, "consistent_dof": 0,
                              "consistent_p": 1.0, "statement": "s", "unit": "deg/s",
                              "own": {"imu2": {"drift": [0.01, 0, 0], "z": [3.3, 0, 0],
                                               "p_value": 0.01}}},
        "bias_dps": [0.0] * 9, "bias_dps_sd": [0.001] * 9, "samples": 100, "duration_s": 1.0}
    st = extras_from_dict({"static": rec}).static
    imu = st.imus["imu2"]
    assert imu.rotation == (1.0 * DEG, 2.0 * DEG, 3.0 * DEG)
    assert imu.relative_bias == (0.5 * DPS, 0.0, -0.5 * DPS)
    assert imu.relative_drift_p == (0.001, 1.0, 1.0) and imu.drift_hac_lags == 4
    assert st.drift_attribution.own["imu2"].drift == (0.01 * DPS, 0.0, 0.0)
    assert st.drift_attribution.statement == "s" and st.samples == 100
    for path, bad, field in ((("imus", "imu2", "relative_drift_z"), "x",
                              "extra.static.imus.imu2.relative_drift_z"),
                             (("drift_attribution", "own", "imu2"), [],
                              "extra.static.drift_attribution.own.imu2"),
                             (("samples",), -1, "extra.static.samples")):
        doc = copy.deepcopy(rec)
        node = doc
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = bad
        with pytest.raises(FileFormatError) as err:
            extras_from_dict({"static": doc}, "cal.json")
        assert err.value.field == field


def test_cli_refuses_a_bad_typed_entry_in_one_line(tmp_path, capsys):
    from rimu.cli import main

    doc = copy.deepcopy(_doc("inflight"))
    doc["extra"]["inflight"]["imus"]["imu2"]["time_offset_ms"] = "4.99"
    bad = tmp_path / "cal.json"
    bad.write_text(json.dumps(doc), encoding="utf-8")
    capsys.readouterr()
    assert main(["parity", "cone6", "--misalignment", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "extra.inflight.imus.imu2.time_offset_ms" in err[0], err
    assert str(bad) in err[0] and "Traceback" not in err[0]
