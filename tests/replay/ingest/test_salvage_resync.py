"""``ingest --salvage`` resynchronises: one damaged stretch in the middle of a log loses
only what it holds, every intact sample after it is kept, and the loss is reported
exactly (byte range or lines, IMU samples per stream)."""

import json

import numpy as np
import pytest
from ingest_helpers import small_imu_data, write_dataflash, write_ulog

from fdi.errors import FileFormatError
from replay.ingest import read_any
from replay.ingest.ardupilot import read_ardupilot
from replay.ingest.px4 import read_px4
from rimu.cli import main


@pytest.fixture
def dataflash(tmp_path):
    t, g, a = small_imu_data(n=200)
    p = tmp_path / "two.BIN"
    ends = write_dataflash(p, t, g, a)
    return p, t, g, ends


def test_ardupilot_flipped_sync_byte_loses_one_message(dataflash, tmp_path, capsys):
    p, _, g, ends = dataflash
    data = bytearray(p.read_bytes())
    data[ends[99]] ^= 0xFF                   # the IMU message of row 100: sync byte
    bad = tmp_path / "flip.BIN"
    bad.write_bytes(bytes(data))
    with pytest.raises(FileFormatError, match="damaged sync bytes"):
        read_ardupilot(bad)
    r = read_ardupilot(bad, salvage=True)
    rows = np.r_[0:100, 101:200]
    np.testing.assert_array_equal(r.streams[0].gyro, g[0][rows])
    np.testing.assert_array_equal(r.streams[1].gyro, g[1])      # IMU2 loses nothing
    (x,) = r.damage.stretches
    assert (x["start"], x["end"], x["bytes"]) == (ends[99], ends[99] + 31, 31)
    assert x["lost"]["imu_samples"] == {"imu1": 1, "imu2": 0}
    out = tmp_path / "o"
    assert main(["ingest", str(bad), "--out", str(out), "--salvage"]) == 0
    text = capsys.readouterr().out
    assert f"bytes {ends[99]}-{ends[99] + 31} (31 bytes)" in text
    assert "imu1 1, imu2 0 IMU samples" in text
    rep = json.loads((out / "ingest_report.json").read_text())
    assert rep["damage"]["stretches"][0]["start"] == ends[99]


def test_ardupilot_garbage_run_keeps_every_row_after_it(dataflash, tmp_path):
    p, _, g, ends = dataflash
    data = bytearray(p.read_bytes())
    a, b = ends[120] + 7, ends[123] + 2      # inside row 121's IMU message to row 124's
    data[a:b] = bytes(range(1, 1 + b - a))   # bytes that hold no sync pair
    bad = tmp_path / "junk.BIN"
    bad.write_bytes(bytes(data))
    r = read_ardupilot(bad, salvage=True)
    # rows 121-123 hold junk; row 124's IMU message lost its sync bytes, its IMU2 is intact
    kept = (np.r_[0:121, 125:200], np.r_[0:121, 124:200])
    for s, gk, k in zip(r.streams, g, kept, strict=True):
        np.testing.assert_array_equal(s.gyro, gk[k])
    (x,) = r.damage.stretches
    assert x["start"] == ends[120] and x["end"] == ends[123] + 31
    assert x["lost"]["imu_samples"] == {"imu1": 4, "imu2": 3}
    assert r.damage.samples_before == 2 * 121
    assert r.damage.samples_after == 75 + 76


@pytest.fixture
def ulog(tmp_path):
    rng = np.random.default_rng(4)
    n = 120
    t = [np.arange(n, dtype=np.uint64) * 4000 + 1_000_000 + 1000 * k for k in range(3)]
    g = [rng.normal(0, 0.1, (n, 3)).astype(np.float32) for _ in range(3)]
    down = np.array([0.0, 0.0, -9.8])
    a = [(rng.normal(0, 0.1, (n, 3)) + down).astype(np.float32)
         for _ in range(3)]
    temps = [np.full(n, 30.0, np.float32) for _ in range(3)]
    p = tmp_path / "three.ulg"
    write_ulog(p, t, g, a, temps, [1, 2, 3])
    return p


@pytest.mark.parametrize("shift", [0, 35, 42, 49])
def test_ulog_16_flipped_bytes_keep_what_pyulog_recovers_and_more(ulog, tmp_path, shift):
    """A corrupt header whose size runs past the rest stops pyulog itself; the reader
    skips to the next chain of valid messages. A corrupt message id pyulog drops and
    resynchronises over. Either way every intact gyro sample is kept."""
    full = read_px4(ulog)
    data = bytearray(ulog.read_bytes())
    at = len(data) // 2 + shift
    for i in range(16):
        data[at + i] ^= 0xFF
    bad = tmp_path / "bad.ulg"
    bad.write_bytes(bytes(data))
    try:
        clean = read_px4(bad)
    except FileFormatError:
        clean = None
    if clean is not None:                     # the flips hit sample values only
        pytest.skip("these bytes hold values, not framing: nothing to resynchronise")
    r = read_px4(bad, salvage=True)
    assert r.damage.stretches
    for x in r.damage.stretches:
        assert x["start"] <= at + 16 and x["end"] >= at - 45 and x["bytes"] > 0
    lost = r.damage.stretches[0]["lost"]["imu_samples"]
    for s, f in zip(r.streams, full.streams, strict=True):
        assert s.size + lost[s.name] == f.size
        idx = np.searchsorted(f.t, s.t)
        np.testing.assert_array_equal(f.t[idx], s.t)
        np.testing.assert_array_equal(f.gyro[idx], s.gyro)
    assert sum(lost.values()) <= 1              # one 45-byte message holds one sample


def test_csv_line_cut_in_half_drops_only_that_line(tmp_path, capsys):
    n = 100
    rng = np.random.default_rng(0)
    g = np.round(rng.normal(0, 0.1, (n, 3)), 6)
    lines = ["time_ms,imu1_gyr_x_rps,imu1_gyr_y_rps,imu1_gyr_z_rps"] + [
        f"{10 * k},{x:.6f},{y:.6f},{z:.6f}" for k, (x, y, z) in enumerate(g)]
    lines[41] = lines[41][:len(lines[41]) // 2]          # data row 40 cut in half
    lines[70] = lines[70].replace(",", ",x", 1)          # row 69: a cell not a number
    p = tmp_path / "log.csv"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(FileFormatError, match=r"log.csv:42"):
        read_any(p)
    r = read_any(p, salvage=True)
    keep = np.setdiff1d(np.arange(n), [40, 69])
    np.testing.assert_allclose(r.streams[0].gyro, g[keep])
    st = r.damage.stretches
    assert [(x["line"], x["lost"]["lines"]) for x in st] == [(42, 1), (71, 1)]
    assert main(["ingest", str(p), "--out", str(tmp_path / "o"), "--salvage"]) == 0
    out = capsys.readouterr().out
    assert "line 42:" in out and "line 71:" in out and "lost 1 line(s)" in out
