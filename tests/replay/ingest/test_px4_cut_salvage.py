"""A ULog cut where one IMU has logged a single sample (issue 30): ``--salvage`` keeps what
precedes the cut, drops (and names) the IMU streams that cannot form a time base, and
refuses only when none can."""

from __future__ import annotations

import json

import numpy as np
import pytest
from ingest_helpers import data_file, write_ulog

from fdi.errors import ConfigError
from replay.ingest.align import align_streams
from replay.ingest.px4 import read_px4
from rimu.cli import main


@pytest.fixture(scope="module")
def cut_ulog(tmp_path_factory):
    """Three IMUs at 250 Hz, the third starting 0.2 s late; cut where it has one sample."""
    rng = np.random.default_rng(5)
    n = 100
    t = [np.arange(n, dtype=np.uint64) * 4000 + 1_000_000 + 1000 * k for k in range(3)]
    t[2] = t[2] + 200_000
    g = [rng.normal(0, 0.1, (n, 3)).astype(np.float32) for _ in range(3)]
    down = np.array([0.0, 0.0, -9.8])
    a = [(rng.normal(0, 0.1, (n, 3)) + down).astype(np.float32) for _ in range(3)]
    temps = [np.full(n, 30.0 + k, np.float32) for k in range(3)]
    d = tmp_path_factory.mktemp("ulog")
    whole = d / "whole.ulg"
    write_ulog(whole, t, g, a, temps, [1310988, 1310996, 1311004])
    data = whole.read_bytes()
    cut = d / "cut.ulg"
    for k in range(len(data) // 3, len(data)):
        cut.write_bytes(data[:k])
        sizes = [s.size for s in read_px4(cut, salvage=True).streams]
        if len(sizes) == 3 and sizes[2] == 1:
            return cut, sizes
    pytest.fail("no cut leaves the third IMU with one sample")


def test_salvage_drops_and_names_the_imu_without_a_time_base(cut_ulog):
    cut, sizes = cut_ulog
    assert sizes[0] > 2 and sizes[1] > 2
    flight, report = align_streams(read_px4(cut, salvage=True), salvage=True)
    assert [m["name"] for m in report["imus"]] == ["imu1", "imu2"]
    assert report["dropped_imus"] == [
        {
            "name": "imu3",
            "source": "sensor_gyro[2]",
            "samples": 1,
            "why": report["dropped_imus"][0]["why"],
        }
    ]
    assert len(report["warnings"]) == 1 and "imu3" in report["warnings"][0]
    assert flight.n == 6 and report["imus"][0]["kept"] == sizes[0]
    # a set that needs all three is refused, saying which cannot
    with pytest.raises(
        ConfigError,
        match=r"2 IMU stream\(s\) can form a time base, 3 "
        r"needed.*imu3 \(sensor_gyro\[2\], 1 sample",
    ):
        align_streams(read_px4(cut, salvage=True), salvage=True, min_imus=3)


def test_ingest_cli_warns_in_one_line_and_writes_the_json(cut_ulog, tmp_path, capsys):
    cut, _ = cut_ulog
    out = tmp_path / "flight"
    assert main(["ingest", str(cut), "--salvage", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    lines = [x for x in text.splitlines() if "cannot form a time base" in x]
    assert len(lines) == 1 and "imu3 (sensor_gyro[2], 1 sample(s))" in lines[0], text
    docs = [json.loads(p.read_text()) for p in out.glob("*.json")]
    assert any(d.get("dropped_imus", [{}])[0].get("name") == "imu3" for d in docs), docs


def test_real_log_cut_with_one_sample_per_imu_is_refused_naming_them(tmp_path):
    """sample_log_small.ulg cut after each IMU's first sample: nothing can form a time
    base; the refusal names every stream and its count."""
    data = data_file("px4_ulog", "sample_log_small.ulg").read_bytes()
    p = tmp_path / "cut.ulg"
    p.write_bytes(data[:184_000])
    read = read_px4(p, salvage=True)
    assert [s.size for s in read.streams] == [1, 1, 1]
    with pytest.raises(
        ConfigError,
        match=r"0 IMU stream\(s\) can form a time base, 1 "
        r"needed.*imu1 .*imu2 .*imu3 ",
    ):
        align_streams(read, salvage=True)
