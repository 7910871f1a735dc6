"""The typed extras write the JSON the calibration writers wrote (:meth:`to_dict`).

Three checks, all cheap:

- the two files in ``tests/fdi/data`` (written by rimu's writers before the types wrote
  themselves, see ``test_extras.py``): read into types and written back, every key in the same
  place and order, strings, booleans and integers equal, numbers equal to 1e-15 relative (a
  number in deg/h or ms goes to SI and back, which may move its last bit);
- records built in SI with values whose unit conversions are exact: written and read back,
  equal (``extras_from_dict(x.to_dict()) == x``), and the JSON equal to the literal the
  writers produce;
- :func:`fdi.extras.replace_extras` keeps a key's place and writes empty entries.

That the writers themselves still write the same bytes is checked on 20 files (turntable,
Ferraris, in-flight, static, refit, presets) by ``tests/calibration/_extras_identity.py``,
run by hand on two commits (minutes, and it needs ../shared/data).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from fdi.extras import (
    INFLIGHT_LAYOUT,
    STATIC_LAYOUT,
    TURNTABLE_LAYOUT,
    CalibrationExtras,
    DriftAttribution,
    EarthRateRecord,
    FerrarisRecord,
    FlightIdentity,
    GyroBias,
    ImuAlignment,
    ImuTiming,
    InflightAlignment,
    InflightTiming,
    LeftOut,
    Method,
    NoiseFit,
    NoiseModel,
    OffsetCheck,
    OffsetConsistency,
    OffsetPiece,
    OwnDrift,
    RateTest,
    ResidualStep,
    StaticAlignment,
    StaticImu,
    extras_from_dict,
    replace_extras,
)
from fdi.fileio import to_jsonable
from fdi.units import DEG, DPH, DPS

DATA = Path(__file__).parent / "data"


def _same(a: Any, b: Any, where: str = "extra") -> None:
    """``a`` and ``b`` are the same JSON: keys in the same order, numbers to 1e-15."""
    assert type(a) is type(b) or {type(a), type(b)} <= {int, float}, where
    if isinstance(a, dict):
        assert list(a) == list(b), where
        for k in a:
            _same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{k}]")
    elif isinstance(a, float) and not (math.isnan(a) and math.isnan(b)):
        assert math.isclose(a, b, rel_tol=1e-15, abs_tol=0.0), (where, a, b)
    elif not isinstance(a, float):
        assert a == b, where


@pytest.mark.parametrize(("name", "layout"), [("turntable", TURNTABLE_LAYOUT),
                                              ("inflight", INFLIGHT_LAYOUT)])
def test_old_writers_extra_is_written_back_by_the_types(name, layout):
    extra = json.loads((DATA / f"calibration3_{name}.json").read_text("utf-8"))["extra"]
    _same(to_jsonable(extras_from_dict(extra).to_dict(layout)), extra)


def _nan_free() -> CalibrationExtras:
    """Every typed entry set, numbers whose deg/h, deg, deg/s and ms forms are exact."""
    check = OffsetCheck(
        sd_s=0.5e-3, sd_hac_s=0.25e-3, sd_bootstrap_s=0.5e-3, sd_pieces_s=0.125e-3, block_s=2.0,
        pieces=(OffsetPiece(0.0, 10.0, 0.25e-3, 0.5e-3, model="full"),
                OffsetPiece(10.0, 20.0, None, None, note="too little yaw")),
        consistency=OffsetConsistency(0.25e-3, 0.5e-3, 0.5e-3, 1.0, 1, 1.0, 0.5, 0.01, 2),
        consistent=True, widened=True, sign="tau: imu at t matches the reference at t + tau")
    return CalibrationExtras(
        inflight=InflightTiming(
            reference="imu1", time_offset_sign="sign", flight=FlightIdentity(
                "f.BIN", 100, 0.0, 1.0, "0123456789abcdef"),
            imus={"imu2": ImuTiming(0.5e-3, 0.25e-3, 0.0, 0.0, check)}),
        inflight_alignment=InflightAlignment(
            imus={"imu2": ImuAlignment(
                model="full", A=((1.0, 0.0, 0.0),) * 3, A_sd=((0.5, 0.5, 0.5),) * 3,
                rotation=(0.5, 0.0, 0.25), rotation_sd=(0.5,) * 3, scale=(0.0,) * 3,
                scale_sd=(0.5,) * 3, nonorthogonality=(0.0,) * 3, nonorthogonality_sd=(0.5,) * 3,
                bias=(2.0 * DPH, 0.0, -1.0 * DPH), bias_sd=(0.5 * DPH,) * 3,
                residual_rms=(0.5 * DPS,) * 3, residual_lag1_autocorrelation=(0.5,) * 3,
                hac_lags=3, samples=90, excitation={"rank": 12}, notes=("a note",))},
            left_out=(LeftOut(1.0, 2.0, "shock", "one"),), samples_used=90, samples=100,
            samples_nonfinite=0),
        warnings=("a warning",), source="session", method=Method(parts={"gyro": "g"}),
        static=StaticAlignment(
            reference="imu1", imus={"imu2": StaticImu(
                rotation=(0.5 * DEG, 0.0, 0.0), rotation_sd=(1.0 * DEG,) * 3,
                relative_bias=(0.5 * DPS,) * 3, relative_drift=(0.25 * DPS,) * 3,
                relative_drift_sd=(0.5 * DPS,) * 3, relative_drift_z=(0.5,) * 3,
                relative_drift_p=(0.5,) * 3, drift_block_s=30.0, drift_hac_lags=4)},
            drift_attribution=DriftAttribution(
                common=(0.25 * DPS,) * 3, common_sd=(0.5 * DPS,) * 3, common_p=0.5,
                consistent_chi2=1.0, consistent_dof=3, consistent_p=0.5,
                own={"imu2": OwnDrift((0.25 * DPS,) * 3, (0.5,) * 3, 0.5)}, statement="s"),
            notes=("n",), alpha=0.01, bias=(0.5 * DPS,) * 6, bias_sd=(0.25 * DPS,) * 6,
            samples=100, duration_s=1.0, alignment_full=True),
        noise_model=NoiseModel("white", {"gyro": NoiseFit(sd_factor={"bias": (1.0,) * 4})}),
        rate_test=RateTest(((1, 2),), ((0.5, 0.0, 0.0),), (1.0,)),
        step_residual_chi2_dof=(1.0, 0.5),
        residual_steps={"gyro": (ResidualStep(1, "r1", "rate", 10, (0.5,), (1.0,)),)},
        earth_rate_fit=EarthRateRecord(15.0 * DPH, 0.5 * DPH, 10.0 * DPH, 0.5 * DPH, 2.0 * DEG,
                                       1.0 * DEG, (1, 3), (15.0 * DPH,), 0.5 * DPH, 1000, True),
        gyro_bias=GyroBias("deg/h", (2.0 * DPH,), (0.5 * DPH,), (1.0 * DPH,), (0.5 * DPH,),
                           (1, 3), (2, 2), (0.25 * DPH,)),
        parity_sd={"gyro": ((0.5, 0.25, 0.5, 0.25),), "accel": ()},
        ferraris=FerrarisRecord(-360.0 * DEG, 9.81, 1.0 * DEG, 1.0 * DEG, True, 49.5 * DEG,
                                ((0.5,) * 3,) * 3, ((0.25,) * 3,) * 3,
                                {"accel": (1.0,) * 3, "gyro": (0.5,) * 3}, 2, 0,
                                {"gyro": {"K": [[1.0]]}}))


def test_every_typed_entry_reads_back_what_it_writes():
    x = _nan_free()
    doc = to_jsonable(x.to_dict())
    assert list(doc) == ["earth_rate_fit", "ferraris", "gyro_bias", "inflight", "method",
                         "noise_model", "parity_accel_calibrated_sd", "parity_calibrated_sd",
                         "rate_test", "residual_steps", "source", "static",
                         "step_residual_chi2_dof", "warnings"]
    assert extras_from_dict(json.loads(json.dumps(doc))) == x


def test_records_write_the_writers_json():
    x = _nan_free()
    doc = to_jsonable(x.to_dict())
    assert doc["gyro_bias"] == {"unit": "deg/h", "model": [2.0], "model_sd": [0.5],
                                "turns": [1.0], "turns_sd": [0.5], "turns_steps": [1, 3],
                                "turns_per_step": [2, 2], "vertical_correction": [0.25]}
    assert doc["noise_model"] == {"method": "white",
                                  "gyro": {"applied": False, "sd_factor": {"bias": [1.0] * 4}}}
    assert doc["residual_steps"] == {"unit": {"gyro": "rad/s", "accel": "m/s^2"},
                                     "gyro": [{"step": 1, "label": "r1", "kind": "rate",
                                               "n": 10, "mean": [0.5], "rms": [1.0]}]}
    chk = doc["inflight"]["imus"]["imu2"]["time_offset_check"]
    assert chk["pieces"] == [
        {"t0_s": 0.0, "t1_s": 10.0, "offset_ms": 0.25, "sd_ms": 0.5, "model": "full"},
        {"t0_s": 10.0, "t1_s": 20.0, "offset_ms": None, "sd_ms": None,
         "note": "too little yaw"}]
    imu = doc["inflight"]["imus"]["imu2"]
    assert list(imu)[:3] == ["model", "A", "A_sd"] and list(imu)[-2:] == ["excitation", "notes"]
    assert imu["time_offset_ms"] == 0.5 and imu["bias_dph"] == [2.0, 0.0, -1.0]
    fer = doc["ferraris"]
    assert (fer["rotation_deg"], fer["latitude_deg"], fer["chi2_dof"]["dof"]) == (-360.0, 49.5, 2)
    assert doc["static"]["drift_attribution"]["unit"].startswith("deg/s")
    assert doc["static"]["imus"]["imu2"]["rotation_deg"] == [0.5, 0.0, 0.0]
    assert doc["parity_accel_calibrated_sd"] == []


def test_layout_orders_the_keys_and_writes_empty_entries():
    x = CalibrationExtras(source="s", method=Method("m"), warnings=())
    assert list(x.to_dict(STATIC_LAYOUT)) == ["method", "source"]
    doc = x.to_dict(TURNTABLE_LAYOUT, other={"regressors": {"names": []}, "zzz": 1})
    assert list(doc) == ["source", "method", "step_residual_chi2_dof", "warnings",
                         "residual_steps", "regressors", "zzz"]
    assert doc["warnings"] == [] and "warnings" not in x.to_dict()


def test_replace_extras_keeps_the_place_and_the_other_entries():
    extra = {"source": "s", "warnings": ["old"], "refit": "text"}
    out = replace_extras(extra, warnings=[])
    assert list(out) == ["source", "warnings", "refit"] and out["warnings"] == []
    assert extra["warnings"] == ["old"]
    assert list(replace_extras({"source": "s"}, warnings=["w"])) == ["source", "warnings"]
