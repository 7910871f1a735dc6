"""The firmware a log names, carried by an in-flight calibration and compared on the next
flight (issue 27: "a lag that belongs to the firmware")."""

from __future__ import annotations

from dataclasses import replace

import pytest

from replay.firmware import (
    ULOG_INFO_SOURCE,
    firmware_change,
    firmware_of,
    px4_firmware_text,
)
from replay.log_events import LogEvent
from tests.replay.ingest.ingest_helpers import data_file


def _msg(text, source="MSG"):
    return LogEvent(1.0, 1.0, source, text)


@pytest.mark.parametrize(("text", "want"), [
    ("ArduCopter V3.3-dev (0a326f5a)", "ArduCopter V3.3-dev (0a326f5a)"),
    ("ArduCopter V4.1.0 (f2af3c7e)", "ArduCopter V4.1.0 (f2af3c7e)"),
    ("ArduPlane V4.3.2", "ArduPlane V4.3.2"),
    ("APM:Copter V3.2.1 (36b405fb)", "APM:Copter V3.2.1 (36b405fb)"),
])
def test_an_ardupilot_boot_message_names_the_firmware(text, want):
    events = (_msg("Frame: QUAD"), _msg(text), _msg("PX4v2 003F0035 3036510B"))
    assert firmware_of(events) == want, text


def test_other_messages_and_sources_name_no_firmware():
    events = (_msg("Frame: QUAD"), _msg("Initialising APM"), _msg("ERR CRASH_CHECK 1", "ERR"),
              _msg("ArduCopter V4.1.0 (f2af3c7e)", "logged_message"))
    assert firmware_of(events) == ""
    assert firmware_of(()) == ""


def test_a_reboot_into_another_build_gives_both():
    events = (_msg("ArduCopter V4.1.0 (aaaa1111)"), _msg("ArduCopter V4.1.0 (aaaa1111)"),
              _msg("ArduCopter V4.2.0 (bbbb2222)"))
    assert firmware_of(events) == "ArduCopter V4.1.0 (aaaa1111) | ArduCopter V4.2.0 (bbbb2222)"


def test_px4_info_fields_give_system_release_hash_and_hardware():
    info = {"sys_name": "PX4", "ver_sw_release": 0x010B0200,
            "ver_sw": "8583f1da30b63154d6ba0bc187d86135dfe33cf9",
            "ver_hw": "CUBEPILOT_CUBEORANGE"}
    assert px4_firmware_text(info) == "PX4 v1.11.2 8583f1da CUBEPILOT_CUBEORANGE"
    assert px4_firmware_text({"ver_sw_release": 0, "ver_sw": ""}) == ""
    assert px4_firmware_text({"ver_sw_release": "garbage", "ver_sw": "abc12345ff"}) == \
        "PX4 abc12345"
    ev = (LogEvent(0.0, 0.0, ULOG_INFO_SOURCE, px4_firmware_text(info)),)
    assert firmware_of(ev) == "PX4 v1.11.2 8583f1da CUBEPILOT_CUBEORANGE"


def test_a_change_is_one_line_naming_both_and_unknown_is_silent():
    w = firmware_change("ArduCopter V3.3-dev (bd817897)", "ArduCopter V3.3-dev (0a326f5a)")
    assert w is not None and "bd817897" in w and "0a326f5a" in w and "\n" not in w
    for a, b in (("x", "x"), ("", "x"), ("x", ""), ("", "")):
        assert firmware_change(a, b) is None, (a, b)


def test_the_calibration_file_keeps_the_firmware_and_reads_it_back():
    from fdi.extras.inflight import FlightIdentity

    fi = FlightIdentity("a.BIN", 10, 0.0, 1.0, "0123456789abcdef", "ArduCopter V4.1.0 (f2)")
    assert fi.to_dict()["firmware"] == "ArduCopter V4.1.0 (f2)"
    assert "firmware" not in replace(fi, firmware="").to_dict()   # old files stay as they were


def _two_flights():
    from replay.imu_set import ImuSetSpec, simulate_imu_set

    a = simulate_imu_set(ImuSetSpec(duration_s=60.0, seed=3))
    b = simulate_imu_set(ImuSetSpec(duration_s=70.0, seed=4))   # not "the same recording"
    return a, b


def test_the_next_flight_under_another_firmware_is_warned_first():
    """Calibrated in flight under one build, checked on a flight logged under another: the
    first warning names both builds; under the same build no firmware line."""
    from calibration.inflight import calibration_from_fit, fit_inflight
    from calibration.inflight.fits_flight import calibration_firmware, flight_mismatch
    from fdi.calfile import calibration_from_dict

    a, b = _two_flights()
    a = replace(a, events=(_msg("ArduCopter V4.1.0 (aaaa1111)"),))
    cal = calibration_from_dict(calibration_from_fit(fit_inflight(a), a).to_dict())
    assert calibration_firmware(cal) == "ArduCopter V4.1.0 (aaaa1111)"
    other = replace(b, events=(_msg("ArduCopter V4.2.0 (bbbb2222)"),))
    _, warnings = flight_mismatch(cal, other)
    assert warnings and "aaaa1111" in warnings[0] and "bbbb2222" in warnings[0], warnings
    same = replace(b, source="another-log.BIN", events=(_msg("ArduCopter V4.1.0 (aaaa1111)"),))
    checks, warnings = flight_mismatch(cal, same)
    assert checks, "the parameters were not checked (taken for the same power-up)"
    assert not any("firmware" in w for w in warnings), warnings


@pytest.mark.parametrize(("folder", "name", "want"), [
    ("erle_pxf_dual_imu", "pxf_copter_22-12-2014_41.BIN", "ArduCopter V3.3-dev (0a326f5a)"),
    ("erle_pxf_dual_imu", "pxf_copter_31-3-2015_83.BIN", "ArduCopter V3.3-dev (bd817897)"),
    ("px4_ulog", "sample_log_small.ulg", "PX4 v1.11.2 8583f1da CUBEPILOT_CUBEORANGE"),
])
def test_the_shared_logs_name_their_firmware(folder, name, want):
    """The two erle flights of one airframe ran two builds (the cross-flight misfit of
    docs/next-flight.md); the PX4 sample names its release, hash and board."""
    from replay.ingest import read_any

    read = read_any(data_file(folder, name), "auto", salvage=True)
    assert firmware_of(read.events) == want


def test_a_part_of_the_calibrated_log_under_another_firmware_is_another_power_up():
    """A part of the calibration's own log is its power-up; the same part whose log names
    another build cannot be (the check comes before the part-of-the-log rule)."""
    from calibration.inflight import calibration_from_fit, fit_inflight
    from replay.turn_on import same_power_up

    a, _ = _two_flights()
    a = replace(a, source="flight.BIN", events=(_msg("ArduCopter V4.1.0 (aaaa1111)"),))
    cal = calibration_from_fit(fit_inflight(a), a)
    n = a.t.shape[0]
    part = replace(a, t=a.t[: n // 2], raw=a.raw[: n // 2], valid=a.valid[: n // 2],
                   omega_true=None if a.omega_true is None else a.omega_true[: n // 2],
                   aux=None if a.aux is None else a.aux.slice(slice(0, n // 2)))
    assert same_power_up(cal, part) is True
    other = replace(part, events=(_msg("ArduCopter V4.2.0 (bbbb2222)"),))
    assert same_power_up(cal, other) is False
