"""Run-time compensation of the calibration's effect terms (fdi.effects).

- The run-time evaluator reproduces the diagnosis library's regressor × estimate on the same
  inputs (ties the two definitions together).
- Block and step corrections are identical; bad inputs give 0 and are counted, never raise.
- The terms the monitor cannot apply are listed with the reason.
- End to end: a simulated flight whose gyros carry g-sensitivity and scale asymmetry (added
  with the calibration simulator's own effect functions): compensated, the per-sensor
  parity residual mean is within 3 σ of zero and there are no more alarms than the
  thresholds' rate allows; uncompensated, the bias is many σ and the monitor alarms.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _effects_flight import (
    A_ASYM,
    FLIGHT_S,
    K_G,
    effect_calibration,
    flight_with_effects,
    residual_z,
)
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import poisson

from calibration.diagnose.context import kind_data
from calibration.diagnose.library import get_candidate
from calibration.presets import preset
from calibration.simulate import SessionNoise, simulate_session
from fdi.calfile import EffectTerm
from fdi.effects import COMPENSABLE, Compensator, term_correction
from fdi.effects_monitor import CompensatedMonitor
from fdi.monitor import Monitor
from fdi.units import DPH
from replay.effect_inputs import flight_effect_inputs
from replay.flight import simulate_flight
from studies.synthetic import synthetic_calibration


# -- the evaluator and the library agree -------------------------------------------------
@pytest.fixture(scope="module")
def session_data():
    seq, truth, _ = preset("tetrad-paper")
    s = simulate_session(None, seq, truth, seed=4, noise=SessionNoise(white=False))
    t = s.t - s.t[0]
    T = 25 + 10 * (1 - np.exp(-t / 500))[:, None] + 0.3 * np.arange(4)[None, :]
    s = dataclasses.replace(s, temperature_degC=T)
    return s, truth, kind_data(s, truth)["gyro"]


def _term(name, d, i, est):
    c = get_candidate(name)
    params = c.fixed_params(d, i) if c.fixed_params else {}
    return c, EffectTerm(name=name, kind="gyro", sensor=i, estimate=est, estimate_sd=0.1 * abs(est),
                         unit=c.unit_for("gyro"), inputs=c.inputs, params=params)


@pytest.mark.parametrize(("name", "est"), [("scale_asymmetry", 3e-3),
                                           ("scale_nonlinearity", -2e-3),
                                           ("g_sensitivity", 40.0), ("temperature", 0.7)])
def test_evaluator_reproduces_library_regressor(session_data, name, est):
    _, _, d = session_data
    assert name in COMPENSABLE
    for i in range(d.n):
        c, term = _term(name, d, i, est * (1 + 0.3 * i))
        want = c.columns(d, i, term.params)[:, 0] * term.estimate
        got = term_correction(term, d.H[i], s=d.s[:, i], force=d.force,
                              temperature=d.temperature[:, i])
        assert np.max(np.abs(want)) > 0, "the regressor is zero on this session"
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.max(np.abs(want)))


def test_scale_nonlinearity_term_records_the_table_rate(session_data):
    _, _, d = session_data
    _, term = _term("scale_nonlinearity", d, 0, 1e-3)
    assert term.params["table_rate_dps"] == pytest.approx(np.degrees(d.table_rate), rel=1e-12)


def test_compensator_on_a_noise_free_session(session_data):
    """The Compensator reads ŝ = SF·u − b (= s on a noise-free session) and subtracts σ² from
    ŝ² (unbiased rate²): its correction is the library's sum of terms."""
    s, truth, d = session_data
    ests = {"scale_asymmetry": 3e-3, "scale_nonlinearity": -2e-3, "g_sensitivity": 40.0,
            "temperature": 0.7}
    terms, want = [], np.zeros((d.N, d.n))
    for k, (name, est) in enumerate(ests.items()):
        i = k % d.n
        c, term = _term(name, d, i, est)
        terms.append(term)
        want[:, i] += c.columns(d, i, term.params)[:, 0] * est
        if name == "scale_nonlinearity":
            want[:, i] -= est * truth.gyro.noise_covariance[i, i] / d.table_rate
    cal = dataclasses.replace(truth, effects=tuple(terms))
    comp = Compensator(cal, available={"specific_force": range(4), "temperature": range(4)})
    assert [a.term.name for a in comp.applied] == list(ests) and comp.skipped == ()
    got = comp.block(s.raw_gyro, force=d.force, temperature=d.temperature)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.max(np.abs(want)))
    # one sample at a time: the same numbers to the bit
    rows = np.array([comp.one(s.raw_gyro[k], d.force[k], d.temperature[k])
                     for k in range(0, d.N, 997)])
    np.testing.assert_array_equal(rows, got[::997])


# -- what cannot be applied, and bad inputs ----------------------------------------------
def _cal_with(*terms):
    return dataclasses.replace(synthetic_calibration("tetrad", seed=1), effects=tuple(terms))


def _t(name, sensor, unit, est=1.0, **params):
    return EffectTerm(name, "gyro", sensor, est, 0.1, unit, (), params)


def test_says_which_it_cannot_apply():
    cal = _cal_with(_t("bias_step", 0, "deg/h", 3.0, time_s=100.0),
                    _t("humidity", 1, "deg/h per %", 0.2),
                    _t("g_sensitivity", 2, "deg/h per g", 50.0),
                    _t("temperature", 3, "deg/h per degC", 0.5, reference_degC=25.0),
                    _t("warmup", 0, "deg/h", 5.0),
                    _t("scale_nonlinearity", 1, "fraction", 1e-3),       # no table rate
                    _t("scale_asymmetry", 2, "percent", 0.1),            # foreign unit
                    _t("scale_asymmetry", 3, "fraction", 1e-3),
                    EffectTerm("temperature", "accel", 0, 0.1, 0.01, "mg per degC", (),
                               {"reference_degC": 25.0}))
    comp = Compensator(cal)                     # a stream with no accelerometers, no temperature
    why = {(s.term.name, s.term.sensor): s.reason for s in comp.skipped}
    assert [(a.term.name, a.term.sensor) for a in comp.applied] == [("scale_asymmetry", 3)]
    assert why[("bias_step", 0)].startswith("session-specific")
    assert "not a sensor property" in why[("bias_step", 0)]
    assert why[("humidity", 1)] == "user effect: no run-time form"
    assert why[("g_sensitivity", 2)] == "needs specific force: no accelerometers in the stream"
    assert why[("temperature", 3)].startswith("needs temperature")
    assert "switch-on" in why[("warmup", 0)]
    assert "table_rate_dps" in why[("scale_nonlinearity", 1)]
    assert "'percent'" in why[("scale_asymmetry", 2)]
    assert "this stream monitors gyro" in why[("temperature", 0)]
    line = comp.summary(("g1", "g2", "g3", "g4"))
    assert line.startswith("compensating: scale_asymmetry on g4 (from rate sign); not applied:")
    assert "g_sensitivity on g3 (needs specific force: no accelerometers in the stream)" in line
    doc = comp.to_dict()
    assert doc["schema"] == "rimu.effects-runtime/1" and len(doc["not_applied"]) == 8
    # with the inputs present, the two input-limited terms are applied
    comp2 = Compensator(cal, available={"specific_force": [2], "temperature": [3]})
    assert {(a.term.name, a.term.sensor) for a in comp2.applied} == {
        ("scale_asymmetry", 3), ("g_sensitivity", 2), ("temperature", 3)}


def test_bad_inputs_give_zero_and_are_counted():
    cal = _cal_with(_t("g_sensitivity", 0, "deg/h per g", 100.0),
                    _t("temperature", 1, "deg/h per degC", 2.0, reference_degC=20.0),
                    _t("scale_asymmetry", 2, "fraction", 1e-2))
    comp = Compensator(cal, available={"specific_force": [0], "temperature": [1]})
    N = 50
    raw = np.full((N, 4), 100.0)
    raw[3, 2] = np.nan
    raw[4, 2] = np.inf
    f = np.tile([0.0, 0.0, 9.81], (N, 1))
    f[5] = np.nan
    T = np.full(N, 30.0)
    T[6:9] = np.nan
    c = comp.block(raw, force=f, temperature=T)
    assert np.all(np.isfinite(c))
    assert c[5, 0] == 0 and c[6:9, 1].tolist() == [0, 0, 0] and c[3:5, 2].tolist() == [0, 0]
    assert c[0, 0] != 0 and c[0, 1] == pytest.approx(2.0 * DPH * 10.0, rel=1e-12)
    assert comp.missing == {("g_sensitivity", 0): 1, ("temperature", 1): 3}
    # missing or malformed inputs altogether: zeros for those terms, no exception
    for bad in (None, "junk", np.ones((N, 2)), np.ones(7)):
        c2 = comp.block(raw, force=bad, temperature=bad)
        assert np.all(c2[:, :2] == 0) and np.all(np.isfinite(c2))
    for row in ([None] * 4, "x", np.ones(3), [1.0, 2.0, np.nan, 4.0]):
        assert np.all(np.isfinite(comp.one(row, force=None, temperature=np.nan)))


def test_no_terms_means_the_plain_monitor_bit_for_bit():
    cal = _cal_with(_t("scale_asymmetry", 0, "fraction", 3e-3))
    fl = simulate_flight(cal, 20.0, seed=3, truth=cal)
    plain = Monitor(cal).run(fl.t, fl.raw, fl.valid, parity=True)
    off = CompensatedMonitor(Monitor(cal), Compensator(cal, enabled=False)).run(
        fl.t, fl.raw, fl.valid, parity=True)
    on = CompensatedMonitor(Monitor(cal), Compensator(cal)).run(fl.t, fl.raw, fl.valid,
                                                                parity=True)
    for a in ("omega", "statistics", "parity", "protection_level"):
        np.testing.assert_array_equal(getattr(off, a), getattr(plain, a), err_msg=a)
    assert np.max(np.abs(on.omega - plain.omega)) > 0, "the term had no effect"


# -- end to end ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def effect_cal():
    return effect_calibration()


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_compensation_removes_the_parity_bias_and_the_alarms(effect_cal, seed):
    cal = effect_cal
    fl = flight_with_effects(cal, seed)
    force, temp, avail = flight_effect_inputs(fl)
    assert avail["specific_force"] == list(range(6)) and temp is None
    g = cal.gyro
    y0 = fl.raw * g.scale_factors - g.biases
    thr_rate = Monitor(cal).thresholds.false_alarms_per_hour
    allowed = int(poisson.isf(1e-3, thr_rate * FLIGHT_S / 3600.0))
    # without compensation: the premise (a parity bias of many σ, alarms)
    z_off = residual_z(cal, y0)
    off = CompensatedMonitor(Monitor(cal), Compensator(cal, enabled=False)).run(
        fl.t, fl.raw, fl.valid, force=force)
    assert np.max(np.abs(z_off)) > 10, z_off
    assert sum(e.type == "detected" for e in off.events) > allowed
    # with compensation
    comp = Compensator(cal, available=avail)
    assert len(comp.applied) == 3
    on = CompensatedMonitor(Monitor(cal), comp).run(fl.t, fl.raw, fl.valid, force=force,
                                                    parity=True)
    assert sum(e.type == "detected" for e in on.events) <= allowed
    assert on.healthy.all()
    # the monitor's own parity vectors: p = V·(y − c); per-sensor residual Vᵀ·p
    from fdi.parity import parity_matrix

    V = parity_matrix(g.H)
    z_on = (on.parity @ V).mean(axis=0) / np.sqrt(
        np.diag(V.T @ V @ g.noise_covariance @ V.T @ V) / len(fl.t))
    assert np.all(np.abs(z_on) < 3), z_on
    np.testing.assert_allclose(z_on, residual_z(cal, y0 - comp.block(fl.raw, force)),
                               rtol=1e-6, atol=1e-6)
    assert comp.missing == {("g_sensitivity", 1): 0, ("g_sensitivity", 3): 0}


# -- end to end with fitted terms (rimu calibrate turntable --effects on a simulated session) --
@pytest.fixture(scope="module")
def fitted_tetrad():
    from calibration.calibrate_checked import calibrate_checked

    seq, truth, noise = preset("tetrad-paper")
    s = simulate_session(None, seq, truth, seed=7, noise=noise,
                         effects={"g_sensitivity": K_G, "scale_asymmetry": A_ASYM},
                         effect_sensors=[1, 3])
    cal = calibrate_checked(s, effects=["g_sensitivity", "scale_asymmetry"],
                            noise_model="white")
    return cal, truth


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_fitted_terms_compensate_a_flight(fitted_tetrad, seed):
    """Terms fitted by ``calibrate --effects`` on a session with the effects (sensors 1
    and 3), applied to a flight of the same true sensors with the same effects: the
    residual mean is within 3 σ, σ from the flight noise and the calibration's own reported
    uncertainties (bias_sd, input_error_cov at the mean rate, each term's estimate_sd times
    the mean of its regressor; sensors independent); uncompensated it is not, and alarms."""
    from fdi.parity import parity_matrix

    cal, truth = fitted_tetrad
    assert {(t.name, t.sensor) for t in cal.effects} >= {("g_sensitivity", 0),
                                                        ("scale_asymmetry", 2)}
    dur = 120.0
    fl = flight_with_effects(cal, seed, truth=truth, duration_s=dur, max_rate_dps=100.0,
                             effects={(nm, i): v for i in (0, 2) for nm, v in
                                      (("scale_asymmetry", A_ASYM), ("g_sensitivity", K_G))})
    force, _, avail = flight_effect_inputs(fl)
    comp = Compensator(cal, available=avail)
    assert len(comp.applied) == len(cal.effects) == 8 and comp.skipped == ()
    on = CompensatedMonitor(Monitor(cal), comp).run(fl.t, fl.raw, fl.valid, force=force,
                                                    parity=True)
    off = Monitor(cal).run(fl.t, fl.raw, fl.valid, parity=True)
    g = cal.gyro
    N = len(fl.t)
    s_hat = fl.raw * g.scale_factors - g.biases
    w = fl.omega_true.mean(axis=0)
    var = np.array([c.bias_sd ** 2 + w @ c.input_error_cov @ w for c in g.sensors])
    for a in comp.applied:
        i, t = a.term.sensor, a.term
        zbar = (0.5 * np.mean(np.abs(s_hat[:, i])) if t.name == "scale_asymmetry"
                else DPH * np.mean(force[:, i] @ g.H[i]) / 9.80665)
        var[i] += (t.estimate_sd * zbar) ** 2
    V = parity_matrix(g.H)
    P = V.T @ V
    sd = np.sqrt(np.diag(P @ (np.diag(var) + g.noise_covariance / N) @ P.T))
    z_on = (on.parity @ V).mean(axis=0) / sd
    z_off = (s_hat @ P.T).mean(axis=0) / sd
    allowed = int(poisson.isf(1e-3, Monitor(cal).thresholds.false_alarms_per_hour * dur
                              / 3600.0))
    assert np.max(np.abs(z_off)) > 4, z_off
    assert sum(e.type == "detected" for e in off.events) > allowed
    assert np.all(np.abs(z_on) < 3), z_on
    assert sum(e.type == "detected" for e in on.events) <= allowed


def test_step_path_equals_block_path(effect_cal):
    """CompensatedMonitor.step (live, realtime replay) gives the block path's answers."""
    cal = effect_cal
    fl = flight_with_effects(cal, 4, duration_s=8.0)
    force, _, avail = flight_effect_inputs(fl)
    blk = CompensatedMonitor(Monitor(cal), Compensator(cal, available=avail)).run(
        fl.t, fl.raw, fl.valid, force=force)
    mon = CompensatedMonitor(Monitor(cal), Compensator(cal, available=avail))
    answers = [mon.step(float(fl.t[k]), fl.raw[k], fl.valid[k], force=force[k])
               for k in range(len(fl.t))]
    np.testing.assert_allclose(np.array([a.omega for a in answers]), blk.omega, rtol=1e-12,
                               atol=1e-15)
    np.testing.assert_allclose(np.array([a.statistics for a in answers]), blk.statistics,
                               rtol=1e-9, atol=1e-12)
    assert mon.sensor_names == tuple(c.name for c in cal.gyro.sensors)     # delegated


def test_temperature_term_compensated_from_the_flight_temperature(effect_cal):
    """A temperature coefficient on sensor 5 and a warming temperature channel: compensated,
    the residual mean is within 3 σ; uncompensated many σ; a NaN stretch is counted."""
    from replay.flight_data import AuxChannels

    cal = dataclasses.replace(effect_cal, effects=(
        *effect_cal.effects, EffectTerm("temperature", "gyro", 4, 20.0, 0.1, "deg/h per degC",
                                        ("temperature",), {"reference_degC": 25.0})))
    fl = flight_with_effects(cal, 5)
    t = fl.t - fl.t[0]
    T = 25.0 + 30.0 * (1 - np.exp(-t / 20.0))
    Tm = T + 0.05 * np.random.default_rng(8).standard_normal(T.size)
    Tm[100:150] = np.nan                                    # logger dropout
    g = cal.gyro
    raw = fl.raw.copy()
    raw[:, 4] += 20.0 * DPH * (T - 25.0) / g.scale_factors[4]
    aux = fl.aux
    aux = AuxChannels((*aux.kinds, "temperature"), (*aux.names, "board"), (*aux.imu, ""),
                      np.column_stack([aux.values, Tm]),
                      np.column_stack([aux.valid, np.isfinite(Tm)]))
    fl = dataclasses.replace(fl, raw=raw, aux=aux)
    force, temp, avail = flight_effect_inputs(fl)
    comp = Compensator(cal, available=avail)
    assert [a.term.name for a in comp.applied][-1] == "temperature"
    y0 = fl.raw * g.scale_factors - g.biases
    c = comp.block(fl.raw, force, temp)
    assert comp.missing[("temperature", 4)] == 50
    z_on, z_off = residual_z(cal, y0 - c), residual_z(cal, y0)
    # the 50 uncompensated samples leave a bias of 50/N of the effect there (≈ 0.3 σ here)
    assert np.all(np.abs(z_on) < 3), z_on
    assert np.max(np.abs(z_off)) > 10, z_off


@pytest.mark.slow
def test_compensated_residual_is_honest_over_seeds(effect_cal):
    """30 flights: the compensated per-sensor residual mean over its noise σ has an RMS
    near 1 (the asymmetry's |ŝ| noise bias and the accelerometer noise add no visible bias)
    and its mean near 0."""
    cal = effect_cal
    g = cal.gyro
    zs = []
    for seed in range(100, 130):
        fl = flight_with_effects(cal, seed)
        force, _, avail = flight_effect_inputs(fl)
        c = Compensator(cal, available=avail).block(fl.raw, force)
        zs.append(residual_z(cal, fl.raw * g.scale_factors - g.biases - c))
    z = np.array(zs)                                       # (30, 6)
    rms = float(np.sqrt(np.mean(z ** 2)))
    print(f"RMS of z over 30 seeds x 6 sensors: {rms:.3f}; means {np.round(z.mean(axis=0), 3)}")
    assert 0.6 < rms < 1.5, rms
    # per sensor, the mean over 30 seeds is within 3 σ (σ = 1/sqrt(30))
    assert np.all(np.abs(z.mean(axis=0)) < 3 / np.sqrt(30)), z.mean(axis=0)


def test_accelerometer_temperature_term():
    """A monitored accelerometer set: its temperature term (mg per °C) is applied, the gyro
    terms are listed as of the other kind."""
    from fdi.units import MG

    base = synthetic_calibration("tetrad", seed=1)
    acc = dataclasses.replace(base.gyro, kind="accel")
    cal = dataclasses.replace(base, sets={"gyro": base.gyro, "accel": acc}, effects=(
        EffectTerm("temperature", "accel", 2, 0.4, 0.01, "mg per degC", ("temperature",),
                   {"reference_degC": 21.0}),
        _t("scale_asymmetry", 0, "fraction", 1e-3)))
    comp = Compensator(cal, "accel", available={"temperature": [2]})
    assert [(a.term.kind, a.term.name) for a in comp.applied] == [("accel", "temperature")]
    assert comp.skipped[0].reason == "a gyro term; this stream monitors accel sensors"
    c = comp.block(np.zeros((3, 4)), temperature=np.array([21.0, 31.0, np.nan]))
    assert c[:, 2].tolist() == [0.0, pytest.approx(0.4 * MG * 10.0, rel=1e-12), 0.0]
    assert comp.missing == {("temperature", 2): 1}


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=4,
                max_size=4),
       st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=3, max_size=3),
       st.floats(allow_nan=True, allow_infinity=True))
def test_any_numbers_give_a_finite_correction_and_block_equals_one(raw, force, temp):
    cal = _cal_with(_t("g_sensitivity", 0, "deg/h per g", 100.0),
                    _t("temperature", 1, "deg/h per degC", 2.0, reference_degC=20.0),
                    _t("scale_asymmetry", 2, "fraction", 1e-2),
                    _t("scale_nonlinearity", 2, "fraction", 1e-3, table_rate_dps=10.0))
    comp = Compensator(cal, available={"specific_force": [0], "temperature": [1]})
    one = comp.one(raw, force, temp)
    blk = comp.block(np.array([raw]), np.array([force]), np.array([temp]))[0]
    assert np.all(np.isfinite(one))
    np.testing.assert_array_equal(one, blk)
