"""Calibration in named stages: same output as before the split, stages callable one by one,
refit with extra regressors, the temperature knob of the simulator."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from calibration.calibrate import calibrate, run_stages
from calibration.effects import TEMP_START_DEGC, temperature_profile
from calibration.fit_residuals import fit_residuals
from calibration.linear_fit import fit_offsets, gyro_rate_test
from calibration.presets import preset
from calibration.problem import gyro_problem
from calibration.simulate import save_simulation, simulate_session
from calibration.truth import load_truth
from fdi.errors import CalibrationError, ConfigError
from fdi.units import DPH
from tests.calibration._sessions import session

# Output of the monolithic ``calibrate`` (commit 494b7b8, before the split into stages),
# seed 0, default options: a regression oracle for the refactoring (identical to 1e-12).
OLD = {
    "tetrad-paper": {
        "gyro": {
            "sf": [0.0006554996600167073, 0.0006705777602906989, 0.000669405301474302,
                   0.0006533837171232581],
            "sf_sd": [5.058391293937006e-09, 5.210879921447098e-09, 5.175085600072936e-09,
                      5.446973959169683e-09],
            "bias": [2.7987792060903297e-05, 4.2358877563777536e-05, 5.459359999528916e-05,
                     2.704789320442719e-05],
            "bias_sd": [7.45481576196527e-07, 7.456530191579235e-07, 7.443741673677226e-07,
                        7.442635464015495e-07],
            "axis0": [0.5785689399840016, -0.004324817828056102, 0.8156220188522026]},
        "earth": (15.008417481529767, 0.1539623200966659)},
    "cone-paper": {
        "gyro": {
            "sf": [0.00667297490594016, 0.006945548170340888, 0.006714277940560238,
                   0.006750214370649146, 0.006843044992247211, 0.0067535633480385795],
            "sf_sd": [1.048112452738632e-06, 1.0452521307741379e-06, 1.0187079054591474e-06,
                      1.057632518715826e-06, 1.0179448595665929e-06, 1.005576124762431e-06],
            "bias": [3.332494440897362, 3.634131091790273, 3.3455462691164164,
                     3.203620379124252, 3.3802373995032, 3.2031484789143483],
            "bias_sd": [0.0005241415047057627, 0.0005475887279397684, 0.0005083401993497487,
                        0.0005026909460373096, 0.0005035633027766298, 0.0004777095477573401],
            "axis0": [0.8257565690522943, 0.010548012998302122, -0.5639280344944478]},
        "accel": {
            "sf": [0.0022063234863507345, 0.00212617569846069, 0.0022844446935979036,
                   0.001847177109906019, 0.0018493684847207096, 0.001848285600889515],
            "sf_sd": [2.6614411550174986e-08, 2.8674658449558105e-08, 2.879699453160884e-08,
                      2.21504142590695e-08, 2.3292903179510105e-08, 2.4982438713373678e-08],
            "bias": [35.75837694797314, 39.857041618114884, 41.05140487543922,
                     38.519510413494636, 32.04185855656223, 34.71902725823406],
            "bias_sd": [0.00045099931767571104, 0.0005674456276663705, 0.0005201275724641089,
                        0.0004801011433031852, 0.000408042599881172, 0.0004998237140055711],
            "axis0": [0.8136586383587489, -0.027981831774162802, -0.580669128949309]},
        "earth": (20.96738044514217, 8.052938455378804)},
}


@pytest.mark.parametrize("name", ["tetrad-paper", "cone-paper"])
def test_same_result_as_before_the_split(name):
    s, _ = session(name, 0)
    cal = calibrate(s)
    for kind, want in OLD[name].items():
        if kind == "earth":
            np.testing.assert_allclose([cal.earth_rate_dph, cal.earth_rate_dph_sd], want,
                                       rtol=1e-12)
            continue
        got = cal.sets[kind]
        for key, attr in (("sf", "scale_factor"), ("sf_sd", "scale_factor_sd"),
                          ("bias", "bias"), ("bias_sd", "bias_sd")):
            np.testing.assert_allclose([getattr(c, attr) for c in got.sensors], want[key],
                                       rtol=1e-12, err_msg=f"{kind} {key}")
        np.testing.assert_allclose(got.sensors[0].axis, want["axis0"], rtol=1e-12)


def test_stages_one_by_one_match_run_stages(tetrad_session):
    st = run_stages(tetrad_session, noise_model="white")
    p = gyro_problem(tetrad_session)
    rt = gyro_rate_test(p)
    fit = fit_offsets(p, rt)
    res = fit_residuals(p, rt, fit)
    np.testing.assert_array_equal(fit.theta, st.gyro.fit.theta)
    np.testing.assert_array_equal(res.noise_cov_raw, st.gyro.residuals.noise_cov_raw)
    # every stage result is frozen
    with pytest.raises(dataclasses.FrozenInstanceError):
        st.gyro.fit.theta = None
    # the stage results are what the file holds
    cal = st.calibration
    np.testing.assert_allclose(cal.gyro.scale_factors, 1.0 / np.linalg.norm(fit.a, axis=1),
                               rtol=1e-14)
    np.testing.assert_allclose(cal.extra["step_residual_chi2_dof"], res.step_chi2_dof)


def test_regressors_refit_agrees_without_effect(tetrad_session):
    """The joint fit with no regressor estimates the same parameters within a small
    fraction of their σ (it only adds the position steps to the gain estimate)."""
    st = run_stages(tetrad_session, noise_model="white")
    N = tetrad_session.t.size
    p = st.gyro.problem.with_regressors(np.zeros((N, 0)), [])
    st2 = run_stages(tetrad_session, noise_model="white", problem=p)
    a, b = st.calibration.gyro, st2.calibration.gyro
    z_b = (b.biases - a.biases) / np.array([c.bias_sd for c in a.sensors])
    z_sf = (b.scale_factors - a.scale_factors) / np.array([c.scale_factor_sd
                                                           for c in a.sensors])
    assert np.all(np.abs(z_b) < 0.5) and np.all(np.abs(z_sf) < 0.5), (z_b, z_sf)


def test_regressors_bad_input(tetrad_session):
    p = gyro_problem(tetrad_session)
    N = tetrad_session.t.size
    with pytest.raises(CalibrationError, match="expected"):
        p.with_regressors(np.zeros((N, 2)), ["one"])
    bad = np.ones(N)
    bad[5] = np.nan
    with pytest.raises(CalibrationError, match="non-finite"):
        p.with_regressors(bad, ["t"])
    with pytest.raises(CalibrationError, match="collinear"):
        run_stages(tetrad_session, problem=p.with_regressors(np.ones(N), ["const"]))


def test_temperature_knob_and_column(cone_preset, tmp_path):
    seq, truth, noise = cone_preset
    base = simulate_session(None, seq, truth, seed=3, noise=noise)
    eff = simulate_session(None, seq, truth, seed=3, noise=noise,
                           effects={"temperature": 2.0}, effect_sensors=[2])
    assert base.temperature_degC is None
    T = temperature_profile(eff.t)
    np.testing.assert_array_equal(eff.temperature_degC, T)
    assert T[0] == TEMP_START_DEGC and T[-1] > TEMP_START_DEGC + 5
    d = (eff.raw_gyro - base.raw_gyro) * truth.gyro.scale_factors
    np.testing.assert_allclose(d[:, 1], 2.0 * DPH * (T - TEMP_START_DEGC), rtol=1e-6,
                               atol=1e-12)
    np.testing.assert_array_equal(np.delete(eff.raw_gyro, 1, axis=1),
                                  np.delete(base.raw_gyro, 1, axis=1))
    # a clean session with the temperature column: knob given as 0
    clean = simulate_session(None, seq, truth, seed=3, noise=noise, effects={"temperature": 0})
    np.testing.assert_array_equal(clean.raw_gyro, base.raw_gyro)
    assert clean.temperature_degC is not None
    d = save_simulation(eff, truth, tmp_path / "sim")
    _, effects, sensors = load_truth(d / "truth.json")
    assert effects == {"temperature": 2.0} and sensors == {"temperature": (2,)}


def test_session_temperature_validated(tetrad_session):
    N, n = tetrad_session.raw_gyro.shape
    ok = dataclasses.replace(tetrad_session, temperature_degC=np.full((N, n), 25.0))
    assert ok.gyro_temperature_degC().shape == (N, n)
    one = dataclasses.replace(tetrad_session, temperature_degC=np.full(N, 25.0))
    assert one.gyro_temperature_degC().shape == (N, n)
    with pytest.raises(ConfigError, match="shape"):
        dataclasses.replace(tetrad_session, temperature_degC=np.zeros((N, n + 5)))
    bad = np.full(N, 25.0)
    bad[7] = np.nan
    with pytest.raises(ConfigError, match="sample 8"):
        dataclasses.replace(tetrad_session, temperature_degC=bad)


def test_temperature_regressor_recovers_the_knob_over_seeds():
    """A temperature-dependent bias, refit with the session's temperature column: the
    coefficient is within 3σ of the truth in at least 18 of 20 seeds (binomial: P(≥ 3
    misses | p = 0.27 %) < 1e-4) and the z-scores scatter like N(0, 1)."""
    seq, truth, noise = preset("tetrad-paper")
    k_dph = 0.5
    sf = truth.gyro.scale_factors
    z = []
    for seed in range(20):
        s = simulate_session(None, seq, truth, seed=100 + seed, noise=noise,
                             effects={"temperature": k_dph})
        p = gyro_problem(s).with_regressors(s.temperature_degC - TEMP_START_DEGC, ["T"])
        st = run_stages(s, noise_model="white", allan=False, earth_rate=False, problem=p)
        beta = st.gyro.fit.beta[:, 0]                       # raw per °C
        sd = st.gyro.uncertainty.theta_sd[4]
        z.append((beta - k_dph * DPH / sf) / sd)
        bz = (st.calibration.gyro.biases - truth.gyro.biases) / np.array(
            [c.bias_sd for c in st.calibration.gyro.sensors])
        z.append(bz)
    z = np.array(z)
    assert np.mean(np.abs(z) < 3) >= 0.95, z
    # without the regressor the same session's biases are far off: the test has power
    st0 = run_stages(s, noise_model="white", allan=False, earth_rate=False)
    z0 = (st0.calibration.gyro.biases - truth.gyro.biases) / np.array(
        [c.bias_sd for c in st0.calibration.gyro.sensors])
    assert np.all(np.abs(z0) > 5), z0
    assert 0.6 < np.sqrt(np.mean(z**2)) < 1.5, np.sqrt(np.mean(z**2))
