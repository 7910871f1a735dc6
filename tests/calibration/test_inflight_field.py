"""Every multi-IMU flight of ../shared/data gets a calibration from ``rimu calibrate
in-flight`` with its defaults (issue 27); the Xsens DOT units ingest through the documented
map ``docs/examples/xsens_dot.toml``. Skipped with the reason when the data are absent.

The fast and slow tests take a cut (one Xsens path, flight 83); all sixteen recordings run
with ``--campaign`` (``python studies/inflight_field.py`` prints the measured table).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from rimu.cli import main

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "replay" / "ingest"))
from ingest_helpers import data_file  # noqa: E402  (the shared data's one finder)

MAP = ROOT / "docs" / "examples" / "xsens_dot.toml"
XSENS = [("Horizontal", k) for k in range(1, 10)] + [("Vertical", k) for k in range(1, 6)]
ERLE = [("pxf_copter_22-12-2014_41.BIN", []), ("pxf_copter_31-3-2015_83.BIN", ["--salvage"])]


def _xsens(kind: str, k: int, out: Path) -> Path:
    files = [data_file(f"ansfl_4x_xsens_dot/{kind}/path_{k}", f"IMU_{j}.csv")
             for j in range(1, 5)]
    assert main(["ingest", *map(str, files), "--map", str(MAP), "--out", str(out)]) == 0
    return out


def _calibrated(folder: Path, out: Path) -> dict:
    assert main(["calibrate", "in-flight", str(folder), "--out", str(out)]) == 0
    return json.loads(out.read_text())


def test_xsens_map_joins_the_four_units(tmp_path: Path) -> None:
    d = _xsens("Horizontal", 1, tmp_path / "h1")
    man = json.loads((d / "manifest.json").read_text())
    rows = sum(1 for _ in open(data_file("ansfl_4x_xsens_dot/Horizontal/path_1", "IMU_1.csv"),
                               encoding="utf-8")) - 1
    assert man["samples"] == rows
    assert sorted(set(man["imu"])) == ["imu1", "imu2", "imu3", "imu4"]
    assert abs(man["sample_rate_hz"] - 120.0) < 0.1


def _check(doc: dict, imus: int) -> None:
    inflight = doc["extra"]["inflight"]
    assert len(inflight["imus"]) == imus - 1
    for rec in inflight["imus"].values():
        assert {p["status"] for p in rec["parameters"]} <= {"estimated", "held at prior"}
    assert all(np.all(np.isfinite(g["input_error_cov"])) for g in doc["sensors"]["gyro"])


@pytest.mark.slow
def test_xsens_vertical_1_is_calibrated_with_the_defaults(tmp_path: Path) -> None:
    """Vertical path 1 has the worst axes of the set (IMU3/IMU4 4-8 deg/s against <1):
    before issue 27 it was refused; now a calibration with findings naming them."""
    d = _xsens("Vertical", 1, tmp_path / "v1")
    doc = _calibrated(d, tmp_path / "v1.json")
    _check(doc, 4)
    assert any(x.startswith("imu3.") for x in doc["extra"]["inflight"]["findings"])


@pytest.mark.campaign
@pytest.mark.parametrize(("kind", "k"), XSENS)
def test_every_xsens_flight_is_calibrated(tmp_path: Path, kind: str, k: int) -> None:
    _check(_calibrated(_xsens(kind, k, tmp_path / "f"), tmp_path / "c.json"), 4)


@pytest.mark.campaign
@pytest.mark.parametrize(("name", "extra"), ERLE)
def test_every_erle_flight_is_calibrated(tmp_path: Path, name: str, extra: list) -> None:
    log = data_file("erle_pxf_dual_imu", name)
    assert main(["ingest", str(log), *extra, "--out", str(tmp_path / "f")]) == 0
    _check(_calibrated(tmp_path / "f", tmp_path / "c.json"), 2)
