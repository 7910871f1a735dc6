"""calibrate(): exact recovery on noise-free sessions, honest errors on one noisy session,
seed 000's parity vectors, the file fields, and the bad-input errors of the estimators."""

import json

import numpy as np
import pytest
from _sessions import session, with_changes

from calibration.calibrate import MIN_STEP_SAMPLES, calibrate
from calibration.compare import compare
from fdi.calfile import load_calibration
from fdi.errors import CalibrationError
from fdi.parity import parity_matrix

EQ24 = np.array([-0.40825, -0.40825, -0.40825, 0.70711])          # seed 000 Eq. 24
EQ25 = np.array([-0.40955, -0.40903, -0.40585, 0.70729])          # seed 000 Eq. 25


@pytest.mark.parametrize("name", ["tetrad-paper", "cone-paper"])
def test_noise_free_session_recovers_every_parameter(name):
    s, truth = session(name, white=False)
    cal = calibrate(s)
    for kind in truth.sets:
        e, t = cal.kind(kind), truth.kind(kind)
        for ce, ct in zip(e.sensors, t.sensors, strict=True):
            assert ce.scale_factor == pytest.approx(ct.scale_factor, rel=1e-10), \
                f"{kind} {ce.name} scale factor"
            np.testing.assert_allclose(ce.axis, ct.axis, atol=1e-10,
                                       err_msg=f"{kind} {ce.name} axis")
            assert ce.bias == pytest.approx(ct.bias, rel=1e-9, abs=1e-12), \
                f"{kind} {ce.name} bias"
        for Me, Mt in zip(e.misalignment_matrices, t.misalignment_matrices, strict=True):
            np.testing.assert_allclose(Me, Mt, atol=1e-10, err_msg=f"{kind} M per subsystem")


@pytest.mark.parametrize("name", ["tetrad-paper", "cone-paper"])
def test_one_noisy_session_every_parameter_within_three_sigma(name):
    s, truth = session(name, seed=0)
    cal = calibrate(s)
    rows = compare(cal, truth)
    kinds = {r.kind for r in rows}
    assert kinds == set(truth.sets) | {"site"}
    for r in rows:
        assert abs(r.z) < 3, f"{r.kind} {r.sensor} {r.parameter}: error/sd = {r.z:.2f}"
    # the per-sample noise covariance is recovered (white noise, >= 36k samples per kind)
    for kind in truth.sets:
        np.testing.assert_allclose(cal.kind(kind).noise_sd, truth.kind(kind).noise_sd,
                                   rtol=0.02, err_msg=f"{kind} noise sd")
        chi = np.asarray(cal.extra["rate_test"]["chi2_dof"])
        assert np.all(chi < 6), "step-difference scatter explained by white noise"


def test_parity_vectors_of_seed_000():
    s, truth = session("tetrad-paper", seed=0)
    cal = calibrate(s)
    np.testing.assert_allclose(parity_matrix(cal.gyro.H_nominal)[0], EQ24, atol=5e-6,
                               err_msg="v (Eq. 24)")
    Vc = parity_matrix(cal.gyro.H)[0]
    sd = np.asarray(cal.extra["parity_calibrated_sd"])[0]
    assert np.all(sd > 0) and np.all(sd < 1e-4)
    Vt = parity_matrix(truth.gyro.H)[0]
    assert np.all(np.abs(Vc - Vt) < 3 * sd), f"v_c {Vc} vs truth {Vt}, sd {sd}"
    # Eq. 25 is printed to 5 decimals: half a unit of the last digit on top of 3 sd
    assert np.all(np.abs(Vc - EQ25) < 3 * sd + 5e-6), f"v_c {Vc} vs Eq. 25, sd {sd}"


def test_file_has_every_field_the_issue_lists(tmp_path):
    s, _ = session("cone-paper", seed=1)
    cal = calibrate(s)
    p = tmp_path / "cal.json"
    cal.save(p)
    doc = json.loads(p.read_text())
    assert doc["schema"] == "rimu.calibration/2"
    for kind in ("gyro", "accel"):
        for e in doc["sensors"][kind]:
            for key in ("name", "axis", "axis_nominal", "misalignment_mrad",
                        "misalignment_mrad_sd", "scale_factor", "scale_factor_sd",
                        "scale_factor_unit", "bias", "bias_sd", "bias_unit", "residual_rms",
                        "input_error_cov"):
                assert key in e, f"{kind} sensor field {key}"
            assert all(v > 0 for v in e["misalignment_mrad_sd"])
        assert np.shape(doc["noise_covariance"][kind]) == (6, 6)
        assert np.shape(doc["misalignment_matrices"][kind][0]["M"]) == (3, 3)
        assert len(doc["allan"][kind]["tau_s"]) >= 5
    assert np.shape(doc["parity"]["nominal"]) == (3, 6)
    assert np.shape(doc["parity"]["calibrated"]) == (3, 6)
    assert "earth_rate_dph" in doc and doc["earth_rate_dph_sd"] > 0
    steps = doc["extra"]["residual_steps"]
    assert [r["step"] for r in steps["gyro"]] == list(range(1, 25))
    assert [r["step"] for r in steps["accel"]] == list(range(1, 11))
    back = load_calibration(p)
    np.testing.assert_allclose(back.gyro.H, cal.gyro.H, atol=1e-12)
    np.testing.assert_allclose(back.gyro.scale_factors, cal.gyro.scale_factors, rtol=1e-12)


def test_input_error_cov_is_gain_normalised_cov_of_a():
    s, _ = session("tetrad-paper", seed=2)
    cal = calibrate(s, allan=False)
    for c in cal.gyro.sensors:
        C = np.asarray(c.input_error_cov)
        # its radial part is the relative scale-factor variance, its tangential part the
        # misalignment variance (first order)
        assert c.axis @ C @ c.axis == pytest.approx((c.scale_factor_sd / c.scale_factor) ** 2,
                                                    rel=1e-6), f"{c.name} radial"
        assert np.trace(C) - c.axis @ C @ c.axis == pytest.approx(
            np.sum(np.asarray(c.misalignment_sd) ** 2), rel=1e-3), f"{c.name} tangential"


def _drop(s, keep):
    return with_changes(s, t=s.t[keep], step=s.step[keep], inner=s.inner[keep],
                        outer=s.outer[keep], inner_rate=s.inner_rate[keep],
                        outer_rate=s.outer_rate[keep], raw_gyro=s.raw_gyro[keep],
                        raw_accel=None if s.raw_accel is None else s.raw_accel[keep])


def test_step_with_too_few_samples():
    s, _ = session("tetrad-paper", seed=0, white=False)
    idx = np.flatnonzero(s.step == 7)
    keep = np.ones(s.t.shape, bool)
    keep[idx[MIN_STEP_SAMPLES - 3:]] = False
    with pytest.raises(CalibrationError) as e:
        calibrate(_drop(with_changes(s, source="sess7"), keep))
    msg = str(e.value)
    assert "sess7" in msg and "step 7" in msg and "7 sample" in msg
    assert f"at least {MIN_STEP_SAMPLES}" in msg


def test_position_with_too_few_samples():
    s, _ = session("cone-paper", seed=0, white=False)
    keep = np.ones(s.t.shape, bool)
    keep[np.flatnonzero(s.step == 3)] = False
    with pytest.raises(CalibrationError, match=r"step 3: no samples of the accelerometer"):
        calibrate(_drop(s, keep))


def test_non_finite_samples_and_unknown_method():
    s, _ = session("tetrad-paper", seed=0, white=False)
    raw = s.raw_gyro.copy()
    raw[np.flatnonzero(s.step == 9)[5], 2] = np.nan
    with pytest.raises(CalibrationError, match=r"step 9: non-finite gyro sample \(sensor 3"):
        calibrate(with_changes(s, raw_gyro=raw))
    with pytest.raises(CalibrationError, match="unknown bias method"):
        calibrate(s, bias_method="average")


def test_rank_deficient_sequence_names_steps():
    s, _ = session("tetrad-paper", seed=0, white=False)
    keep = np.isin(s.step, [1, 2, 3, 4, 5, 6])             # x and Up only
    s2 = _drop(with_changes(s, source="tt", steps=s.steps[:6]), keep)
    with pytest.raises(CalibrationError) as e:
        calibrate(s2)
    assert "tt" in str(e.value) and "1/2, 3/4, 5/6" in str(e.value)


def test_warns_when_white_noise_does_not_explain_the_step_differences():
    from calibration.presets import preset
    from calibration.simulate import NoiseModel, simulate_session
    from fdi.units import DPH

    seq, truth, _ = preset("tetrad-paper")
    s = simulate_session(None, seq, truth, seed=1,
                         noise=NoiseModel(bias_instability={"gyro": 5 * DPH}))
    cal = calibrate(s, allan=False)
    assert any("rate-step differences scatter more" in w for w in cal.extra["warnings"])
    assert any("step means of the residuals scatter" in w for w in cal.extra["warnings"])
    s0, _ = session("tetrad-paper", seed=0)
    cal0 = calibrate(s0, allan=False)
    assert cal0.extra["warnings"] == []
    assert np.all(np.asarray(cal0.extra["step_residual_chi2_dof"]) < 3)
