"""``rimu replay``: same events as Monitor.run on the flight's samples, injection, strictness."""

import json

import numpy as np
import pytest
from test_logio import CAL

from fdi.monitor import Monitor
from replay.can_write import write_flight_log
from replay.faults import parse_fault
from replay.flight import simulate_flight
from rimu.cli import main


@pytest.fixture(scope="module")
def cal_path(tmp_path_factory):
    p = tmp_path_factory.mktemp("cal") / "cal.json"
    CAL.save(p)
    return p


def _report(path):
    return json.loads(path.read_text())


@pytest.mark.parametrize("suffix", [".log", ".blf"])
def test_replay_gives_the_events_of_monitor_run_on_the_same_samples(tmp_path, cal_path,
                                                                    suffix):
    faults = (parse_fault("step:3:40sigma:2", CAL), parse_fault("ramp:5:2sigma/s:4", CAL))
    f = simulate_flight(CAL, 8.0, seed=21, faults=faults)
    ref = Monitor(CAL).run(f.t, f.raw, f.valid)
    assert len(ref.events) >= 2
    log = tmp_path / f"f{suffix}"
    write_flight_log(f, log)
    rep = tmp_path / "r.json"
    assert main(["replay", str(log), "--cal", str(cal_path), "--report", str(rep),
                 "--no-progress"]) == 0
    d = _report(rep)
    assert d["schema"] == "rimu.report/1"
    got = [(e["sensor"], e["type"], e["reason"]) for e in d["events"]]
    assert got == [(e.sensor, e.type, e.reason) for e in ref.events]
    np.testing.assert_allclose([e["t"] for e in d["events"]], [e.t for e in ref.events],
                               atol=1e-6, err_msg="event times")
    fr = d["frames"]
    assert fr["read"] == fr["used"] == int(f.valid.sum()) and fr["rejected"] == {}
    assert d["truth"] and d["summary"]["isolation_correct"][0] is True
    assert d["summary"]["detection_delay_s"][0] is not None


def test_inject_scenario_into_a_clean_log(tmp_path, cal_path, capsys):
    f = simulate_flight(CAL, 4.0, seed=22)
    log = tmp_path / "clean.asc"
    write_flight_log(f, log)
    scen = tmp_path / "s.toml"
    scen.write_text('schema = "rimu.scenario/1"\n[[faults]]\nsensor = 6\nkind = "step"\n'
                    'size = "50sigma"\nonset = 1.5\n')
    rep = tmp_path / "r.json"
    assert main(["replay", str(log), "--cal", str(cal_path), "--inject", str(scen),
                 "--report", str(rep), "--no-progress"]) == 0
    d = _report(rep)
    assert d["summary"]["isolated_sensors"] == [6]
    assert d["faults"][0]["kind"] == "step" and d["faults"][0]["isolation_correct"]
    assert 0 <= d["summary"]["detection_delay_s"][0] < 0.5
    assert d["summary"]["false_alarms"] == 0
    assert "isolated" in capsys.readouterr().out


def test_corrupt_log_reports_and_strict_fails(tmp_path, cal_path, capsys):
    f = simulate_flight(CAL, 2.0, seed=23)
    log = tmp_path / "a.log"
    write_flight_log(f, log)
    lines = log.read_text().splitlines()
    lines.insert(50, "garbage")
    lines[100] = lines[100][:-3] + ("0" if lines[100][-3] != "0" else "1") + lines[100][-2:]
    bad = tmp_path / "bad.log"
    bad.write_text("\n".join(lines) + "\n")
    (tmp_path / "bad.log.truth.json").write_text((tmp_path / "a.log.truth.json").read_text())
    rep = tmp_path / "r.json"
    assert main(["replay", str(bad), "--cal", str(cal_path), "--report", str(rep),
                 "--no-progress"]) == 0
    fr = _report(rep)["frames"]
    assert fr["rejected"] == {"garbage_line": 1, "crc": 1} and fr["balanced"]
    assert main(["replay", str(bad), "--cal", str(cal_path), "--strict",
                 "--no-progress"]) == 2
    assert "rimu: error:" in capsys.readouterr().err


def test_truncated_blf_warns_keeps_and_strict_fails(tmp_path, cal_path, capsys):
    f = simulate_flight(CAL, 3.0, seed=24)
    log = tmp_path / "a.blf"
    write_flight_log(f, log)
    b = log.read_bytes()
    log.write_bytes(b[: 2 * len(b) // 3])
    rep = tmp_path / "r.json"
    assert main(["replay", str(log), "--cal", str(cal_path), "--report", str(rep),
                 "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "warning" in err and "truncated" in err
    d = _report(rep)
    assert 0 < d["samples"] < f.t.size and d["frames"]["errors"][0]["kind"] == "truncated"
    assert main(["replay", str(log), "--cal", str(cal_path), "--strict",
                 "--no-progress"]) == 2


def test_replay_with_rrd(tmp_path, cal_path):
    f = simulate_flight(CAL, 1.0, seed=25)
    log = tmp_path / "a.trc"
    write_flight_log(f, log)
    rrd = tmp_path / "a.rrd"
    rep = tmp_path / "r.json"
    assert main(["replay", str(log), "--cal", str(cal_path), "--rrd", str(rrd),
                 "--report", str(rep), "--no-progress"]) == 0
    assert rrd.stat().st_size > 10_000
    assert _report(rep)["timing_s"]["rerun"] > 0


def test_replay_three_j1939_imus_with_the_example_map(tmp_path):
    """Three J1939 ARI gyros (nine sensors) through the shipped example DBC and map."""
    import can

    from fdi.calfile import Calibration, SensorCal, SensorSet
    from fdi.units import DPS
    from replay.channel_map import EXAMPLE_J1939_MAP, load_channel_map
    from replay.frames import load_dbc

    cmap = load_channel_map(EXAMPLE_J1939_MAP)
    axes = [s.axis_nominal for s in cmap.sensors]
    sd_dps = 0.05
    sens = tuple(SensorCal(name=s.name, axis=a, axis_nominal=a, scale_factor=DPS,
                           scale_factor_sd=0.0, bias=0.0, bias_sd=0.0,
                           scale_factor_unit="(deg/s)/raw", raw_unit="raw")
                 for s, a in zip(cmap.sensors, axes, strict=True))
    cal = Calibration("3imu-j1939", {"gyro": SensorSet("gyro", sens,
                                                       (sd_dps * DPS) ** 2 * np.eye(9))},
                      100.0)
    calp = tmp_path / "cal.json"
    cal.save(calp)
    rng = np.random.default_rng(31)
    N = 300
    t = np.arange(N) / 100.0
    w = 20.0 * np.sin(2 * np.pi * 0.5 * t)[:, None] * np.array([1.0, -0.5, 0.3])
    true = np.array([w[:, [1, 0, 2]]] * 3).transpose(1, 0, 2).reshape(N, 9)  # pitch,roll,yaw
    meas = true + sd_dps * rng.standard_normal((N, 9))
    meas[t >= 1.5, 4] += 40 * sd_dps            # imu2 roll: 40-sigma step at 1.5 s
    msg = load_dbc(cmap.dbc).get_message_by_name("ARI")
    log = tmp_path / "j.blf"
    with can.Logger(str(log)) as wr:
        for k in range(N):
            for imu, sa in enumerate((0x80, 0x81, 0x82)):
                raw = {n: round((meas[k, 3 * imu + j] + 250.0) * 128)
                       for j, n in enumerate(("PitchRate", "RollRate", "YawRate"))}
                if k == 100 and imu == 2:
                    raw["YawRate"] = 0xFFFF   # not available
                raw.update(PitchRateFigureOfMerit=0, RollRateFigureOfMerit=0,
                           YawRateFigureOfMerit=0, RateMeasurementLatency=2)
                wr.on_message_received(can.Message(
                    timestamp=1.767e9 + t[k] + 3e-4 * imu, is_extended_id=True,
                    arbitration_id=(msg.frame_id & ~0xFF) | sa,
                    data=msg.encode(raw, scaling=False, strict=False)))
    rep = tmp_path / "r.json"
    assert main(["replay", str(log), "--cal", str(calp), "--map", str(EXAMPLE_J1939_MAP),
                 "--report", str(rep), "--no-progress"]) == 0
    d = _report(rep)
    fr = d["frames"]
    assert fr["read"] == fr["used"] == 3 * N and fr["values_not_available"] == 1
    assert d["samples"] == N
    assert d["summary"]["isolated_sensors"] == [5]
    first = d["events"][0]
    assert first["sensor"] == 5 and 1.5 <= first["t"] < 1.6


def test_realtime_replay_prints_events_as_they_happen_and_matches(tmp_path, cal_path, capsys):
    f = simulate_flight(CAL, 1.0, seed=26, faults=(parse_fault("step:1:60sigma:0.4", CAL),))
    log = tmp_path / "rt.log"
    write_flight_log(f, log)
    r1, r2 = tmp_path / "a.json", tmp_path / "b.json"
    assert main(["replay", str(log), "--cal", str(cal_path), "--report", str(r1),
                 "--no-progress"]) == 0
    capsys.readouterr()
    import time
    t0 = time.monotonic()
    assert main(["replay", str(log), "--cal", str(cal_path), "--report", str(r2),
                 "--realtime", "--no-progress"]) == 0
    assert time.monotonic() - t0 >= 0.95, "paced at the recorded rate"
    out = capsys.readouterr().out
    a, b = _report(r1), _report(r2)
    assert a["events"] == b["events"] and a["events"]
    assert out.index("isolated") < out.index("events:"), "printed before the summary"
