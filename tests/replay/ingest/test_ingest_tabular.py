"""CSV, MATLAB and R data through the rimu.ingest-map/1 map: written here and real."""

import json

import numpy as np
import pytest
import scipy.io
from ingest_helpers import data_file

from fdi.errors import FileFormatError
from fdi.units import DPS, G0
from replay.flight_io import load_flight_dir
from replay.ingest import read_any
from replay.ingest.ingest_map import load_ingest_map
from rimu.cli import main

MAP_CSV = """schema = "rimu.ingest-map/1"
format = "csv"
[time]
column = "ms"
unit = "ms"
[[imus]]
name = "left"
gyro = ["gx1", "gy1", "gz1"]
gyro_unit = "deg/s"
accel = ["ax1", "ay1", "az1"]
accel_unit = "g"
temperature = "temp1"
[[imus]]
name = "right"
gyro = ["gx2", "gy2", "gz2"]
gyro_unit = "rad/s"
"""


def _csv(tmp_path, n=100, seed=0):
    rng = np.random.default_rng(seed)
    v = np.round(rng.normal(0, 1, (n, 10)), 6)
    ms = 10 * np.arange(n)
    head = "ms,gx1,gy1,gz1,ax1,ay1,az1,temp1,gx2,gy2,gz2"
    lines = [head] + [",".join([str(int(m)), *(f"{x:.6f}" for x in row)])
                      for m, row in zip(ms, v, strict=True)]
    p = tmp_path / "log.csv"
    p.write_text("\n".join(lines) + "\n")
    mp = tmp_path / "map.toml"
    mp.write_text(MAP_CSV)
    return p, mp, ms, v


def test_csv_through_map_units_and_names(tmp_path):
    p, mp, ms, v = _csv(tmp_path)
    out = tmp_path / "f"
    assert main(["ingest", str(p), "--map", str(mp), "--out", str(out)]) == 0
    f = load_flight_dir(out)
    assert f.sensor_names[:3] == ("left.x", "left.y", "left.z")
    np.testing.assert_allclose(f.t, ms / 1000.0)
    np.testing.assert_allclose(f.raw[:, :3], v[:, :3] * DPS, rtol=1e-15)
    np.testing.assert_allclose(f.raw[:, 3:], v[:, 7:10], rtol=1e-15)
    acc = f.aux.select("accel")
    np.testing.assert_allclose(acc.values, v[:, 3:6] * G0, rtol=1e-15)
    np.testing.assert_allclose(f.aux.select("temperature").values[:, 0], v[:, 6])


def test_csv_short_line_exit_2_and_salvage(tmp_path, capsys):
    p, mp, _, v = _csv(tmp_path)
    lines = p.read_text().splitlines()
    lines[61] = lines[61][:12]                       # data row 61 cut short: file line 62
    p.write_text("\n".join(lines) + "\n")
    assert main(["ingest", str(p), "--map", str(mp), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"{p}:62" in err and "expected 11" in err
    assert main(["ingest", str(p), "--map", str(mp), "--out", str(tmp_path / "o"),
                 "--salvage"]) == 0
    f = load_flight_dir(tmp_path / "o")
    assert f.t.shape[0] == 99                        # the cut line dropped, the rest kept
    np.testing.assert_allclose(f.raw[:, 3:], np.delete(v, 61 - 1, axis=0)[:, 7:10])
    rep = json.loads((tmp_path / "o" / "ingest_report.json").read_text())
    (x,) = rep["damage"]["stretches"]
    assert x["line"] == 62 and x["lost"] == {"lines": 1}


def test_csv_bad_cell_names_line_and_column(tmp_path):
    p, mp, *_ = _csv(tmp_path)
    lines = p.read_text().splitlines()
    cells = lines[11].split(",")
    cells[4] = "x1.5"
    lines[11] = ",".join(cells)
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(FileFormatError, match=r"log.csv:12.*'x1.5' is not a number.*'ax1'"):
        read_any(p, map_path=mp)
    r = read_any(p, map_path=mp, salvage=True)
    assert [s.size for s in r.streams] == [99, 99]
    assert r.damage.samples_before == 2 * 10 and r.damage.samples_after == 2 * 89


def test_map_errors_name_field_and_line(tmp_path):
    mp = tmp_path / "m.toml"
    mp.write_text(MAP_CSV.replace('gyro_unit = "deg/s"', 'gyro_unit = "dps"'))
    with pytest.raises(FileFormatError, match=r"m.toml:9.*imus\[1\].gyro_unit"):
        load_ingest_map(mp)
    mp.write_text(MAP_CSV.replace("temperature =", "temprature ="))
    with pytest.raises(FileFormatError, match="temperature"):
        load_ingest_map(mp)
    p, *_ = _csv(tmp_path)
    mp.write_text(MAP_CSV.replace('"gz2"', '"gz9"'))
    with pytest.raises(FileFormatError, match="no column 'gz9'"):
        read_any(p, map_path=mp)


def test_mat_structs_without_map(tmp_path):
    rng = np.random.default_rng(2)
    n = 300
    t = np.arange(n) * 0.02
    files = []
    for k in range(2):
        w = rng.normal(0, 0.01, (n, 3))
        fb = rng.normal(0, 0.1, (n, 3))
        p = tmp_path / f"imu{k + 1}_raw.mat"
        scipy.io.savemat(p, {f"imu{k + 1}_raw": {"t": t[:, None], "wb": w, "fb": fb}})
        files.append((p, w, fb))
    out = tmp_path / "f"
    assert main(["ingest", *(str(p) for p, *_ in files), "--out", str(out)]) == 0
    f = load_flight_dir(out)
    assert f.imu == ("imu1",) * 3 + ("imu2",) * 3
    np.testing.assert_array_equal(f.raw, np.hstack([files[0][1], files[1][1]]))
    rep = json.loads((out / "ingest_report.json").read_text())
    assert "units assumed SI" in rep["imus"][0]["notes"][0]


def test_mat_with_map_and_damaged_mat(tmp_path, capsys):
    n = 50
    g = np.arange(3 * n, dtype=float).reshape(n, 3)
    p = tmp_path / "bench.mat"
    scipy.io.savemat(p, {"gyro_dps": g, "time_us": np.arange(n) * 10_000})
    mp = tmp_path / "m.toml"
    mp.write_text('schema = "rimu.ingest-map/1"\n[time]\ncolumn = "time_us"\nunit = "us"\n'
                  '[[imus]]\ngyro = "gyro_dps"\ngyro_unit = "deg/s"\n')
    r = read_any(p, map_path=mp)
    np.testing.assert_allclose(r.streams[0].gyro, g * DPS)
    np.testing.assert_allclose(r.streams[0].t, np.arange(n) * 0.01)
    bad = tmp_path / "cut.mat"
    bad.write_bytes(p.read_bytes()[:300])
    assert main(["ingest", str(bad), "--map", str(mp), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "no samples to salvage" in err


def test_rda_data_frame_with_map(tmp_path, capsys):
    import pandas as pd
    import rdata

    rng = np.random.default_rng(3)
    v = rng.normal(0, 1, (200, 6))
    cols = ["Gyro. X", "Gyro. Y", "Gyro. Z", "Accel. X", "Accel. Y", "Accel. Z"]
    p = tmp_path / "imu.rda"
    rdata.write_rda(p, {"adis": pd.DataFrame(v, columns=cols)})
    mp = tmp_path / "m.toml"
    mp.write_text('schema = "rimu.ingest-map/1"\n[time]\nrate_hz = 100.0\n[[imus]]\n'
                  'gyro = ["Gyro. X", "Gyro. Y", "Gyro. Z"]\ngyro_unit = "deg/s"\n'
                  'accel = ["Accel. X", "Accel. Y", "Accel. Z"]\naccel_unit = "g"\n')
    out = tmp_path / "f"
    assert main(["ingest", str(p), "--map", str(mp), "--out", str(out)]) == 0
    f = load_flight_dir(out)
    np.testing.assert_allclose(f.raw, v[:, :3] * DPS, rtol=1e-15)
    np.testing.assert_allclose(f.t, np.arange(200) / 100.0)
    assert f.sample_rate_hz == pytest.approx(100.0)
    assert main(["ingest", str(p), "--out", str(tmp_path / "o")]) == 2
    assert "carry no units" in capsys.readouterr().err


# -- the real files --------------------------------------------------------------------
def test_real_erle_csv_equals_the_bin():
    csv = data_file("erle_pxf_dual_imu", "pxf_41_imu_imu2.csv")
    bin_ = data_file("erle_pxf_dual_imu", "pxf_copter_22-12-2014_41.BIN")
    a, b = read_any(csv), read_any(bin_)
    for s, u in zip(a.streams, b.streams, strict=True):
        np.testing.assert_allclose(s.t, u.t, atol=1e-9)
        np.testing.assert_allclose(s.gyro, u.gyro, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(s.accel, u.accel, rtol=1e-6, atol=1e-9)


def test_real_four_mpu9250(tmp_path):
    files = [data_file("multi_imu_4x_mpu9250", f"imu{k}_raw.mat") for k in (1, 2, 3, 4)]
    out = tmp_path / "f"
    assert main(["ingest", *map(str, files), "--out", str(out)]) == 0
    f = load_flight_dir(out)
    assert f.t.shape[0] == 41671 and f.n == 12 and f.valid.all()    # README: 41671 × 3
    assert f.t[-1] == pytest.approx(967.975, abs=1e-3)
    acc = f.aux.select("accel").values.reshape(-1, 4, 3)
    norm = np.linalg.norm(acc.mean(axis=0), axis=1)
    # README: IMU1 |f| = 8.00 m/s², IMU2-4 9.66-9.82 m/s²
    assert norm[0] == pytest.approx(8.00, abs=0.02)
    assert np.all((norm[1:] > 9.6) & (norm[1:] < 9.85))


def test_real_adis16405_rda(tmp_path):
    p = data_file("smac_adis16405", "adis_16405_imu1.rda")
    mp = tmp_path / "m.toml"
    mp.write_text('schema = "rimu.ingest-map/1"\nformat = "rda"\n[time]\nrate_hz = 100.0\n'
                  '[[imus]]\ngyro = ["Gyro. X", "Gyro. Y", "Gyro. Z"]\ngyro_unit = "deg/s"\n'
                  'accel = ["Accel. X", "Accel. Y", "Accel. Z"]\naccel_unit = "g"\n')
    r = read_any(p, map_path=mp)
    assert r.meta["attributes"]["freq"] == [100.0]
    s = r.streams[0]
    assert s.size == 1_000_000
    # README: means [0.40, -0.42, -0.29] deg/s, accel z -1.016 g
    np.testing.assert_allclose(s.gyro.mean(axis=0) / DPS, [0.40, -0.42, -0.29], atol=0.01)
    assert s.accel[:, 2].mean() / G0 == pytest.approx(-1.016, abs=0.002)


def test_csv_imu_at_half_rate_is_resampled_and_counted(tmp_path):
    n = 101
    rng = np.random.default_rng(11)
    fast = rng.normal(0, 0.1, (n, 3))
    t = np.arange(n) * 10                                     # ms
    slow_rows = np.arange(0, n, 2)                            # imu2 every other row
    slow = rng.normal(0, 0.1, (slow_rows.size, 3))
    lines = ["time_ms,imu1_gyr_x_rps,imu1_gyr_y_rps,imu1_gyr_z_rps,"
             "imu2_gyr_x_rps,imu2_gyr_y_rps,imu2_gyr_z_rps"]
    for i in range(n):
        two = (",".join(f"{v:.9f}" for v in slow[i // 2]) if i % 2 == 0 else ",,")
        lines.append(f"{t[i]}," + ",".join(f"{v:.9f}" for v in fast[i]) + "," + two)
    p = tmp_path / "rates.csv"
    p.write_text("\n".join(lines) + "\n")
    out = tmp_path / "f"
    assert main(["ingest", str(p), "--out", str(out)]) == 0   # rimu's column naming
    f = load_flight_dir(out)
    rep = json.loads((out / "ingest_report.json").read_text())
    im2 = rep["imus"][1]
    assert rep["time_base"]["reference"] == "imu1"
    assert im2["samples_in"] == slow_rows.size and im2["kept"] == slow_rows.size
    assert im2["resampled_on_base"] == n // 2 and im2["missing_on_base"] == 0
    assert "50 rows with no gyro value" in im2["notes"][-1]
    np.testing.assert_allclose(f.raw[::2, 3:], slow, atol=1e-9)
    np.testing.assert_allclose(f.raw[1::2, 3:], 0.5 * (slow[:-1] + slow[1:]), atol=1e-9)
