"""``rimu diagnose`` and ``rimu calibrate turntable --effects``: JSON layout, report, temperature
columns, and one-line errors (exit 2) on bad input."""

import json

import numpy as np
import pytest
from _cli import run as _run
from _diagnose_sessions import session, with_temperature

from calibration.session_io import load_session, save_session
from calibration.simulate import save_simulation
from rimu.cli import main


@pytest.fixture(scope="module")
def drift_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("drift")
    seq_truth = session("tetrad-paper", 11, effects={"bias_drift": 10.0}, effect_sensors=[2])
    from calibration.presets import preset

    save_simulation(seq_truth[0], preset("tetrad-paper").truth, d / "s")
    assert main(["calibrate", "turntable", str(d / "s"), "--out", str(d / "cal.json")]) == 0
    return d


def test_json_layout_and_before_after(drift_dir, capsys):
    code, out, err = _run(capsys, "diagnose", drift_dir / "s", "--cal", drift_dir / "cal.json",
                          "--json", "--truth", drift_dir / "s" / "truth.json")
    assert code == 0, err
    doc = json.loads(out)
    for key in ("effects", "unexplained", "unexplained_detail", "not_testable",
                "error_before", "error_after"):
        assert key in doc, key
    (e,) = doc["effects"]
    for key in ("name", "sensors", "estimate", "estimate_sd", "unit", "p_value"):
        assert key in e, key
    assert e["name"] == "bias_drift" and e["sensors"] == [2] and e["unit"] == "deg/h"
    b, a = doc["error_before"], doc["error_after"]
    for k in ("residual_rms", "step_chi2_dof", "parity_rms", "truth"):
        assert k in b and k in a, k
    assert b["step_chi2_dof"]["gyro"][1] > 10 > 3 > a["step_chi2_dof"]["gyro"][1]
    assert b["truth"]["max_abs_z"] > 5 and a["truth"]["max_abs_z"] < 4
    assert any(n["name"] == "temperature" for n in doc["not_testable"])
    # the refit calibration's verdict and its detectability limits
    assert doc["verdict"] in ("adequate", "adequate within sequence limits",
                              "effects not ruled out")
    assert (doc["verdict"] == "adequate within sequence limits") == (
        not doc["not_ruled_out"] and bool(doc["sequence_limits"]))
    assert (doc["verdict"] == "effects not ruled out") == bool(doc["not_ruled_out"])
    for r in doc["not_ruled_out"] + doc["sequence_limits"]:
        assert r["power"] < 0.99 and r["size_for_power"] > r["size"] > 0, r
        assert r["parameter"] in ("bias", "scale_factor", "misalignment_1", "misalignment_2")
    assert not any(r["name"] == "bias_drift" and r["sensor"] == 2
                   for r in doc["not_ruled_out"])                     # it is fitted


def test_text_report_and_refit_file(drift_dir, tmp_path, capsys):
    code, out, err = _run(capsys, "diagnose", drift_dir / "s", "--cal", drift_dir / "cal.json",
                          "--report", tmp_path / "rep", "--out", tmp_path / "cal2.json")
    assert code == 0, err
    assert "bias_drift" in out and "before gyro" in out and "after  gyro" in out
    page = (tmp_path / "rep" / "diagnosis.md").read_text()
    assert "bias_drift" in page
    pngs = sorted(p.name for p in (tmp_path / "rep").glob("*.png"))
    assert "gyro_step_means.png" in pngs and "gyro_spectrum.png" in pngs
    assert "gyro_2_bias_drift.png" in pngs
    doc = json.loads((tmp_path / "cal2.json").read_text())
    assert doc["schema"] == "rimu.calibration/3" and doc["effects"][0]["name"] == "bias_drift"


def test_calibrate_prints_the_verdict_and_fits_asked_effects(drift_dir, tmp_path, capsys):
    code, out, err = _run(capsys, "calibrate", "turntable",
                                  drift_dir / "s", "--out", tmp_path / "c.json")
    assert code == 0, err
    assert "model adequacy (alpha 0.01): effects suspected: gyro 2: bias_drift" in out
    assert "Gauss-Markov noise widening is withheld" in err  # warnings go to stderr
    code, out, err = _run(capsys, "calibrate", "turntable",
                                  drift_dir / "s", "--out", tmp_path / "c.json",
                          "--effects", "bias_drift")
    assert code == 0, err
    doc = json.loads((tmp_path / "c.json").read_text())
    a = doc["adequacy"]
    # nothing suspected once the drift is fitted; where the tests ran against white +
    # Gauss-Markov noise some slow effects cannot be ruled out at 5 sigma (the verdict
    # says so and lists them), under white noise the verdict is "adequate"
    want = ("effects not ruled out" if a["not_ruled_out"] else
            "adequate within sequence limits" if a["sequence_limits"] else "adequate")
    assert a["noise_null"]["gyro"] != "white" or not a["not_ruled_out"]
    assert a["verdict"] == want
    assert f"model adequacy (alpha 0.01): {want}" in out and "effect bias_drift on gyro 2" in out
    if want == "effects not ruled out":
        assert "not ruled out (this session's noise could hide them" in out
        assert "what to do: repeat the session" in out
    assert "monitor compensates the effect terms whose inputs it has" in out + err
    assert len(doc["effects"]) == 4


def test_temperature_columns_round_trip_and_effect(tmp_path):
    s, truth = session("tetrad-paper", 12)
    s = with_temperature(s, truth, 2.0, 2)
    save_session(s, tmp_path / "t")
    header = (tmp_path / "t" / "samples.csv").read_text().split("\n", 1)[0]
    assert "temp_degC.g3" in header
    back = load_session(tmp_path / "t")
    np.testing.assert_array_equal(back.temperature_degC, s.temperature_degC)
    from calibration.calibrate import calibrate
    from calibration.diagnose import diagnose

    d = diagnose(back, calibrate(back, noise_model="white"))
    (e,) = d.effects
    assert (e["name"], e["sensors"]) == ("temperature", [3]) and e["unit"] == "deg/h per degC"
    assert abs(e["estimate"] - 2.0) < 3 * e["estimate_sd"]


def _one_line_exit_2(capsys, *argv, must=()):
    code, out, err = _run(capsys, *argv)
    assert code == 2, (out, err)
    line = err.strip()
    assert "\n" not in line and line.startswith("rimu: error:"), err
    for m in must:
        assert m in line, (m, line)
    return line


def test_bad_inputs_one_line(drift_dir, tmp_path, capsys):
    # a calibration of another configuration
    cone, _ = session("cone-paper", 1)
    save_session(cone, tmp_path / "cone")
    assert main(["calibrate", "turntable",
                 str(tmp_path / "cone"), "--out", str(tmp_path / "cone.json")]) == 0
    capsys.readouterr()
    _one_line_exit_2(capsys, "diagnose", drift_dir / "s", "--cal", tmp_path / "cone.json",
                     must=("cone.json", "sensors.gyro", "another configuration"))
    # a calibration of another session of the same configuration
    other, _ = session("tetrad-paper", 13)
    save_session(other, tmp_path / "other")
    _one_line_exit_2(capsys, "diagnose", tmp_path / "other", "--cal", drift_dir / "cal.json",
                     must=("cal.json", "residual_rms", "another session"))
    # an asked-for effect whose input the session lacks
    _one_line_exit_2(capsys, "calibrate", "turntable",
                             drift_dir / "s", "--out", tmp_path / "x.json",
                     "--effects", "temperature", must=("temperature", str(drift_dir / "s")))
    _one_line_exit_2(capsys, "calibrate", "turntable",
                             drift_dir / "s", "--out", tmp_path / "x.json",
                     "--effects", "humidity", must=("unknown effect 'humidity'",))
    _one_line_exit_2(capsys, "diagnose", drift_dir / "s", "--cal", drift_dir / "cal.json",
                     "--alpha", "1.5", must=("alpha",))


def test_nan_temperature_one_line(tmp_path, capsys):
    s, truth = session("tetrad-paper", 14)
    s = with_temperature(s, truth, 1.0, 0, per_sensor=False)
    save_session(s, tmp_path / "t")
    csv = tmp_path / "t" / "samples.csv"
    lines = csv.read_text().split("\n")
    cells = lines[100].split(",")
    cells[-1] = "nan"
    lines[100] = ",".join(cells)
    csv.write_text("\n".join(lines))
    _one_line_exit_2(capsys, "calibrate", "turntable", tmp_path / "t", "--out", tmp_path / "c.json",
                     must=("samples.csv:101", "temp_degC", "got nan"))


def test_misspelt_temperature_column_refused(tmp_path, capsys):
    s, truth = session("tetrad-paper", 14)
    s = with_temperature(s, truth, 1.0, 0, per_sensor=False)
    save_session(s, tmp_path / "t")
    csv = tmp_path / "t" / "samples.csv"
    text = csv.read_text()
    csv.write_text(text.replace("temp_degC", "temp_degF", 1))
    _one_line_exit_2(capsys, "calibrate", "turntable", tmp_path / "t", "--out", tmp_path / "c.json",
                     must=("samples.csv", "temp_degF"))
