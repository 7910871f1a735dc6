"""Time offsets of an in-flight calibration applied before the monitor
(calibration.inflight.timing): inject a lag, fit it, move the IMU, fit again."""

from __future__ import annotations

import numpy as np

from calibration.inflight.calfile import calibration_from_fit
from calibration.inflight.fit import fit_inflight
from calibration.inflight.timing import apply_time_offsets, time_offsets_s
from replay.imu_set import ImuSetSpec, simulate_imu_set


def _flight(seed: int, tau_s: float):
    return simulate_imu_set(ImuSetSpec(imus=2, duration_s=60, seed=seed,
                                       time_offset_s=(0.0, tau_s)))


def test_moved_imu_has_no_offset_left() -> None:
    # a 5 ms lag, fitted, applied: the refit on the moved flight finds no offset (within
    # 3 sigma plus the fit's own sd of the first estimate, which the move inherits)
    for seed in (3, 4, 5):
        f = _flight(seed, 0.005)
        fit = fit_inflight(f)
        a = fit.alignments["imu2"]
        cal = calibration_from_fit(fit, f)
        assert abs(time_offsets_s(cal)["imu2"] - a.time_offset_s) < 1e-12
        moved, applied = apply_time_offsets(f, cal)
        assert set(applied) == {"imu2"}
        b = fit_inflight(moved).alignments["imu2"]
        bound = 3 * np.hypot(b.time_offset_sd_s, a.time_offset_sd_s)
        assert abs(b.time_offset_s) < bound, (
            f"seed {seed}: offset after the move {b.time_offset_s * 1e3:.4f} ms, "
            f"bound {bound * 1e3:.4f} ms")
        # the reference is untouched, the moved IMU loses at most its first/last sample
        ref = [k for k, g in enumerate(f.imu) if g == "imu1"]
        np.testing.assert_array_equal(moved.raw[:, ref], f.raw[:, ref])
        mov = [k for k, g in enumerate(f.imu) if g == "imu2"]
        assert (~moved.valid[:, mov]).sum(axis=0).max() <= 1


def test_turntable_calibration_or_zero_offset_leaves_the_flight_alone() -> None:
    f = _flight(6, 0.0)
    fit = fit_inflight(f, time_offset=False)
    cal = calibration_from_fit(fit, f)
    moved, applied = apply_time_offsets(f, cal)
    assert applied == {} and moved is f
