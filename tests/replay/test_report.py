"""The rimu.report/1 dictionary: fields, time order, false alarms, delays, rate error."""

import json

import numpy as np

from fdi.answer import BlockResult, Event
from fdi.calfile import Calibration, SensorCal, SensorSet
from fdi.geometry import cone6
from fdi.units import DPS
from replay.faults import Fault
from replay.flight import Flight
from replay.report import REPORT_SCHEMA, build_report, format_report


def _cal():
    cfg = cone6()
    sens = tuple(SensorCal(name=f"s{i + 1}", axis=cfg.H[i], axis_nominal=cfg.H[i],
                           scale_factor=1e-3, scale_factor_sd=0.0, bias=0.0, bias_sd=0.0)
                 for i in range(6))
    return Calibration("cone6", {"gyro": SensorSet("gyro", sens, np.eye(6) * 1e-8)}, 100.0)


def _flight(faults, omega_true=True, truth=None):
    N = 1000
    t = np.arange(N) / 100.0
    rng = np.random.default_rng(0)
    w = rng.standard_normal((N, 3)) if omega_true else None
    return Flight(t=t, raw=np.zeros((N, 6)), valid=np.ones((N, 6), bool), sample_rate_hz=100.0,
                  sensor_names=tuple(f"s{i + 1}" for i in range(6)), raw_unit="mV",
                  omega_true=w, faults=tuple(faults),
                  truth={} if truth is None else truth, source="mem")


def _result(fl, events, omega=None, cap="isolate", pl=None):
    N = fl.t.shape[0]
    healthy = np.ones((N, 6), bool)
    return BlockResult(t=fl.t, omega=fl.omega_true if omega is None else omega,
                       omega_sd=np.zeros((N, 3)), healthy=healthy,
                       statistics=np.zeros((N, 4)), thresholds=np.ones((N, 4)),
                       protection_level=np.zeros(N) if pl is None else pl,
                       capability=np.full(N, cap),
                       events=list(events))


def test_fields_order_false_alarms_and_delays():
    f1 = Fault("step", 3, 1e-3, 2.0, spec="step:3:15sigma:2")
    f2 = Fault("ramp", 5, 1e-4, 6.0, spec="ramp:5:1sigma/s:6")
    fl = _flight([f1, f2])
    ev = [
        Event(6.5, None, "detected", "parity scale 64", 30.0, 20.0),
        Event(1.0, None, "detected", "parity scale 1", 40.0, 35.0),      # before any onset
        Event(2.0, None, "detected", "parity scale 1", 400.0, 35.0),     # onset sample
        Event(2.03, 3, "isolated", "parity scale 1", 400.0, 35.0, 1, 1e-3),
        Event(4.0, 2, "health", "stale"),                                  # sensor w/o fault
        Event(7.0, 5, "isolated", "parity scale 64", 30.0, 20.0),
        Event(8.0, 5, "readmitted", "dwell"),
    ]
    omega = fl.omega_true + np.array([1.0, -2.0, 2.0]) * DPS
    omega[:100] = np.nan                                          # no rate for 10 % of samples
    pl = np.full(1000, 3.5 * DPS)                   # |error| = 3 deg/s: 2 breaches below
    pl[500:502] = 2.0 * DPS
    pl[600] = np.inf
    rep = build_report(_result(fl, ev, omega, pl=pl), fl, _cal(),
                       frames={"read": 3, "used": 2, "rejected": {"crc": 1}})
    assert rep["schema"] == REPORT_SCHEMA
    ts = [e["t"] for e in rep["events"]]
    assert ts == sorted(ts) and len(ts) == 7
    assert set(rep["events"][0]) >= {"t", "sensor", "type", "reason", "statistic", "threshold"}
    fa = [(e["t"], e["false_alarm"]) for e in rep["events"]]
    assert fa == [(1.0, True), (2.0, False), (2.03, False), (4.0, True), (6.5, False),
                  (7.0, False), (8.0, False)]
    s = rep["summary"]
    assert s["false_alarms"] == 2
    assert s["isolated_sensors"] == [2, 3, 5]
    np.testing.assert_allclose(s["detection_delay_s"], [0.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(s["isolation_delay_s"], [0.03, 1.0], atol=1e-12)
    # the first isolation after f2's onset names sensor 5: correct; f1: sensor 3: correct
    assert s["isolation_correct"] == [True, True]
    assert rep["faults"][0]["detection_delay_samples"] == 0
    assert rep["faults"][1]["detected_by"] == "parity scale 64"
    np.testing.assert_allclose(s["rate_error_rms_axis_dps"], [1.0, 2.0, 2.0], rtol=1e-9)
    np.testing.assert_allclose(s["rate_error_rms_dps"], np.sqrt(3.0), rtol=1e-9)
    np.testing.assert_allclose(s["rate_available_fraction"], 0.9)
    assert rep["frames"]["rejected"] == {"crc": 1}
    assert s["integrity_breaches"] == 2
    np.testing.assert_allclose(s["protection_level_median_dps"], 3.5)
    assert s["capability_at_end"] == "isolate"
    json.dumps(rep, allow_nan=False)                               # JSON-able as written
    text = format_report(rep)
    assert "false alarms: 2" in text and "FALSE ALARM" in text
    assert "fault step:3:15sigma:2: detected yes after 0 s" in text
    assert "rate error RMS: 1.732 deg/s" in text


def test_wrong_isolation_and_missed_fault():
    f1 = Fault("step", 3, 1e-3, 2.0, spec="a")
    f2 = Fault("step", 4, 1e-3, 9.0, spec="b")
    fl = _flight([f1, f2])
    ev = [Event(2.1, 1, "isolated", "parity scale 2", 50.0, 30.0)]
    s = build_report(_result(fl, ev), fl, _cal())["summary"]
    # a wrong isolation (healthy sensor 1) after f1's onset: f1 noticed, but mis-isolated;
    # it counts as a false alarm too (an alarm on a sensor without fault)
    np.testing.assert_allclose(s["detection_delay_s"][0], 0.1, atol=1e-12)
    assert s["detection_delay_s"][1] is None
    assert s["isolation_correct"] == [False, None]
    assert s["false_alarms"] == 1
    np.testing.assert_allclose(s["rate_error_rms_dps"], 0.0, atol=1e-15)


def test_isolation_of_another_fault_is_not_attributed():
    f1 = Fault("ramp", 5, 1e-4, 1.0, spec="ramp")
    f2 = Fault("dropout", 1, 0.0, 2.0, 0.5, spec="dropout")
    fl = _flight([f1, f2])
    ev = [Event(2.09, 1, "health", "stale", 0.1, 0.1)]
    rep = build_report(_result(fl, ev), fl, _cal())
    ramp, drop = rep["faults"]
    assert ramp["detected"] is False and ramp["isolated"] is False
    assert ramp["isolation_correct"] is None
    assert drop["isolation_correct"] is True
    np.testing.assert_allclose(drop["detection_delay_s"], 0.09, atol=1e-12)
    assert rep["summary"]["false_alarms"] == 0


def test_without_truth_false_alarms_unknown():
    fl = _flight([], omega_true=False)
    rep = build_report(_result(fl, [Event(1.0, None, "detected", "x", 1.0, 0.5)],
                               omega=np.zeros((1000, 3))), fl, _cal())
    assert rep["truth"] is False
    assert rep["summary"]["false_alarms"] is None
    assert rep["events"][0]["false_alarm"] is None
    assert rep["summary"]["rate_error_rms_dps"] is None
    assert "frames" not in rep
    # a simulated healthy flight (truth, no faults): every alarm is a false alarm
    fl2 = _flight([], truth={"schema": "rimu.flight-truth/1", "faults": []})
    rep2 = build_report(_result(fl2, [Event(5.0, 2, "isolated", "parity scale 1", 1, 0.5)]),
                        fl2, _cal())
    assert rep2["summary"]["false_alarms"] == 1
