"""`rimu ingest` carries the log's own events into the flight folder: an ArduPilot log with
ERR/EV messages (no time field, as old logs write them) and a ULog with PX4's failure
detector set, each written here byte by byte, read through the product's readers."""

from __future__ import annotations

import json
import math
import struct

import numpy as np
import pytest
from ingest_helpers import _fmt_msg, _msg, small_imu_data

from replay.flight_io import load_flight_dir
from replay.ingest.px4 import read_px4
from rimu.cli import main


def _dataflash_with_events(path):
    t, gyros, accels = small_imu_data(300)
    fmt, cols = "Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"
    out = bytearray()
    out += _fmt_msg(0x81, "IMU", fmt, cols) + _fmt_msg(0x82, "IMU2", fmt, cols)
    out += _fmt_msg(0x83, "ERR", "BB", "Subsys,ECode") + _fmt_msg(0x84, "EV", "B", "Id")
    out += _fmt_msg(0x85, "MSG", "Z", "Message")
    out += _msg(0x85, "Z", [b"ArduCopter V3.3-dev"])
    extra = {50: [_msg(0x84, "B", [10])],                          # ARMED at 2.00 s
             100: [_msg(0x83, "BB", [16, 2])],                     # EKF bad variance
             150: [_msg(0x83, "BB", [16, 0])],                     # ... cleared
             200: [_msg(0x83, "BB", [12, 1])],                     # crash
             250: [_msg(0x84, "B", [10])]}                         # re-armed
    for j, tm in enumerate(t):
        for k in range(2):
            out += _msg(0x81 + k, fmt, [int(tm), *gyros[k][j], *accels[k][j]])
        for m in extra.get(j, []):
            out += m
    path.write_bytes(bytes(out))
    return t / 1000.0


def test_ardupilot_events_reach_the_flight_folder(tmp_path, capsys):
    log = tmp_path / "events.BIN"
    t = _dataflash_with_events(log)
    out = tmp_path / "f"
    assert main(["ingest", str(log), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    f = load_flight_dir(out)
    # an event takes the last IMU time before it; a span ends at the first IMU time after
    # its closing message
    want = [("ArduCopter V3.3-dev", "info", 0, 0), ("EV ARMED", "info", 50, 50),
            ("ERR EKFCHECK 2: bad variance", "estimator", 100, 151),
            ("ERR EKFCHECK 0: variance cleared", "info", 150, 150),
            ("ERR CRASH_CHECK 1: crash", "crash", 200, 251), ("EV ARMED", "info", 250, 250)]
    assert [(e.text, e.category) for e in f.events] == [w[:2] for w in want]
    np.testing.assert_allclose([(e.t_s, e.t_end_s) for e in f.events],
                               [(t[w[2]], t[w[3]]) for w in want], rtol=0, atol=1e-9)
    assert "1 crash, 1 estimator, 4 info" in printed
    assert "ERR CRASH_CHECK 1: crash (crash)" in printed
    report = json.loads((out / "ingest_report.json").read_text())
    assert report["events"]["by_category"] == {"crash": 1, "estimator": 1, "info": 4}
    # the declared crash (until re-armed, held 0.5 s) is what the envelope marks
    env = report["envelope"]
    assert [p["reasons"] for p in env["periods"]] == [["declared"]]
    p = env["periods"][0]
    assert p["t0_s"] == pytest.approx(t[200])
    assert p["t1_s"] == pytest.approx(t[276])           # re-armed at t[251], + hold 0.5 s


_VS_FMT = "vehicle_status:uint64_t timestamp;uint16_t failure_detector_status;bool failsafe;"


def test_px4_failure_detector_reaches_the_events(tmp_path):
    from ingest_helpers import write_ulog
    from pyulog import ULog

    n = 40
    t_us = 1_000_000 + 20_000 * np.arange(n)
    rng = np.random.default_rng(1)
    g = [rng.normal(0, 0.1, (n, 3)) for _ in range(2)]
    a = [rng.normal(0, 0.1, (n, 3)) + np.array([0, 0, -9.8]) for _ in range(2)]
    path = tmp_path / "x.ulg"
    write_ulog(path, [t_us, t_us], g, a, [np.full(n, 30.0)] * 2, [1, 2])
    u = ULog(str(path))
    hdr = ULog._MessageHeader()
    mf = ULog.MessageFormat(_VS_FMT.encode(), hdr)
    u._message_formats[mf.name] = mf
    add = ULog._MessageAddLogged(struct.pack("<BH", 0, 9) + b"vehicle_status", hdr,
                                 u._message_formats)
    rec = np.zeros(5, add.dtype)
    rec["timestamp"] = [1_000_000, 1_200_000, 1_400_000, 1_600_000, 1_700_000]
    rec["failure_detector_status"] = [0, 2, 2 | 32, 0, 32]   # pitch, then battery
    add.buffer = bytearray(rec.tobytes())
    u._data_list.append(ULog.Data(add))
    u.write_ulog(str(path))
    ev = read_px4(path).events
    crash = [e for e in ev if e.category == "crash"]
    assert [(e.t_s, e.t_end_s, e.text) for e in crash] == [
        (pytest.approx(1.2), pytest.approx(1.6), "failure detector: pitch")]
    info = [e for e in ev if e.category == "info"]
    assert [(e.t_s, e.t_end_s, e.text) for e in info] == [
        (pytest.approx(1.4), pytest.approx(1.6), "failure detector: battery"),
        (pytest.approx(1.7), math.inf, "failure detector: battery")]
