"""ArduPilot DataFlash reader and ``rimu ingest`` on .BIN logs: written here and real."""

import json

import numpy as np
import pytest
from ingest_helpers import data_file, small_imu_data, write_dataflash

from fdi.errors import FileFormatError
from replay.flight_io import load_flight_dir
from replay.ingest import align_streams, read_any
from replay.ingest.ardupilot import read_ardupilot
from rimu.cli import main

ERLE = "erle_pxf_dual_imu"


@pytest.fixture
def two_imu_log(tmp_path):
    t, g, a = small_imu_data()
    p = tmp_path / "two.BIN"
    ends = write_dataflash(p, t, g, a)
    return p, t, g, a, ends


def test_reads_back_what_was_written(two_imu_log):
    p, t, g, a, _ = two_imu_log
    r = read_ardupilot(p)
    assert r.damage is None and [s.source for s in r.streams] == ["IMU", "IMU2"]
    for s, gk, ak in zip(r.streams, g, a, strict=True):
        np.testing.assert_allclose(s.t, t / 1000.0, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(s.gyro, gk)       # float32 values: exact
        np.testing.assert_array_equal(s.accel, ak)
        assert s.temperature is None


def test_instance_field_and_temperature(tmp_path):
    t, g, a = small_imu_data(n=50, k=3, seed=1)
    temps = [np.full(t.size, 30.5 + k) for k in range(3)]
    p = tmp_path / "new.bin"
    write_dataflash(p, t, g, a, instance_field=True, temps=temps)
    r = read_any(p)
    assert r.format == "ardupilot"
    assert [s.name for s in r.streams] == ["imu1", "imu2", "imu3"]
    assert [s.source for s in r.streams] == ["IMU[I=0]", "IMU[I=1]", "IMU[I=2]"]
    for k, s in enumerate(r.streams):
        np.testing.assert_allclose(s.t, t / 1000.0, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(s.gyro, g[k])
        np.testing.assert_array_equal(s.temperature, temps[k])


def test_cli_writes_flight_folder_and_report(two_imu_log, tmp_path, capsys):
    p, t, g, a, _ = two_imu_log
    out = tmp_path / "flight"
    assert main(["ingest", str(p), "--out", str(out)]) == 0
    f = load_flight_dir(out)
    assert f.sensor_names == ("imu1.x", "imu1.y", "imu1.z", "imu2.x", "imu2.y", "imu2.z")
    assert f.imu == ("imu1",) * 3 + ("imu2",) * 3
    assert f.raw_unit == "rad/s" and f.kind == "gyro"
    np.testing.assert_array_equal(f.raw, np.hstack(g))
    assert f.valid.all()
    assert f.sample_rate_hz == pytest.approx(50.0)
    acc = f.aux.select("accel")
    assert acc.names == ("imu1.x", "imu1.y", "imu1.z", "imu2.x", "imu2.y", "imu2.z")
    np.testing.assert_array_equal(acc.values, np.hstack(a))
    rep = json.loads((out / "ingest_report.json").read_text())
    assert rep["schema"] == "rimu.ingest-report/1" and rep["damage"] is None
    for imu in rep["imus"]:
        assert imu["samples_in"] == imu["kept"] == t.size
        assert imu["dropped"] == {} and imu["missing_on_base"] == 0
    assert "2 IMU(s)" in capsys.readouterr().out


def test_truncated_log_exit_2_then_salvage(two_imu_log, tmp_path, capsys):
    p, _, g, _, ends = two_imu_log
    data = p.read_bytes()
    cut = ends[149] + 10                # inside the IMU message of row 150
    bad = tmp_path / "cut.BIN"
    bad.write_bytes(data[:cut])
    out = tmp_path / "flight"
    assert main(["ingest", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert str(bad) in err and "truncated" in err and f"offset {ends[149]}" in err
    assert "--salvage keeps the 300 IMU samples" in err
    assert not out.exists()
    assert main(["ingest", str(bad), "--out", str(out), "--salvage"]) == 0
    f = load_flight_dir(out)
    assert f.t.shape[0] == 150
    np.testing.assert_array_equal(f.raw, np.hstack(g)[:150])
    rep = json.loads((out / "ingest_report.json").read_text())
    assert rep["salvaged"] and rep["damage"]["offset"] == ends[149]


def test_corrupt_bytes_in_the_middle(two_imu_log, tmp_path, capsys):
    p, _, g, _, ends = two_imu_log
    data = bytearray(p.read_bytes())
    start = ends[79] + 5                 # garbage inside row 80's first message
    data[start:start + 40] = b"\x00" * 40
    bad = tmp_path / "corrupt.BIN"
    bad.write_bytes(bytes(data))
    with pytest.raises(FileFormatError) as ei:
        read_ardupilot(bad)
    assert "corrupt" in str(ei.value) and str(bad) in str(ei.value)
    assert f"offset {ends[79]}" in str(ei.value)
    r = read_ardupilot(bad, salvage=True)
    # row 80 is lost (its IMU message holds the zeros, its IMU2 header is zeroed); the
    # reader resynchronises at row 81 and keeps every row after it
    assert [s.size for s in r.streams] == [199, 199]
    rows = np.r_[0:80, 81:200]
    np.testing.assert_array_equal(r.streams[1].gyro, g[1][rows])
    np.testing.assert_array_equal(r.streams[0].gyro, g[0][rows])
    (x,) = r.damage.stretches
    assert (x["start"], x["end"]) == (ends[79], ends[80])
    assert x["lost"]["imu_samples"] == {"imu1": 1, "imu2": 1}
    assert main(["ingest", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "corrupt" in capsys.readouterr().err


def test_not_a_log_and_no_imu(tmp_path, capsys):
    junk = tmp_path / "junk.BIN"
    junk.write_bytes(b"hello world" * 10)
    assert main(["ingest", str(junk), "--out", str(tmp_path / "o")]) == 2
    assert str(junk) in capsys.readouterr().err
    missing = tmp_path / "none.BIN"
    assert main(["ingest", str(missing), "--out", str(tmp_path / "o")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_misaligned_stamps_are_resampled_and_counted(two_imu_log):
    p, *_ = two_imu_log
    r = read_ardupilot(p)
    s2 = r.streams[1]
    from dataclasses import replace
    shifted = replace(s2, t=s2.t + 0.005)          # 5 ms later: between base samples
    dup = shifted.take(np.r_[np.arange(10), 9, np.arange(10, s2.size)])
    r2 = replace(r, streams=(r.streams[0], dup))
    f, rep = align_streams(r2, reference="imu1")
    im = rep["imus"][1]
    assert im["samples_in"] == s2.size + 1
    assert im["dropped"]["time stamp not increasing (duplicate or backwards)"] == 1
    assert im["kept"] == 0 and im["resampled_on_base"] == s2.size - 1
    assert im["missing_on_base"] == 1             # the first base time precedes imu2
    assert im["samples_in"] == (im["kept"] + im["used_for_resampling"]
                                + sum(im["dropped"].values()))
    # linear interpolation: base time k lies 15 ms after imu2 sample k-1, 5 ms before k
    want = 0.25 * s2.gyro[:-1] + 0.75 * s2.gyro[1:]
    np.testing.assert_allclose(f.raw[1:, 3:], want, rtol=0, atol=1e-12)
    assert not f.valid[0, 3:].any()


# -- the real logs ---------------------------------------------------------------------
def test_real_erle_41_reads_clean(tmp_path):
    p = data_file(ERLE, "pxf_copter_22-12-2014_41.BIN")
    r = read_ardupilot(p)
    assert r.damage is None
    assert [s.size for s in r.streams] == [6944, 6944]        # data README: 6,944 pairs
    np.testing.assert_array_equal(r.streams[0].t, r.streams[1].t)
    out = tmp_path / "f41"
    assert main(["ingest", str(p), "--out", str(out)]) == 0
    f = load_flight_dir(out)
    assert f.n == 6 and f.t.shape[0] == 6944 and f.valid.all()
    # the data README's observation: IMU1's mean acc_z (about -8 m/s², z down) is about
    # 2.4 m/s² smaller in magnitude than IMU2's
    acc = f.aux.select("accel").values
    assert np.mean(acc[:, 2]) - np.mean(acc[:, 5]) == pytest.approx(2.4, abs=0.1)


def test_real_erle_83_is_truncated_and_salvaged(tmp_path, capsys):
    p = data_file(ERLE, "pxf_copter_31-3-2015_83.BIN")
    out = tmp_path / "f83"
    assert main(["ingest", str(p), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "truncated" in err and "offset 1515993" in err
    assert main(["ingest", str(p), "--out", str(out), "--salvage"]) == 0
    f = load_flight_dir(out)
    assert f.t.shape[0] == 3933                                # README: 3,933 pairs
    assert f.t[-1] - f.t[0] == pytest.approx(118.7, abs=0.1)
    g = f.raw
    assert np.corrcoef(g[:, 0], g[:, 3])[0, 1] > 0.99          # README: corr 0.999


def _two_imu_cal(path):
    """A nominal calibration of two aligned IMUs (H = [I; I]) in rad/s."""
    from fdi.calfile import Calibration, SensorCal, SensorSet

    H = np.vstack([np.eye(3), np.eye(3)])
    names = [f"imu{k}.{ax}" for k in (1, 2) for ax in "xyz"]
    sens = tuple(SensorCal(name=nm, axis=h, axis_nominal=h, scale_factor=1.0,
                           scale_factor_sd=1e-4, bias=0.0, bias_sd=1e-3,
                           raw_unit="raw", scale_factor_unit="(rad/s)/raw", bias_unit="rad/s")
                 for nm, h in zip(names, H, strict=True))
    Calibration("two-imu", {"gyro": SensorSet("gyro", sens, np.eye(6) * 0.01 ** 2)},
                50.0).save(path)


def test_monitor_file_takes_the_folder(two_imu_log, tmp_path, capsys):
    p, *_ = two_imu_log
    out = tmp_path / "flight"
    assert main(["ingest", str(p), "--out", str(out)]) == 0
    _two_imu_cal(tmp_path / "cal.json")
    rep = tmp_path / "report.json"
    rc = main(["monitor-file", str(out), "--cal", str(tmp_path / "cal.json"),
               "--report", str(rep)])
    assert rc == 0, capsys.readouterr()
    doc = json.loads(rep.read_text())
    assert doc["schema"] == "rimu.report/1"


def test_declared_imu_that_logged_nothing_is_warned(tmp_path, capsys):
    from ingest_helpers import _fmt_msg

    t, g, a = small_imu_data(n=60, k=1)
    p = tmp_path / "one.BIN"
    write_dataflash(p, t, g, a)
    data = p.read_bytes()
    # the FMT of IMU2 declared (as an ArduPilot log with two IMUs does), no IMU2 sample
    p.write_bytes(_fmt_msg(0x82, "IMU2", "Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ")
                  + data)
    r = read_ardupilot(p)
    assert len(r.streams) == 1
    assert r.meta["warnings"] == ["the log's format declares IMU2 but holds no IMU2 sample "
                                  "(that IMU logged nothing)"]
    out = tmp_path / "o"
    assert main(["ingest", str(p), "--out", str(out)]) == 0
    assert "warning:" in capsys.readouterr().out
    rep = json.loads((out / "ingest_report.json").read_text())
    assert "IMU2" in rep["meta"]["warnings"][0]
