"""Gyro biases with the Earth rate removed: explicit model and whole turns (seed 000 Eq. 20)."""

import numpy as np
import pytest
from _sessions import session, with_changes

from calibration.bias import offset_operator, turn_windows
from calibration.calibrate import calibrate
from fdi.errors import CalibrationError
from fdi.units import DPH, EARTH_RATE


def test_turn_windows_whole_turns_only():
    fs, w = 100.0, np.deg2rad(10.0)
    n1, n2, n3 = 5400, 3600, 2000                     # 1.5 turns, 1 turn, 0.56 turn
    step = np.repeat([1, 2, 3], [n1, n2, n3])
    tt = np.concatenate([np.arange(n) / fs for n in (n1, n2, n3)])
    outer = w * tt * np.where(step == 2, -1, 1)
    orate = w * np.where(step == 2, -1.0, 1.0)
    tw = turn_windows(step, outer, np.zeros_like(tt), orate, [1, 2, 3])
    assert tw.steps == (1, 2) and tw.turns == (1, 1) and tw.short_steps == (3,)
    assert tw.in_window[step == 1].sum() == 3600, "one whole turn of the 1.5-turn step"
    assert tw.in_window[step == 2].all() and not tw.in_window[step == 3].any()
    # a sinusoid at the table rate averages to zero over the window (seed 000 Eq. 20)
    m = tw.in_window & (step == 1)
    assert abs(np.mean(np.sin(outer[m] + 0.4))) < 1e-12


def test_offset_operator_is_weighted_mean_minus_gain():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(5, 3))
    w = np.array([0.1, 0.2, 0.3, 0.4, 0.0])
    op_a = rng.normal(size=(3, 5))
    u = rng.normal(size=5)
    c = offset_operator(w, X, op_a) @ u
    assert c == pytest.approx(w @ u - (op_a @ u) @ (X.T @ w)), "c = sum w (u - a.x)"


@pytest.mark.parametrize("name", ["tetrad-paper", "cone-paper"])
def test_both_methods_recover_injected_biases(name):
    s, truth = session(name, white=False)
    for method in ("model", "turns"):
        cal = calibrate(s, bias_method=method, allan=False)
        np.testing.assert_allclose(cal.gyro.biases, truth.gyro.biases, rtol=1e-8,
                                   atol=1e-6 * DPH, err_msg=f"gyro bias, method {method}")
        assert cal.extra["method"]["bias"] == method


def test_turns_method_vertical_earth_rate_term():
    s, truth = session("tetrad-paper", white=False)
    cal = calibrate(s, allan=False)
    gb = cal.extra["gyro_bias"]
    assert gb["turns_steps"] == list(range(5, 17))
    # what seed 000's plain average leaves in the bias: h~ . mean(Up_b) Omega sin(phi)
    _, _, fb = s.inputs()
    m = np.isin(s.step, gb["turns_steps"])
    upb = (fb[m] / np.linalg.norm(fb[m], axis=1, keepdims=True)).mean(axis=0)
    expect = truth.gyro.H @ upb * EARTH_RATE * np.sin(np.deg2rad(s.latitude_deg)) / DPH
    np.testing.assert_allclose(gb["vertical_correction"], expect, rtol=1e-6, atol=1e-9,
                               err_msg="vertical Earth-rate correction (deg/h)")
    assert np.max(np.abs(expect)) > 1.0, "seed 000's sequence does not cancel it (deg/h)"


def test_turns_method_needs_whole_turns():
    s, _ = session("tetrad-paper", white=False)
    keep = np.ones(s.t.shape, bool)
    for k in range(5, 17):                           # cut every outer step to 20 s
        idx = np.flatnonzero(s.step == k)
        keep[idx[2000:]] = False
    s2 = with_changes(s, t=s.t[keep], step=s.step[keep], inner=s.inner[keep],
                      outer=s.outer[keep], inner_rate=s.inner_rate[keep],
                      outer_rate=s.outer_rate[keep], raw_gyro=s.raw_gyro[keep])
    cal = calibrate(s2, allan=False)                 # the model method still works
    assert "turns" not in cal.extra["gyro_bias"]
    with pytest.raises(CalibrationError, match="whole turn"):
        calibrate(s2, bias_method="turns")
