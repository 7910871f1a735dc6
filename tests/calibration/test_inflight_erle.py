"""Findings on the two erle PXF ArduCopter flights (two IMUs, ~50 Hz), read from
``../shared/data`` (no licence stated: the data are never copied here). Skipped when the
folder is absent. The numbers are in docs/inflight.md ("Real flight")."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from _erle import DATA, FLIGHTS, read_erle

from calibration.inflight.calfile import calibration_from_fit
from calibration.inflight.diagnose import diagnose_flight
from calibration.inflight.fit import fit_inflight
from fdi.errors import CalibrationError

pytestmark = pytest.mark.skipif(
    not all((DATA / f).is_file() for f in FLIGHTS.values()),
    reason=f"erle flight logs not found in {DATA} (../shared/data beside the repository)")


def _part(f, t0: float, t1: float):
    m = (f.t >= t0) & (f.t < t1)
    return replace(f, t=f.t[m], raw=f.raw[m], valid=f.valid[m], aux=f.aux.slice(m))


@pytest.fixture(scope="module")
def f41():
    return read_erle("41")


@pytest.fixture(scope="module")
def f83():
    return read_erle("83")


def test_flight_41_imu2_lags_imu1_by_about_9_ms_in_both_flying_parts(f41) -> None:
    """The same skew and scale difference in two separate flying parts of the log."""
    est = []
    for t0, t1 in ((0.0, 89.0), (117.0, 138.0)):
        a = fit_inflight(_part(f41, t0, t1)).alignments["imu2"]
        assert a.model == "full"
        est.append((a.time_offset_s, a.time_offset_sd_s, np.diag(a.A), a.A_cov))
    (t1, s1, d1, _), (t2, s2, d2, _) = est
    assert -12e-3 < t1 < -7e-3 and s1 < 1e-3
    assert abs(t1 - t2) < 3 * np.hypot(s1, s2)
    assert np.all(d1 - 1 > 0.015) and np.all(d2 - 1 > 0.015)      # IMU2 reads 2-6 % more


def test_flight_41_last_piece_has_too_little_yaw_for_the_full_model(f41) -> None:
    part = _part(f41, 163.0, 240.0)
    with pytest.raises(CalibrationError, match=r"does not excite A\[x,z\]"):
        fit_inflight(part, model="full")
    assert fit_inflight(part).alignments["imu2"].model == "rotation"     # auto falls back


def test_flight_41_shocks_are_left_out_and_structure_remains(f41) -> None:
    fit = fit_inflight(f41)
    reasons = [s.reason for s in fit.left_out]
    assert reasons.count("gap") >= 2
    assert any(r in ("shock", "crash", "take-off") for r in reasons)
    doc = diagnose_flight(f41, calibration_from_fit(fit, f41))
    names = {e["name"] for e in doc["effects"]}
    assert "time_skew" in names
    skew = next(e for e in doc["effects"] if e["name"] == "time_skew")
    assert skew["estimate"] < -5                                    # ms
    assert doc["unexplained"]


def test_flight_83_no_skew_and_residual_power_follows_vibration(f83) -> None:
    fit = fit_inflight(f83)
    a = fit.alignments["imu2"]
    assert abs(a.time_offset_s) < 1e-3
    doc = diagnose_flight(f83, calibration_from_fit(fit, f83))
    vib = [e for e in doc["effects"] if e["name"] == "vibration_noise"]
    assert vib and vib[0]["p_value"] < 1e-6
    assert "time_skew" not in {e["name"] for e in doc["effects"]}
