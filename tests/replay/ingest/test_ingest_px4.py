"""PX4 ULog reader: files written here through pyulog's writer, and the real samples."""

import json

import numpy as np
import pytest
from ingest_helpers import data_file, write_ulog

from fdi.errors import FileFormatError
from replay.flight_io import load_flight_dir
from replay.ingest.px4 import read_px4
from rimu.cli import main

PX4 = "px4_ulog"


@pytest.fixture
def ulog(tmp_path):
    rng = np.random.default_rng(4)
    n = 120
    # three IMUs sampled every 4 ms, each with its own phase (0, 1, 2 ms)
    t = [np.arange(n, dtype=np.uint64) * 4000 + 1_000_000 + 1000 * k for k in range(3)]
    g = [rng.normal(0, 0.1, (n, 3)).astype(np.float32) for _ in range(3)]
    down = np.array([0.0, 0.0, -9.8])
    a = [(rng.normal(0, 0.1, (n, 3)) + down).astype(np.float32) for _ in range(3)]
    temps = [np.full(n, 30.0 + 5 * k, np.float32) for k in range(3)]
    p = tmp_path / "three.ulg"
    write_ulog(p, t, g, a, temps, [1310988, 1310996, 1311004])
    return p, t, g, a


def test_reads_instances_with_device_ids_and_temperature(ulog):
    p, t, g, a = ulog
    r = read_px4(p)
    assert r.format == "px4" and r.damage is None
    assert [s.device_id for s in r.streams] == [1310988, 1310996, 1311004]
    for k, s in enumerate(r.streams):
        np.testing.assert_allclose(s.t, t[k] * 1e-6, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(s.gyro, g[k].astype(float))
        np.testing.assert_array_equal(s.temperature, 30.0 + 5 * k)
        np.testing.assert_array_equal(s.accel, a[k].astype(float))   # same stamps
        np.testing.assert_array_equal(s.error_count, 0)


def test_ingest_resamples_other_phases(ulog, tmp_path):
    p, _, g, _ = ulog
    out = tmp_path / "f"
    assert main(["ingest", str(p), "--out", str(out)]) == 0
    f = load_flight_dir(out)
    rep = json.loads((out / "ingest_report.json").read_text())
    assert rep["time_base"]["reference"] == "imu1"
    assert f.sample_rate_hz == pytest.approx(250.0)
    im2 = rep["imus"][1]
    # imu2 is 1 ms late: every base time but the first lies between two of its samples
    assert im2["kept"] == 0 and im2["resampled_on_base"] == 119
    assert im2["missing_on_base"] == 1
    assert im2["samples_in"] == im2["used_for_resampling"] + sum(im2["dropped"].values())
    # base time k: 3 ms after imu2 sample k-1, 1 ms before sample k
    want = 0.25 * g[1][:-1].astype(float) + 0.75 * g[1][1:].astype(float)
    np.testing.assert_allclose(f.raw[1:, 3:6], want, rtol=0, atol=1e-7)
    temps = f.aux.select("temperature")
    assert temps.names == ("imu1", "imu2", "imu3")
    np.testing.assert_allclose(temps.values[1:], [[30.0, 35.0, 40.0]] * 119)


def test_truncated_ulog_exit_2_and_salvage(ulog, tmp_path, capsys):
    p, *_ = ulog
    data = p.read_bytes()
    bad = tmp_path / "cut.ulg"
    bad.write_bytes(data[:len(data) // 2 + 5])
    assert main(["ingest", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(bad) in err and "byte offset" in err
    r = read_px4(bad, salvage=True)
    full = read_px4(p)
    assert 0 < sum(s.size for s in r.streams) < sum(s.size for s in full.streams)
    for s, f in zip(r.streams, full.streams, strict=True):
        np.testing.assert_array_equal(s.gyro, f.gyro[:s.size])
    assert main(["ingest", str(bad), "--out", str(tmp_path / "o"), "--salvage"]) == 0


def test_corrupt_header_names_its_offset(ulog, tmp_path):
    p, *_ = ulog
    data = bytearray(p.read_bytes())
    at = len(data) // 2
    data[at:at + 30] = b"\xff" * 30
    bad = tmp_path / "bad.ulg"
    bad.write_bytes(bytes(data))
    with pytest.raises(FileFormatError, match="byte offset"):
        read_px4(bad)
    r = read_px4(bad, salvage=True)
    assert r.damage is not None and r.damage.offset <= at


def test_not_a_ulog(tmp_path, capsys):
    p = tmp_path / "x.ulg"
    p.write_bytes(b"ULog\x01\x12\x35" + b"\x00" * 3)
    assert main(["ingest", str(p), "--out", str(tmp_path / "o")]) == 2
    assert str(p) in capsys.readouterr().err


@pytest.mark.parametrize("name, temps", [
    ("sample_log_small.ulg", (40.0, 28.2, 29.6)),      # data README: 40, 28, 30 °C
    ("sample_logging_tagged_and_default_params.ulg", None)])
def test_real_ulog_samples(name, temps, tmp_path):
    p = data_file(PX4, name)
    r = read_px4(p)
    assert r.damage is None and len(r.streams) == 3
    assert len({s.device_id for s in r.streams}) == 3
    if temps is None:
        assert all(s.temperature is None for s in r.streams)      # SITL logs 0 °C
    else:
        got = [float(np.mean(s.temperature)) for s in r.streams]
        np.testing.assert_allclose(got, temps, atol=1.0)
    out = tmp_path / "f"
    assert main(["ingest", str(p), "--out", str(out)]) == 0
    f = load_flight_dir(out)
    assert f.n == 9 and f.imu == ("imu1",) * 3 + ("imu2",) * 3 + ("imu3",) * 3


def test_vehicle_imu_delta_angles_become_rates(tmp_path):
    from ingest_helpers import write_vehicle_imu_ulog

    rng = np.random.default_rng(8)
    n, dt = 80, 4000
    t = np.arange(n, dtype=np.uint64) * dt + 2_000_000
    w = [rng.normal(0, 0.5, (n, 3)) for _ in range(2)]
    f = [rng.normal(0, 1.0, (n, 3)) + np.array([0, 0, -9.8]) for _ in range(2)]
    p = tmp_path / "vimu.ulg"
    write_vehicle_imu_ulog(p, t, w, f, dt)
    r = read_px4(p)                                   # auto: no sensor_gyro in the log
    assert [s.source for s in r.streams] == ["vehicle_imu[0]", "vehicle_imu[1]"]
    assert [s.device_id for s in r.streams] == [100, 101]
    for s, wk, fk in zip(r.streams, w, f, strict=True):
        # float32 delta angles: relative error about 1e-7
        np.testing.assert_allclose(s.gyro, wk, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(s.accel, fk, rtol=1e-6, atol=1e-6)
    with pytest.raises(FileFormatError, match="no sensor_gyro data"):
        read_px4(p, topic="sensor_gyro")


def test_real_vehicle_imu_agrees_where_raw_sensor_gyro_does_not():
    p = data_file(PX4, "sample_log_small.ulg")
    raw = read_px4(p, topic="sensor_gyro")
    cal = read_px4(p, topic="vehicle_imu")
    assert [s.size for s in cal.streams] == [12, 12, 12]       # data README: 12 each
    assert [s.device_id for s in cal.streams] == [s.device_id for s in raw.streams]
    spread_raw = np.ptp([s.gyro.mean(axis=0) for s in raw.streams], axis=0)
    spread_cal = np.ptp([s.gyro.mean(axis=0) for s in cal.streams], axis=0)
    # sensor_gyro is logged before PX4's calibration: 3.5 °/s apart; vehicle_imu after it
    assert spread_raw.max() > np.radians(3.0) and spread_cal.max() < np.radians(0.5)


def test_declared_imu_that_logged_nothing_is_named(tmp_path, capsys):
    """Issue 18: an IMU instance the log subscribes to but that logged no sample (pyulog
    drops it) is named in a warning, at read and by rimu ingest; a full log has none."""
    rng = np.random.default_rng(5)
    n = 60
    t = [np.arange(n, dtype=np.uint64) * 4000 + 1_000_000 for _ in range(2)] \
        + [np.zeros(0, np.uint64)]
    g = [rng.normal(0, 0.1, (m.size, 3)).astype(np.float32) for m in t]
    down = np.array([0.0, 0.0, -9.8])
    a = [(rng.normal(0, 0.1, (m.size, 3)) + down).astype(np.float32) for m in t]
    temps = [np.full(m.size, 30.0, np.float32) for m in t]
    p = tmp_path / "silent.ulg"
    write_ulog(p, t, g, a, temps, [1, 2, 3])
    r = read_px4(p)
    assert [s.source for s in r.streams] == ["sensor_gyro[0]", "sensor_gyro[1]"]
    assert r.meta["warnings"] == ["the log subscribes to sensor_gyro[2] but holds no "
                                  "sensor_gyro[2] sample (that IMU logged nothing)"]
    assert main(["ingest", str(p), "--out", str(tmp_path / "f")]) == 0
    assert "sensor_gyro[2] sample (that IMU logged nothing)" in capsys.readouterr().out


def test_full_log_has_no_silent_imu_warning(ulog):
    assert "warnings" not in read_px4(ulog[0]).meta
