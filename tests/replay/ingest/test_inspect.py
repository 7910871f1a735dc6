"""``rimu inspect LOG``: the streams, rates, durations, gaps, events and damage of a log,
printed before anything is written; on synthetic logs (known truth) and the shared ones."""

import json

import numpy as np
from ingest_helpers import data_file, small_imu_data, write_dataflash
from test_ingest_tabular import MAP_CSV

from replay.ingest.inventory import inventory
from rimu.cli import main


def _listing(d):
    return sorted(p.name for p in d.iterdir())


def test_synthetic_dataflash_with_a_gap_a_duplicate_and_a_damaged_message(tmp_path, capsys):
    t, g, a = small_imu_data(n=200)                    # 20 ms steps: 50 Hz
    t = t.copy()
    t[120:] += 1000                                    # a 1 s gap after sample 119 (50 lost)
    t[150] = t[149]                                    # a duplicate stamp
    p = tmp_path / "two.BIN"
    ends = write_dataflash(p, t, g, a)
    data = bytearray(p.read_bytes())
    data[ends[59] - 62 + 2] = 0xFE                     # row 60's IMU message: unknown id
    p.write_bytes(bytes(data))
    before = _listing(tmp_path)
    inv = inventory(p)
    i1, i2 = inv["imus"]
    assert (i1["name"], i1["source"], i2["source"]) == ("imu1", "IMU", "IMU2")
    # row 60's IMU message, and the one before it (row 59's IMU2: distrusted); the lost
    # sample and the step after the duplicate stamp (40 ms) are gaps too
    assert i1["samples"] == i2["samples"] == 199
    assert abs(i2["sample_rate_hz"] - 50.0) < 1e-9
    for d in (i1, i2):
        assert d["gaps"]["count"] == 3 and d["gaps"]["missing_samples"] == 52
    assert abs(i2["gaps"]["longest_s"] - 1.02) < 1e-9
    assert i2["duplicate_stamps"] == 1 and i2["backward_stamps"] == 0
    assert abs(i2["duration_s"] - (t[-1] - t[0]) / 1000) < 1e-9
    assert inv["damage"] is not None and inv["damage"]["stretches"]
    assert main(["inspect", str(p)]) == 0
    out = capsys.readouterr().out
    assert "imu2 (IMU2): 199 samples at 50 Hz" in out
    assert "3 gap(s) (52 samples missing, longest 1.020 s" in out
    assert "1 duplicate time stamp(s)" in out and "needs --salvage" in out
    assert _listing(tmp_path) == before, "inspect writes nothing"
    assert main(["inspect", str(p), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["schema"] == "rimu.inventory/1" and len(doc["imus"]) == 2


def test_csv_with_map(tmp_path, capsys):
    n = 100
    rng = np.random.default_rng(0)
    v = np.round(rng.normal(0, 1, (n, 10)), 6)
    ms = 10 * np.arange(n)
    lines = ["ms,gx1,gy1,gz1,ax1,ay1,az1,temp1,gx2,gy2,gz2"] + [
        ",".join([str(int(m)), *(f"{x:.6f}" for x in row)]) for m, row in zip(ms, v,
                                                                             strict=True)]
    p = tmp_path / "log.csv"
    p.write_text("\n".join(lines) + "\n")
    mp = tmp_path / "map.toml"
    mp.write_text(MAP_CSV)
    assert main(["inspect", str(p), "--map", str(mp)]) == 0
    out = capsys.readouterr().out
    assert "2 IMU stream(s)" in out and "100 samples at 100 Hz" in out
    assert "gyro + accel, temperature" in out


def test_shared_logs(capsys):
    inv = inventory(data_file("erle_pxf_dual_imu", "pxf_copter_31-3-2015_83.BIN"))
    assert [d["source"] for d in inv["imus"]] == ["IMU", "IMU2"]
    assert all(abs(d["sample_rate_hz"] - 50) < 1 for d in inv["imus"])
    assert inv["damage"] is not None                   # the log is cut at its end
    assert inv["events"]["by_category"].get("estimator", 0) >= 1
    assert any("IMU3" in w for w in inv["warnings"])
    ulg = data_file("px4_ulog", "sample_log_small.ulg")
    inv = inventory(ulg)
    assert len(inv["imus"]) == 3 and all(d["device_id"] for d in inv["imus"])
    assert all(d["temperature"] and d["accel"] for d in inv["imus"])
    mat = data_file("multi_imu_4x_mpu9250", "imu1_raw.mat")
    assert main(["inspect", str(mat), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)["imus"][0]
    assert d["samples"] == 41671 and abs(d["duration_s"] - 968.0) < 0.1
