"""End to end: rimu simulate flight → rimu monitor-file → rimu.report/1 JSON."""

import json

import numpy as np
import pytest

from fdi.calfile import Calibration, SensorCal, SensorSet
from fdi.geometry import cone6
from fdi.units import DPH, DPS
from rimu.cli import main


def _cal():
    cfg = cone6()
    rng = np.random.default_rng(1)
    sens = []
    for i in range(6):
        h = cfg.H[i] + 5e-4 * rng.standard_normal(3)
        sens.append(SensorCal(name=cfg.sensor_names[i], axis=h / np.linalg.norm(h),
                              axis_nominal=cfg.H[i], scale_factor=0.01 * DPS,
                              scale_factor_sd=1e-6 * DPS, bias=3 * DPH, bias_sd=0.5 * DPH,
                              input_error_cov=np.eye(3) * 1e-10, misalignment_sd=np.full(2, 1e-5),
                              raw_unit="mV", scale_factor_unit="mV/(deg/s)", bias_unit="deg/h"))
    return Calibration("cone6", {"gyro": SensorSet("gyro", tuple(sens),
                                                   np.eye(6) * (0.01 * DPS) ** 2)}, 100.0)


@pytest.fixture
def cal_file(tmp_path):
    p = tmp_path / "cal.json"
    _cal().save(p)
    return p


def test_simulate_then_monitor_file(tmp_path, cal_file, capsys):
    out = tmp_path / "flight"
    rc = main(["simulate", "flight", "--cal", str(cal_file), "--duration", "12", "--seed", "3",
               "--fault", "step:3:30sigma:8", "--out", str(out)])
    assert rc == 0
    assert (out / "manifest.json").exists() and (out / "truth.json").exists()
    rep_path = tmp_path / "report.json"
    rc = main(["monitor-file", str(out), "--cal", str(cal_file), "--report", str(rep_path)])
    text = capsys.readouterr().out
    assert rc == 0, text
    rep = json.loads(rep_path.read_text())
    assert rep["schema"] == "rimu.report/1"
    ts = [e["t"] for e in rep["events"]]
    assert ts == sorted(ts)
    s = rep["summary"]
    assert s["false_alarms"] == 0, rep["events"][:5]
    assert s["isolated_sensors"] == [3], rep["events"][:5]
    assert s["detection_delay_s"][0] == 0.0          # a 30σ step: caught in its onset sample
    assert s["isolation_correct"] == [True]
    assert s["rate_error_rms_dps"] is not None and s["rate_error_rms_dps"] < 0.05
    assert "false alarms: 0" in text and "isolated sensors: [3]" in text


def test_cli_errors_are_one_line(tmp_path, cal_file, capsys):
    rc = main(["simulate", "flight", "--cal", str(cal_file), "--duration", "1",
               "--fault", "step:9:1sigma:0", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert rc == 2 and "SENSOR 9 out of range 1..6" in err and "Traceback" not in err
    rc = main(["monitor-file", str(tmp_path / "nowhere"), "--cal", str(cal_file)])
    err = capsys.readouterr().err
    assert rc == 2 and "nowhere: no such directory" in err
    rc = main(["simulate", "flight", "--cal", str(cal_file), "--duration", "1",
               "--out", str(tmp_path / "f.asc")])
    err = capsys.readouterr().err
    # a CAN log (.asc) is written through replay.logio and reads back with python-can
    assert rc == 0, err
    import can

    with can.ASCReader(str(tmp_path / "f.asc")) as r:
        assert sum(1 for _ in r) > 0


def test_simulate_flight_with_truth_sidecar(tmp_path, cal_file):
    from calibration.truth import save_truth
    from replay.flight import draw_true_model, load_flight_dir

    truth = _cal()
    save_truth(truth, {}, {}, tmp_path / "truth.json")
    rc = main(["simulate", "flight", "--cal", str(cal_file), "--duration", "2", "--seed", "1",
               "--truth", str(tmp_path / "truth.json"), "--out", str(tmp_path / "f")])
    assert rc == 0
    fl = load_flight_dir(tmp_path / "f")
    tp = fl.truth["true_parameters"]
    assert tp["source"] == "truth"
    np.testing.assert_allclose(tp["axis"], truth.gyro.H, rtol=1e-12)
    # without --truth the parameters are drawn, and differ from the calibration
    rc = main(["simulate", "flight", "--cal", str(cal_file), "--duration", "2", "--seed", "1",
               "--bias-instability", "5", "--bias-corr", "50", "--out", str(tmp_path / "g")])
    assert rc == 0
    g = load_flight_dir(tmp_path / "g")
    np.testing.assert_allclose(g.truth["true_parameters"]["axis"],
                               draw_true_model(_cal(), 1).axis, rtol=1e-12)
    np.testing.assert_allclose(g.truth["bias_drift"]["bias_instability"], [5 * DPH] * 6)
    assert g.truth["bias_drift"]["bias_correlation_s"] == 50.0
