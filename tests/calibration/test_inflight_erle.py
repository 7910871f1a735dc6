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
    assert -12e-3 < t1 < -7e-3
    assert a.offset_check["sd_hac_ms"] < 1.0 and s2 >= 1e-3 * a.offset_check["sd_hac_ms"]
    assert abs(t1 - t2) < 3 * np.hypot(s1, s2)
    assert np.all(d1 - 1 > 0.015) and np.all(d2 - 1 > 0.015)      # IMU2 reads 2-6 % more


def test_flight_41_last_piece_has_too_little_yaw_for_the_full_model(f41) -> None:
    """Was: the full model refused ("does not excite A[x,z]"), auto fell back to rotation.
    Now (issue 27) the parameters that need yaw are held at the prior, the rest estimated:
    scale z rests on the yaw alone and keeps the prior's sd."""
    from calibration.inflight.fit import ESTIMATED, HELD

    part = _part(f41, 163.0, 240.0)
    a = fit_inflight(part, model="full").alignments["imu2"]
    st = {p.name: p for p in a.parameters}
    assert st["scale z"].status == HELD
    assert st["scale z"].sd > 0.5 * st["scale z"].prior_sd
    assert st["scale x"].status == ESTIMATED and st["scale y"].status == ESTIMATED


def test_flight_41_shocks_are_left_out_and_structure_remains(f41) -> None:
    fit = fit_inflight(f41)
    reasons = [s.reason for s in fit.left_out]
    assert reasons.count("gap") >= 2
    assert any(r in ("shock", "crash", "take-off") for r in reasons)
    doc = diagnose_flight(f41, calibration_from_fit(fit, f41))
    assert doc["unexplained"]


def test_flight_41_first_part_offset_varies_and_its_sd_is_widened(f41) -> None:
    """0-89 s holds a calm stretch on the ground (60-67 s, rates near 1 deg/s) whose apparent
    lag is ~-2 ms against ~-9.5 ms in flight: the pieces disagree and the sd says so."""
    a = fit_inflight(_part(f41, 0.0, 89.0)).alignments["imu2"]
    chk = a.offset_check
    assert not chk["consistent"] and chk["consistency"]["p_value"] < 1e-6
    assert a.time_offset_sd_s == pytest.approx(1e-3 * chk["sd_pieces_ms"])
    assert a.time_offset_sd_s > 3 * 1e-3 * chk["sd_hac_ms"]


def test_diagnose_and_calibration_give_one_time_offset_on_both_flights(f41, f83) -> None:
    """diagnose works on the calibration's samples with its exact shift: what it reports
    left of the offset is within the combined sd (or nothing is left)."""
    for f in (f41, f83):
        fit = fit_inflight(f)
        doc = diagnose_flight(f, calibration_from_fit(fit, f))
        (tm,) = doc["timing"]
        assert tm["calibration_ms"] == pytest.approx(1e3 * fit.alignments["imu2"].time_offset_s)
        assert not tm["left"] or tm["apart_in_combined_sd"] < 1
        assert abs(tm["left_ms"]) < tm["combined_sd_ms"]
        assert doc["samples_used"] <= int(fit.used.sum())
        assert doc["left_out"] == [s.to_dict() for s in fit.left_out]
        assert fit.alignments["imu2"].offset_check["consistent"]


def test_flight_83_no_skew_and_residual_power_follows_vibration(f83) -> None:
    fit = fit_inflight(f83)
    a = fit.alignments["imu2"]
    assert abs(a.time_offset_s) < 1e-3
    doc = diagnose_flight(f83, calibration_from_fit(fit, f83))
    vib = [e for e in doc["effects"] if e["name"] == "vibration_noise"]
    assert vib and vib[0]["p_value"] < 1e-6
    assert "time_skew" not in {e["name"] for e in doc["effects"]}
