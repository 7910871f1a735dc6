"""A calibration carried to a flight under another firmware (replay.firmware_prior): the
firmware-dependent parameters of every IMU but the reference held at the calibration's
prior, so a change within the stated tolerance raises no alarm and a fault is still seen."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from fdi.units import DPS
from replay.chain import ChainOptions, chain_for_flight
from replay.firmware_prior import apply_firmware_prior, firmware_prior
from replay.log_events import LogEvent

BUILD_A = "ArduCopter V4.1.0 (aaaa1111)"
BUILD_B = "ArduCopter V4.2.0 (bbbb2222)"


def _msg(text):
    return (LogEvent(1.0, 1.0, "MSG", text),)


def _flights(seed: int, scale=(1.04, 0.97, 1.03)):
    """Flight A (IMU2 4 ms late) and the same two IMUs on flight B under another build:
    IMU2 12 ms late and its scale factors moved by ``scale`` (the driver's), both within
    the prior (±1 sample = 20 ms at 50 Hz, ±3 %, 1σ)."""
    from replay.imu_set import ImuSetSpec, simulate_imu_set

    a = simulate_imu_set(ImuSetSpec(duration_s=60.0, seed=seed, time_offset_s=(0.0, 0.004)))
    b = simulate_imu_set(ImuSetSpec(duration_s=70.0, seed=seed, time_offset_s=(0.0, 0.012)))
    raw = b.raw.copy()
    raw[:, 3:6] *= np.asarray(scale)
    return (replace(a, events=_msg(BUILD_A)),
            replace(b, raw=raw, source="other.BIN", events=_msg(BUILD_B)))


@pytest.fixture(scope="module")
def calibrated():
    from calibration.inflight import calibration_from_fit, fit_inflight

    a, b = _flights(10)
    return calibration_from_fit(fit_inflight(a), a), a, b


def test_another_build_widens_every_imu_but_the_reference(calibrated):
    cal, _, b = calibrated
    fp = firmware_prior(cal, b)
    assert fp is not None and fp.imus == ("imu2",) and fp.calibrated == (BUILD_A,)
    assert fp.flight == BUILD_B
    p = cal.extras.inflight_alignment.prior
    assert fp.scale_sd == pytest.approx(p["scale_sd"])
    assert fp.misalignment_sd == pytest.approx(1e-3 * p["misalignment_mrad_sd"])
    assert fp.time_offset_sd_s == pytest.approx(1e-3 * p["time_offset_ms_sd"])
    wide = apply_firmware_prior(cal, fp)
    g0, g1 = cal.kind("gyro"), wide.kind("gyro")
    across = fp.misalignment_sd**2 + fp.nonorthogonality_sd**2
    for c0, c1, h in zip(g0.sensors, g1.sensors, np.asarray(g0.H), strict=True):
        if c0.name.startswith("imu1."):
            assert c1 == c0, c0.name                                   # the reference
            continue
        u = h / np.linalg.norm(h)
        want = fp.scale_sd**2 * np.outer(u, u) + across * (np.eye(3) - np.outer(u, u))
        np.testing.assert_allclose(np.asarray(c1.input_error_cov) - c0.input_error_cov, want,
                                   rtol=1e-12, atol=1e-18, err_msg=c0.name)
        assert c1.timing_jitter == pytest.approx(math.hypot(c0.timing_jitter,
                                                            fp.time_offset_sd_s)), c0.name


def test_the_same_build_or_none_named_changes_nothing(calibrated):
    cal, a, b = calibrated
    assert firmware_prior(cal, replace(b, events=_msg(BUILD_A))) is None
    assert firmware_prior(cal, replace(b, events=())) is None            # the flight names none
    from calibration.inflight import calibration_from_fit, fit_inflight

    silent = replace(a, events=())
    assert firmware_prior(calibration_from_fit(fit_inflight(silent), silent), b) is None
    assert apply_firmware_prior(cal, None) is cal


@pytest.mark.parametrize("seed", [10, 11])
def test_a_change_within_the_prior_raises_no_alarm_and_a_step_is_still_seen(seed):
    """Kept as calibrated, the moved time offset and scale open a detection at once and the
    flight stays unverified; held at the prior, no alarm, and a 10 °/s step on imu2.x at
    35 s is detected within 1 s."""
    from calibration.inflight import calibration_from_fit, fit_inflight
    from replay.faults import Fault
    from replay.scenario import apply_faults

    a, b = _flights(seed)
    cal = calibration_from_fit(fit_inflight(a), a)

    def run(flight, prior):
        ch = chain_for_flight(flight, cal, ChainOptions(report=False, firmware_prior=prior))
        res = ch.feed_whole(flight)
        alarms = [e for e in res.events if e.type in ("detected", "isolated", "health")]
        return ch, res, alarms

    _, res, alarms = run(b, False)
    assert alarms and res.unverified.any(axis=1).mean() > 0.5, alarms
    ch, res, alarms = run(b, True)
    assert ch.firmware_prior is not None and "firmware_prior" in ch.extra()
    assert not alarms, alarms
    assert res.unverified.any(axis=1).mean() == 0.0
    f = Fault("step", 4, 10.0 * DPS, 35.0, 10.0, "step:4:35")
    raw, valid = apply_faults(b.t, b.raw, b.valid, [f], cal, kind=b.kind)
    _, _, alarms = run(replace(b, raw=raw, valid=valid), True)
    late = [e for e in alarms if e.t >= 35.0]
    assert late and late[0].t - 35.0 <= 1.0, late
