"""One flipped byte anywhere in a DataFlash log costs at most the messages it touches plus
one (the message before a break in framing is distrusted: DataFlash has no checksum).
Seeded flips at many positions of a synthetic log, and message-id flips in a real one."""

import numpy as np
import pytest
from ingest_helpers import data_file, small_imu_data, write_dataflash

from fdi.errors import FileFormatError
from replay.ingest.ardupilot import read_ardupilot


def _read(path):
    try:
        return read_ardupilot(path)
    except FileFormatError:
        return read_ardupilot(path, salvage=True)


def _kept(full, r):
    """Per stream name: which samples of ``full`` (by time) ``r`` still holds."""
    out = {}
    got = {s.name: s for s in r.streams}
    for s in full.streams:
        g = got.get(s.name)
        out[s.name] = np.isin(s.t, g.t) if g is not None else np.zeros(s.size, bool)
    return out


def test_one_flipped_byte_costs_the_messages_it_touches_plus_one(tmp_path):
    t, g, a = small_imu_data(n=120)
    p = tmp_path / "two.BIN"
    ends = write_dataflash(p, t, g, a)
    full = read_ardupilot(p)
    clean = p.read_bytes()
    first = ends[0] - 2 * 31                          # the first IMU message (31 bytes each)
    rng = np.random.default_rng(30)
    positions = rng.integers(first, len(clean), 150)
    worst = 0
    for pos in positions:
        data = bytearray(clean)
        data[pos] ^= int(rng.integers(1, 256))
        bad = tmp_path / "flip.BIN"
        bad.write_bytes(bytes(data))
        r = _read(bad)
        kept = _kept(full, r)
        lost = sum(int((~k).sum()) for k in kept.values())
        touched = 1                                   # every byte here is in an IMU message
        worst = max(worst, lost)
        assert lost <= touched + 1, (int(pos), lost, r.damage and r.damage.stretches)
        # the samples kept are the originals, except at most the one message the byte is in
        altered = 0
        for s_full, s in zip(full.streams, r.streams, strict=True):
            i = np.clip(np.searchsorted(s_full.t, s.t), 0, s_full.size - 1)
            same = (s_full.t[i] == s.t) & np.all(s_full.gyro[i] == s.gyro, axis=1)
            altered += int((~same).sum())
        assert altered <= 1, int(pos)
        if r.damage is not None:
            assert r.damage.stretches, "damage is reported by stretch"
    assert worst >= 1, "some flips hit the framing"


def test_real_log_message_id_flip_keeps_the_rest(tmp_path):
    """Erle flight 41: a message id flipped to an unknown type at 97 % of the file (before:
    the rest of the log was lost, "56061 trailing bytes are no message")."""
    fraction = 0.97
    src = data_file("erle_pxf_dual_imu", "pxf_copter_22-12-2014_41.BIN")
    full = read_ardupilot(src)
    data = bytearray(src.read_bytes())
    from replay.ingest.ardupilot import _open, _scan

    o, ln, _ = _scan(_open(str(src)), bytes(data))
    k = int(np.searchsorted(o, int(fraction * len(data))))
    data[o[k] + 2] = 0xFE                             # no FMT defines type 254
    bad = tmp_path / "flip.BIN"
    bad.write_bytes(bytes(data))
    with pytest.raises(FileFormatError):
        read_ardupilot(bad)
    r = read_ardupilot(bad, salvage=True)
    kept = _kept(full, r)
    lost = sum(int((~m).sum()) for m in kept.values())
    assert lost <= 2, (lost, r.damage.stretches)
    (x,) = r.damage.stretches
    assert x["start"] <= o[k] < x["end"] <= o[k + 1] + ln[k + 1]
    assert sum(x["dropped_messages"].values()) <= 2


def test_flipped_sign_bits_in_values_are_marked_not_kept(tmp_path, capsys):
    """DataFlash has no checksum: a value whose sign bit flipped is read as a value. Where
    that is physically impossible (20 rad/s to -20 and back within one 20 ms sample: a jump
    larger than a 2000 deg/s gyro's full range) it is set to NaN, counted and reported; a
    flipped low mantissa bit is not (a few parts per million of the value: plausible)."""
    import json

    from replay.ingest import read_any
    from rimu.cli import main

    t, g, a = small_imu_data(n=120)
    rows = [17, 60, 100]
    for j in rows:
        g[0][j - 2:j + 3, 1] = 20.0      # a fast roll, 1146 deg/s
    p = tmp_path / "two.BIN"
    ends = write_dataflash(p, t, g, a)
    data = bytearray(p.read_bytes())
    for j in rows:                       # IMU message of row j, GyrY: its sign bit
        data[ends[j] - 62 + 3 + 4 + 4 + 3] ^= 0x80
    data[ends[30] - 62 + 3 + 4] ^= 0x01  # row 30 GyrX: lowest mantissa bit
    bad = tmp_path / "vals.BIN"
    bad.write_bytes(bytes(data))
    raw = read_ardupilot(bad)            # framing intact: the reader alone cannot tell
    assert raw.damage is None and np.all(raw.streams[0].gyro[rows, 1] == -20.0)
    r = read_any(bad)
    s = r.streams[0]
    assert np.isnan(s.gyro[rows, 1]).all() and not np.isnan(s.gyro[rows, 0]).any()
    ok = np.setdiff1d(np.arange(120), rows)
    np.testing.assert_array_equal(s.gyro[ok], raw.streams[0].gyro[ok])
    assert s.gyro[30, 0] != g[0][30, 0]                 # the mantissa flip: kept, plausible
    np.testing.assert_array_equal(r.streams[1].gyro, g[1])
    assert r.meta["implausible"] == {"imu1": {"gyro": {
        "samples": 3, "values": 3, "first_t_s": [float(s.t[j]) for j in rows]}}}
    out = tmp_path / "o"
    assert main(["ingest", str(bad), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "3 gyro sample(s) physically implausible" in text
    rep = json.loads((out / "ingest_report.json").read_text())
    assert rep["meta"]["implausible"]["imu1"]["gyro"]["samples"] == 3


def test_implausible_rule():
    from replay.ingest.plausible import GYRO_RANGE_RADPS as R
    from replay.ingest.plausible import implausible

    x = np.zeros((9, 3))
    x[2, 0] = 2.5 * R                    # beyond twice the range
    x[5, 1] = 1.2 * R                    # a one-sample spike larger than the range
    x[7:, 2] = 1.5 * R                   # a step (a real manoeuvre's edge): kept
    bad = implausible(x, R)
    assert sorted(map(tuple, np.argwhere(bad))) == [(2, 0), (5, 1)]


def test_no_implausible_sample_in_the_real_logs():
    """The rule flags nothing on the shared real logs (a crash at 600 deg/s included)."""
    from replay.ingest import read_any

    for folder, name in (("erle_pxf_dual_imu", "pxf_copter_22-12-2014_41.BIN"),
                         ("px4_ulog", "sample_log_small.ulg")):
        r = read_any(data_file(folder, name))
        assert "implausible" not in r.meta, (name, r.meta.get("implausible"))
