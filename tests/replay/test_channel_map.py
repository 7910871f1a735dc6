"""Channel maps: TOML validation, calibration check, and three J1939 IMUs as nine sensors."""

import numpy as np
import pytest
from can import Message

from fdi.calfile import Calibration, SensorCal, SensorSet
from fdi.errors import ConfigError, FileFormatError
from fdi.units import DPS
from replay.accounting import FrameAccounting
from replay.assemble import decode_frames
from replay.channel_map import (
    EXAMPLE_J1939_MAP,
    check_against_calibration,
    default_channel_map,
    load_channel_map,
)
from replay.frames import load_dbc
from replay.raw_frames import RawFrames
from replay.slot_checks import j1939_not_available

SAS = (0x80, 0x81, 0x82)


def _ari_frames(rates_dps, t, *, na=(), rng=None):
    """ARI frames (PGN 61482) of three IMUs; rates_dps (N, 3 IMUs, 3 fields pitch/roll/yaw).

    ``na``: (sample, imu, field, raw) to force a J1939 raw value (e.g. 0xFB00, 0xFFFF).
    """
    cmap = load_channel_map(EXAMPLE_J1939_MAP)
    db = load_dbc(cmap.dbc)
    msg = db.get_message_by_name("ARI")
    rng = rng or np.random.default_rng(0)
    forced = {(k, i, f): r for k, i, f, r in na}
    out = []
    for k in range(len(t)):
        for i, sa in enumerate(SAS):
            raw = {}
            for f, name in enumerate(("PitchRate", "RollRate", "YawRate")):
                r = forced.get((k, i, f))
                if r is None:
                    r = round((rates_dps[k, i, f] + 250.0) * 128)
                raw[name] = r
            raw.update(PitchRateFigureOfMerit=0, RollRateFigureOfMerit=0,
                       YawRateFigureOfMerit=0, RateMeasurementLatency=2)
            data = msg.encode(raw, scaling=False, strict=False)
            fid = (msg.frame_id & ~0xFF) | sa
            out.append(Message(timestamp=1.7e9 + t[k] + 2e-4 * i + rng.uniform(0, 1e-4),
                               arbitration_id=fid, is_extended_id=True, data=data,
                               channel=0))
    return out


def test_example_map_loads_nine_sensors_with_source_addresses():
    cmap = load_channel_map(EXAMPLE_J1939_MAP)
    assert cmap.n == 9 and cmap.j1939 and cmap.kind == "gyro"
    assert [s.source_address for s in cmap.sensors] == [a for a in SAS for _ in range(3)]
    assert [s.signal for s in cmap.sensors[:3]] == ["PitchRate", "RollRate", "YawRate"]
    np.testing.assert_allclose(cmap.sensors[0].axis_nominal, [0, 1, 0])


def test_j1939_not_available_ranges():
    r = np.array([0, 0xFAFF, 0xFB00, 0xFE00, 0xFFFF])
    np.testing.assert_array_equal(j1939_not_available(r, 16), [0, 0, 1, 1, 1])
    np.testing.assert_array_equal(j1939_not_available(np.array([0xFA, 0xFB, 0xFF]), 8),
                                  [0, 1, 1])


def test_three_j1939_imus_become_nine_sensors_and_not_available_is_missing():
    rng = np.random.default_rng(4)
    N = 200
    t = np.arange(N) / 100.0
    rates = rng.uniform(-200, 200, (N, 3, 3))
    na = [(10, 0, 1, 0xFB00), (11, 2, 2, 0xFFFF), (12, 1, 0, 0xFE00),
          (20, 1, 0, 0xFFFF), (20, 1, 1, 0xFFFF), (20, 1, 2, 0xFFFF)]  # last: whole frame NA
    msgs = _ari_frames(rates, t, na=na, rng=rng)
    # an IMU the map does not know (SA 0x83) and an unrelated standard frame
    stray = [Message(timestamp=1.7e9 + 0.5, arbitration_id=(msgs[0].arbitration_id & ~0xFF)
                     | 0x83, is_extended_id=True, data=msgs[0].data),
             Message(timestamp=1.7e9 + 0.6, arbitration_id=0x123, is_extended_id=False,
                     data=b"\x00" * 8)]
    allm = sorted(msgs + stray, key=lambda m: m.timestamp)
    cmap = load_channel_map(EXAMPLE_J1939_MAP)
    acct = FrameAccounting()
    s = decode_frames(RawFrames.from_messages(allm), load_dbc(cmap.dbc), cmap, acct,
                      sample_rate_hz=100.0)
    assert acct.balanced()
    assert acct.read == 3 * N + 2
    assert dict(acct.rejected) == {"unknown_id": 2, "j1939_not_available": 1}
    assert acct.used == 3 * N - 1
    assert acct.values_not_available == 3
    assert s.raw.shape == (N, 9)
    expect = rates.reshape(N, 9)
    # 1/128 °/s per bit: decoded within half a bit of the truth
    missing = {(10, 1), (11, 8), (12, 3), (20, 3), (20, 4), (20, 5)}
    for k in range(N):
        for j in range(9):
            if (k, j) in missing:
                assert not s.valid[k, j] and np.isnan(s.raw[k, j]), f"sample {k} sensor {j + 1}"
            else:
                assert s.valid[k, j], f"sample {k} sensor {j + 1}"
                assert abs(s.raw[k, j] - expect[k, j]) <= 0.5 / 128 + 1e-12
    np.testing.assert_allclose(s.t - s.t[0], t, atol=2e-4, err_msg="sample times")


def _cal9():
    axes = [[0, 1, 0], [1, 0, 0], [0, 0, 1]] * 3
    sens = tuple(SensorCal(name=f"g{i + 1}", axis=np.array(a, float),
                           axis_nominal=np.array(a, float), scale_factor=DPS,
                           scale_factor_sd=0.0, bias=0.0, bias_sd=0.0,
                           scale_factor_unit="(deg/s)/raw") for i, a in enumerate(axes))
    return Calibration("3imu", {"gyro": SensorSet("gyro", sens, np.eye(9) * 1e-6)}, 100.0)


def test_map_checked_against_calibration_axes_and_count():
    cmap = load_channel_map(EXAMPLE_J1939_MAP)
    cal = _cal9()
    check_against_calibration(cmap, cal)
    bad = _cal9()
    s = bad.gyro.sensors
    s2 = (s[1], s[0], *s[2:])
    bad = Calibration("x", {"gyro": SensorSet("gyro", s2, np.eye(9))}, 100.0)
    with pytest.raises(ConfigError, match="sensor 1"):
        check_against_calibration(cmap, bad)
    with pytest.raises(ConfigError, match="6 gyro sensors, the calibration 9"):
        check_against_calibration(default_channel_map(6), cal)


@pytest.mark.parametrize("text, field", [
    ('schema = "rimu.channel_map/2"', "schema"),
    ('schema = "rimu.channel_map/1"\n[[sensors]]\nsignal = "A"', "sensors[1].message"),
    ('schema = "rimu.channel_map/1"\n[[sensors]]\nmessage = "M"\nsignal = "A"\nunit = "furlong"',
     "sensors[1].unit"),
    ('schema = "rimu.channel_map/1"\nj1939 = true\n[[sensors]]\nmessage = "M"\nsignal = "A"',
     "sensors[1].source_address"),
    ('schema = "rimu.channel_map/1"\n[[sensors]]\nmessage = "M"\nsignal = "A"\n'
     'axis_nominal = [0, 0]', "sensors[1].axis_nominal"),
])
def test_bad_map_names_the_field(tmp_path, text, field):
    p = tmp_path / "m.toml"
    p.write_text(text)
    with pytest.raises(FileFormatError) as e:
        load_channel_map(p)
    assert e.value.field == field


def test_a_misspelt_key_is_refused_not_ignored(tmp_path):
    """Issue 10 regression: ``axis_nomnal`` was silently ignored, which switched off the
    check that sensor i of the map is sensor i of the calibration."""
    p = tmp_path / "m.toml"
    p.write_text('schema = "rimu.channel_map/1"\n[[sensors]]\nmessage = "M"\nsignal = "A"\n'
                 'axis_nomnal = [0, 0, 1]\n')
    with pytest.raises(FileFormatError) as e:
        load_channel_map(p)
    assert (e.value.field, e.value.line) == ("sensors[1].axis_nomnal", 5), str(e.value)
    assert "did you mean 'axis_nominal'?" in str(e.value)
    p.write_text('schema = "rimu.channel_map/1"\ntime_tolerence_s = 0.01\n'
                 '[[sensors]]\nmessage = "M"\nsignal = "A"\n')
    with pytest.raises(FileFormatError, match="did you mean 'time_tolerance_s'"):
        load_channel_map(p)
