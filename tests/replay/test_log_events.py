"""Log events: ArduPilot ERR/EV/MSG and PX4 flags into LogEvent spans, the flight folder's
``events`` list (round trip, precise errors), and the declared intervals the envelope uses."""

from __future__ import annotations

import json
import math
import re
from types import SimpleNamespace

import numpy as np
import pytest

from fdi.errors import FileFormatError
from replay.flight_data import Flight
from replay.flight_io import load_flight_dir, save_flight_dir
from replay.ingest.ardupilot import ardupilot_events
from replay.ingest.px4 import px4_events
from replay.log_events import LogEvent, declared_intervals, flag_intervals


def _err(tb, ta, sub, code):
    return [tb, ta, "ERR", {"Subsys": sub, "ECode": code}]


def _ev(tb, ta, i):
    return [tb, ta, "EV", {"Id": i}]


def test_ardupilot_crash_lasts_until_rearmed_and_ekf_until_cleared():
    raw = [[math.nan, 1.0, "MSG", {"Message": "ArduCopter V3.3 "}],
           _ev(1.0, 1.0, 10), _ev(2.0, 2.1, 28),
           _err(5.0, 5.1, 16, 2), _err(7.0, 7.1, 16, 0),
           _err(9.0, 9.2, 12, 1), _ev(9.0, 30.0, 10),          # re-armed after a pause
           _err(40.0, 40.1, 17, 1),                            # never resolved
           _err(41.0, 41.1, 24, 1), _ev(42.0, 42.1, 21), _ev(43.0, 43.1, 22),
           _err(44.0, 44.1, 6, 1)]
    ev = ardupilot_events(raw)
    assert ev[0] == LogEvent(1.0, 1.0, "MSG", "ArduCopter V3.3")      # time after when none before
    ekf = [e for e in ev if e.text.startswith("ERR EKFCHECK 2")]
    assert ekf == [LogEvent(5.0, 7.1, "ERR", "ERR EKFCHECK 2: bad variance", 2, "estimator")]
    crash = [e for e in ev if e.category == "crash"]
    assert [(e.text, e.t_s, e.t_end_s) for e in crash] == [
        ("ERR CRASH_CHECK 1: crash", 9.0, 30.0),      # ends at the first IMU time after ARMED
        ("EV FLIP_START", 42.0, 43.1)]
    fs = next(e for e in ev if "FAILSAFE_EKFINAV" in e.text)
    assert fs.category == "estimator" and fs.t_end_s == math.inf
    assert next(e for e in ev if "EKF_PRIMARY" in e.text).category == "estimator"
    assert next(e for e in ev if "FAILSAFE_BATT" in e.text).category == "info"
    # by default only crashes are declared out of the envelope
    assert [d.reason for d in declared_intervals(ev)] == ["ERR CRASH_CHECK 1: crash",
                                                          "EV FLIP_START"]
    assert len(declared_intervals(ev, ("crash", "estimator"))) == 5


def test_flag_intervals():
    t = np.arange(8.0)
    f = np.array([0, 1, 1, 0, 4, 6, 2, 2])
    assert flag_intervals(t, f) == [(1.0, 3.0, 1), (4.0, math.inf, 6)]
    assert flag_intervals(t, f, 4) == [(4.0, 6.0, 4)]


def _data(name, **cols):
    return SimpleNamespace(name=name, multi_id=0, data={k: np.asarray(v) for k, v in
                                                         cols.items()})


def test_px4_failure_detector_and_estimator_flags():
    u = SimpleNamespace(
        data_list=[_data("vehicle_status", timestamp=[0, 1_000_000, 2_000_000, 3_000_000],
                         failure_detector_status=[0, 1, 33, 0], failsafe=[0, 0, 1, 1]),
                   _data("estimator_status", timestamp=[0, 500_000, 900_000],
                         filter_fault_flags=[0, 2, 0])],
        logged_messages=[SimpleNamespace(timestamp=1_500_000, message="[commander] x ")])
    ev = px4_events(u)
    crash = [e for e in ev if e.category == "crash"]
    assert [(e.t_s, e.t_end_s, e.text) for e in crash] == [(1.0, 3.0,
                                                            "failure detector: roll")]
    assert any(e.text == "failure detector: battery" and e.category == "info" for e in ev)
    est = [e for e in ev if e.category == "estimator"]
    assert [(e.t_s, e.t_end_s, e.code) for e in est] == [(0.5, pytest.approx(0.9), 2)]
    assert any(e.source == "vehicle_status.failsafe" and e.t_end_s == math.inf for e in ev)
    assert any(e.text == "[commander] x" for e in ev)
    assert [e.t_s for e in ev] == sorted(e.t_s for e in ev)


def _flight(events=()):
    t = np.arange(5) / 10.0
    return Flight(t=t, raw=np.zeros((5, 3)), valid=np.ones((5, 3), bool),
                  sample_rate_hz=10.0, sensor_names=("imu1.x", "imu1.y", "imu1.z"),
                  raw_unit="rad/s", imu=("imu1",) * 3, events=tuple(events))


def test_events_round_trip_through_the_flight_folder(tmp_path):
    ev = (LogEvent(0.1, 0.3, "ERR", "ERR CRASH_CHECK 1: crash", 1, "crash"),
          LogEvent(0.2, math.inf, "ERR", "ERR EKFCHECK 2: bad variance", 2, "estimator"),
          LogEvent(0.2, 0.2, "EV", "EV ARMED", 10))
    save_flight_dir(_flight(ev), tmp_path)
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["schema"] == "rimu.flight/1" and man["events"][1]["t_end"] is None
    assert load_flight_dir(tmp_path).events == ev
    save_flight_dir(_flight(), tmp_path)                  # none: no key, still loads
    assert "events" not in json.loads((tmp_path / "manifest.json").read_text())
    assert load_flight_dir(tmp_path).events == ()


@pytest.mark.parametrize(("bad", "field"), [
    ({"events": {}}, "events"),
    ({"events": [{"t": "x"}]}, "events[0].t"),
    ({"events": [{"t": 1.0, "t_end": 0.5}]}, "events[0].t_end"),
    ({"events": [{"t": 1.0, "category": "oops"}]}, "events[0].category"),
    ({"events": [{"t": 1.0, "code": 1.5}]}, "events[0].code"),
    ({"events": [{"t": 1.0, "colour": "red"}]}, "events[0].colour"),
])
def test_bad_events_are_refused_naming_the_field(tmp_path, bad, field):
    save_flight_dir(_flight(), tmp_path)
    man = json.loads((tmp_path / "manifest.json").read_text())
    man.update(bad)
    (tmp_path / "manifest.json").write_text(json.dumps(man))
    with pytest.raises(FileFormatError, match=re.escape(f"field '{field}'")):
        load_flight_dir(tmp_path)


def test_shared_ulogs_give_their_messages_and_no_declared_event():
    """The shared ULogs are short samples: vehicle_status and estimator_status exist with
    every flag clear, so only the logged text messages come out (category info), after the
    firmware the log names at its start (replay.firmware)."""
    from replay.ingest.px4 import read_px4
    from tests.calibration._erle import SHARED

    path = SHARED / "px4_ulog" / "sample_log_small.ulg"
    if not path.exists():
        pytest.skip(f"{path} not found (set RIMU_SHARED_DATA)")
    read = read_px4(path)
    assert [e.text for e in read.events] == ["PX4 v1.11.2 8583f1da CUBEPILOT_CUBEORANGE",
                                             "[commander] Takeoff detected",
                                             "[commander] Landing detected",
                                             "[commander] Disarmed by landing"]
    assert {e.category for e in read.events} == {"info"}
    assert read.events[0].source == "ulog.info"
    assert read.events[0].t_s == pytest.approx(20.309082)
    assert read.events[1].t_s == pytest.approx(22.683736)
