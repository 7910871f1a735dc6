"""Simulated flights: true model, faults, motion, chunking and the flight directory format."""

import json

import numpy as np
import pytest

from fdi.calfile import Calibration, SensorCal, SensorSet
from fdi.errors import ConfigError, FileFormatError
from fdi.geometry import load_configuration
from fdi.units import DPH, DPS
from replay.faults import Fault, parse_fault
from replay.flight import (
    CHUNK_SAMPLES,
    FLIGHT_SCHEMA,
    Flight,
    draw_true_model,
    iter_flight,
    load_flight_dir,
    save_flight_dir,
    simulate_flight,
    true_model_from_calibration,
)
from replay.motion import body_rates


def make_cal(config="cone6", *, noise_dps=0.01, sf=0.01 * DPS, err=2e-4, seed=0):
    """A calibration with realistic misalignment, bias and uncertainty (sensor units mV)."""
    cfg = load_configuration(config)
    rng = np.random.default_rng(seed)
    sens = []
    for i in range(cfg.n):
        h = cfg.H[i] + 1e-3 * rng.standard_normal(3)
        sens.append(SensorCal(
            name=cfg.sensor_names[i], axis=h / np.linalg.norm(h), axis_nominal=cfg.H[i],
            scale_factor=sf * (1 + 0.01 * i), scale_factor_sd=err * sf,
            bias=10 * DPH * rng.standard_normal(), bias_sd=(1 + i) * DPH,
            input_error_cov=np.diag([1.0, 2.0, 3.0]) * err ** 2,
            misalignment_sd=np.full(2, err), raw_unit="mV",
            scale_factor_unit="mV/(deg/s)", bias_unit="deg/h"))
    A = rng.standard_normal((cfg.n, cfg.n)) * 0.2 + np.eye(cfg.n)
    cov = (noise_dps * DPS) ** 2 * (A @ A.T) / np.mean(np.diag(A @ A.T))
    return Calibration(cfg.name, {"gyro": SensorSet("gyro", tuple(sens), cov)}, 100.0)


CAL = make_cal()


def test_motion_bounded_smooth_full_scale_and_deterministic():
    t = np.arange(0, 600, 0.01)
    w = body_rates(t, seed=4)
    assert np.abs(w).max() <= 300 * DPS * (1 + 1e-12)
    # full-scale manoeuvres: pulses whose peak exceeds 99 % of the maximum
    a = np.abs(w)
    peaks = (a[1:-1] > 0.99 * 300 * DPS) & (a[1:-1] >= a[:-2]) & (a[1:-1] > a[2:])
    minute = (t[1:-1] // 60).astype(int)
    for ax in range(3):
        per_min = peaks[:, ax].sum() / 10.0
        assert per_min >= 3, f"axis {ax}: {per_min} full-scale manoeuvres per minute"
    per_each_minute = np.bincount(minute, weights=peaks.sum(axis=1), minlength=10)
    assert per_each_minute.min() >= 5, f"full-scale manoeuvres per minute: {per_each_minute}"
    # C1: angular acceleration bounded by A·π/w_min = 300°/s·π/0.4 s
    acc = np.abs(np.diff(w, axis=0)) / 0.01
    assert acc.max() < 300 * DPS * np.pi / 0.4 * 1.01
    np.testing.assert_array_equal(w, body_rates(t, seed=4))
    assert not np.array_equal(w, body_rates(t, seed=5))
    # any time range on its own gives the same rates (chunked simulation)
    np.testing.assert_array_equal(body_rates(t[30000:31000], seed=4), w[30000:31000])


def test_chunks_equal_whole_flight():
    faults = [parse_fault("stuck:2::655.3", CAL), parse_fault("ramp:1:1sigma/s:600", CAL)]
    whole = simulate_flight(CAL, 700, seed=3, faults=faults)
    assert whole.t.shape[0] == 70000 > CHUNK_SAMPLES
    short = simulate_flight(CAL, 100, seed=3, faults=faults)
    np.testing.assert_array_equal(short.raw, whole.raw[:10000])
    pieces = list(iter_flight(CAL, 700, seed=3, faults=faults))
    assert len(pieces) == 2
    np.testing.assert_array_equal(np.concatenate([p.raw for p in pieces]), whole.raw)
    # the stuck value crosses the chunk boundary (onset sample 65530 < 65536)
    k = 65530
    assert np.all(whole.raw[k:, 1] == whole.raw[k - 1, 1])
    assert whole.raw[k - 1, 1] != whole.raw[k - 2, 1]


def _compensated_error(fl: Flight, model) -> np.ndarray:
    """raw·SF_true − h_true·ω − b_true: the noise plus the injected faults (SI)."""
    return fl.raw * model.scale_factor - fl.omega_true @ model.axis.T - model.bias


def test_true_model_is_used_and_noise_has_calibration_covariance():
    fl = simulate_flight(CAL, 400, seed=11)
    model = draw_true_model(CAL, 11)
    e = _compensated_error(fl, model)
    C = np.cov(e.T)
    S = CAL.gyro.noise_covariance
    # each entry's Monte Carlo sd ≈ sqrt((S_ii S_jj + S_ij²)/N)
    sd = np.sqrt((np.outer(np.diag(S), np.diag(S)) + S ** 2) / e.shape[0])
    z = (C - S) / sd
    assert np.abs(z).max() < 4.5, f"noise covariance off by {np.abs(z).max():.1f} sd"
    zm = e.mean(axis=0) / np.sqrt(np.diag(S) / e.shape[0])
    assert np.abs(zm).max() < 4, f"mean of the noise: {zm} standard errors"


def _rest_offset_z(cal, seeds):
    """Per seed and sensor, (ŜF·u_rest − b̂)/bias_sd: the calibrated output at zero input
    minus the calibrated bias, in units of the stated bias uncertainty."""
    zb = []
    for seed in seeds:
        m = draw_true_model(cal, seed)
        for i, c in enumerate(cal.gyro.sensors):
            u_rest = m.bias[i] / m.scale_factor[i]              # raw output at zero input
            zb.append((c.scale_factor * u_rest - c.bias) / c.bias_sd)
    return np.array(zb)


def test_true_parameters_drawn_from_calibration_covariance():
    """(a_true − a_cal) ~ N(0, input_error_cov), and the calibrated output at rest minus b̂
    ~ N(0, bias_sd²) (what the calibration measured), over seeds."""
    zs = []
    for seed in range(400):
        m = draw_true_model(CAL, seed)
        for i, c in enumerate(CAL.gyro.sensors):
            a_true = m.axis[i] * c.scale_factor / m.scale_factor[i]   # gain-normalised
            d = a_true - c.axis
            zs.append(d / np.sqrt(np.diag(c.input_error_cov)))
    zs, zb = np.array(zs), _rest_offset_z(CAL, range(400))
    for k in range(3):
        v = zs[:, k].var()
        assert 0.9 < v < 1.1, f"axis error component {k}: variance/expected {v:.3f}"
    assert 0.9 < zb.var() < 1.1, f"bias error variance/expected {zb.var():.3f}"
    assert abs(zs.mean()) < 3 / np.sqrt(zs.size) * 1.5 and abs(zb.mean()) < 3 / np.sqrt(zb.size)
    # calibration error is present: the model differs from the calibration
    m = draw_true_model(CAL, 0)
    assert np.all(m.axis != CAL.gyro.H) and np.all(m.bias != CAL.gyro.biases)


def test_rest_offset_stays_within_bias_sd_for_a_large_mems_bias():
    """A MEMS gyro with a 3 °/s bias and a 3 % scale-factor tolerance: a scale-factor error
    must not move the output at rest (the calibration measured its bias there), so the
    offset at rest stays N(0, bias_sd²). Drawing b_true around b̂ in input units instead
    gave an offset of (g − 1)·b̂: 0.09 °/s (1 sd) here, 65 bias_sd."""
    from dataclasses import replace

    s = CAL.gyro
    big = tuple(replace(c, bias=3.0 * DPS * (1 if i % 2 else -1), bias_sd=5 * DPH,
                        input_error_cov=np.eye(3) * 0.03 ** 2)
                for i, c in enumerate(s.sensors))
    cal = Calibration(CAL.configuration, {"gyro": replace(s, sensors=big)},
                      CAL.sample_rate_hz)
    zb = _rest_offset_z(cal, range(300))
    n = zb.size
    assert abs(zb.mean()) < 3 / np.sqrt(n), f"mean rest offset {zb.mean():.3f} bias_sd"
    # variance of n standard normals: sd of the sample variance sqrt(2/n)
    assert abs(zb.var() - 1.0) < 3 * np.sqrt(2.0 / n), \
        f"rest offset variance {zb.var():.3f} bias_sd² (expected 1)"


def test_truth_calibration_used_as_is():
    truth = make_cal(seed=9)
    fl = simulate_flight(CAL, 20, seed=1, truth=truth)
    model = true_model_from_calibration(truth, CAL)
    np.testing.assert_array_equal(model.axis, truth.gyro.H)
    np.testing.assert_array_equal(model.scale_factor, truth.gyro.scale_factors)
    e = _compensated_error(fl, model)
    assert np.abs(e).max() < 6 * np.sqrt(np.diag(truth.gyro.noise_covariance)).max()
    assert fl.truth["true_parameters"]["source"] == "truth"
    # the (Calibration, effects, effect_sensors) tuple load_truth returns works too
    m2 = true_model_from_calibration((truth, {}, {}), CAL)
    np.testing.assert_array_equal(m2.bias, model.bias)
    with pytest.raises(ConfigError, match="4 gyro sensors"):
        true_model_from_calibration(make_cal("tetrad"), CAL)


@pytest.mark.parametrize("spec", ["step:3:15sigma:5", "ramp:2:2sigma/s:5:3", "scale:4:1%:5",
                                  "spike:5:50sigma:5", "spike:5:50sigma:5:0.05"])
def test_additive_faults_exact(spec):
    f = parse_fault(spec, CAL)
    base = simulate_flight(CAL, 10, seed=2)
    fl = simulate_flight(CAL, 10, seed=2, faults=[f])
    model = draw_true_model(CAL, 2)
    i = f.sensor - 1
    d = (fl.raw - base.raw) * model.scale_factor       # injected input (SI)
    t = fl.t
    win = (t >= f.onset - 1e-12) & (t < f.end - 1e-12)
    if f.kind == "step":
        want = np.where(win, f.size, 0.0)
    elif f.kind == "ramp":
        want = np.where(win, f.size * (t - f.onset), 0.0)
    elif f.kind == "scale":
        want = np.where(win, f.size * (fl.omega_true @ model.axis[i]), 0.0)
    elif f.duration is None:
        want = np.where(np.arange(t.size) == 500, f.size, 0.0)
    else:
        want = np.where(win, f.size, 0.0)
    np.testing.assert_allclose(d[:, i], want, atol=1e-12, err_msg=spec)
    others = np.delete(d, i, axis=1)
    assert np.all(others == 0), f"{spec}: other sensors changed"
    assert fl.faults == (f,) and fl.truth["faults"][0]["spec"] == spec


def test_stuck_noise_dropout():
    fs = [parse_fault("stuck:1::3:2", CAL), parse_fault("noise:2:3x:2", CAL),
          parse_fault("dropout:6::4:1.5", CAL)]
    base = simulate_flight(CAL, 60, seed=5)
    fl = simulate_flight(CAL, 60, seed=5, faults=fs)
    # stuck: samples 300..499 repeat sample 299; afterwards the sensor moves again
    assert np.all(fl.raw[300:500, 0] == base.raw[299, 0])
    np.testing.assert_array_equal(fl.raw[500:, 0], base.raw[500:, 0])
    # noise ×3: the difference to the healthy flight is 2η exactly
    model = draw_true_model(CAL, 5)
    e_base = _compensated_error(base, model)[200:, 1]
    d = (fl.raw[200:, 1] - base.raw[200:, 1]) * model.scale_factor[1]
    np.testing.assert_allclose(d, 2 * e_base, atol=1e-12, err_msg="noise growth")
    np.testing.assert_array_equal(fl.raw[:200, 1], base.raw[:200, 1])
    # dropout: no sample from sensor 6 in [4, 5.5) s, NaN raw
    gone = ~fl.valid[:, 5]
    np.testing.assert_array_equal(np.flatnonzero(gone), np.arange(400, 550))
    assert np.all(np.isnan(fl.raw[gone, 5])) and fl.valid[:, :5].all()


def test_other_sample_rate_keeps_noise_density():
    fl = simulate_flight(CAL, 100, seed=8, sample_rate_hz=400.0)
    assert fl.sample_rate_hz == 400.0 and fl.t.shape[0] == 40000
    np.testing.assert_allclose(fl.t[1], 1 / 400.0)
    model = draw_true_model(CAL, 8)
    e = _compensated_error(fl, model)
    ratio = e.var(axis=0) / (np.diag(CAL.gyro.noise_covariance) * 4.0)
    # variance of a sample variance: 2/N relative, N = 40000 → sd 0.7 %
    assert np.all(np.abs(ratio - 1) < 0.04), ratio


def test_bias_drift_statistics_and_chunking():
    """Gauss-Markov bias: stationary sd σ and correlation e⁻¹ at τ; random walk: q²·Δt."""
    sig, tau, q = 0.05 * DPS, 2.0, 0.01 * DPS
    base = simulate_flight(CAL, 700, seed=6)
    gm = simulate_flight(CAL, 700, seed=6, bias_instability=sig, bias_correlation_s=tau)
    model = draw_true_model(CAL, 6)
    b = (gm.raw - base.raw) * model.scale_factor           # the drift alone (SI)
    # 700 s / 2 s ≈ 350 independent stretches per sensor, 6 sensors: var within ~±8 %
    ratio = b.var() / sig ** 2
    assert abs(ratio - 1) < 0.25, f"GM variance ratio {ratio:.3f}"
    lag = round(tau * 100)
    rho = np.mean(b[lag:] * b[:-lag]) / np.mean(b * b)
    assert abs(rho - np.exp(-1)) < 0.08, f"GM correlation at tau {rho:.3f}"
    # the drift crosses the chunk boundary smoothly and a shorter flight is its prefix
    short = simulate_flight(CAL, 100, seed=6, bias_instability=sig, bias_correlation_s=tau)
    np.testing.assert_array_equal(short.raw, gm.raw[:10000])
    k = CHUNK_SAMPLES
    jump = np.abs(b[k] - b[k - 1]) / (sig * np.sqrt(2 / (100 * tau)))
    assert np.all(jump < 5), f"drift jumps at the chunk boundary: {jump}"
    rw = simulate_flight(CAL, 700, seed=6, random_walk=q)
    r = (rw.raw - base.raw) * model.scale_factor
    inc = r[100:] - r[:-100]                                 # 1-s increments: var q²·1 s
    ratio = inc[::100].var() / q ** 2
    assert abs(ratio - 1) < 0.15, f"random walk increment variance ratio {ratio:.3f}"
    assert rw.truth["bias_drift"]["random_walk"] == [q] * 6
    with pytest.raises(ConfigError, match="bias_instability"):
        simulate_flight(CAL, 1, seed=0, bias_instability=[1.0, 2.0])


def test_bad_arguments():
    with pytest.raises(ConfigError, match="out of range"):
        simulate_flight(CAL, 1, seed=0, faults=[Fault("step", 7, 1.0, 0.0)])
    with pytest.raises(ConfigError, match="duration"):
        simulate_flight(CAL, 0, seed=0)
    with pytest.raises(ConfigError, match="no accel"):
        simulate_flight(CAL, 1, seed=0, kind="accel")


def _flight_with_gaps():
    fl = simulate_flight(CAL, 3, seed=1, faults=[parse_fault("dropout:2::1:0.5", CAL),
                                                 parse_fault("step:4:6sigma:2", CAL)])
    raw = fl.raw.copy()
    raw[10, 3] = np.inf          # values the sensor sent: stay valid
    raw[11, 3] = -np.inf
    raw[12, 3] = np.nan
    raw[13, 3] = 1e300
    return Flight(**{**fl.__dict__, "raw": raw})


def test_directory_round_trip(tmp_path):
    fl = _flight_with_gaps()
    save_flight_dir(fl, tmp_path / "f")
    man = json.loads((tmp_path / "f" / "manifest.json").read_text())
    assert man["schema"] == FLIGHT_SCHEMA and man["columns"][0] == "t"
    g = load_flight_dir(tmp_path / "f")
    np.testing.assert_array_equal(g.t, fl.t)
    np.testing.assert_array_equal(g.raw, fl.raw)          # NaN == NaN here, inf kept
    np.testing.assert_array_equal(g.valid, fl.valid)
    assert g.valid[12, 3] and np.isnan(g.raw[12, 3]) and not g.valid[120, 1]
    np.testing.assert_array_equal(g.omega_true, fl.omega_true)
    assert g.faults == fl.faults
    assert g.sensor_names == fl.sensor_names and g.raw_unit == "mV"
    assert g.sample_rate_hz == 100.0 and g.kind == "gyro"
    assert g.truth["true_parameters"] == json.loads(json.dumps(fl.truth["true_parameters"]))
    # a recorded flight without truth
    rec = Flight(t=fl.t, raw=fl.raw, valid=fl.valid, sample_rate_hz=100.0,
                 sensor_names=fl.sensor_names)
    save_flight_dir(rec, tmp_path / "f")
    h = load_flight_dir(tmp_path / "f")
    assert h.omega_true is None and h.faults == () and h.truth == {}


def _write_dir(tmp_path, rows, *, manifest=None):
    d = tmp_path / "bad"
    d.mkdir(exist_ok=True)
    m = {"schema": FLIGHT_SCHEMA, "sample_rate_hz": 100.0, "sensor_names": ["a", "b"],
         "raw_unit": "mV", "columns": ["t", "a", "b"]}
    m.update(manifest or {})
    (d / "manifest.json").write_text(json.dumps(m))
    (d / "samples.csv").write_text("t,a,b\n" + "".join(r + "\n" for r in rows))
    return d


def test_empty_cells_and_crlf(tmp_path):
    d = _write_dir(tmp_path, ["0,1,", "0.01,,2", "0.02,nan,inf"])
    (d / "samples.csv").write_bytes((d / "samples.csv").read_bytes().replace(b"\n", b"\r\n"))
    g = load_flight_dir(d)
    np.testing.assert_array_equal(g.valid, [[True, False], [False, True], [True, True]])
    assert g.raw[0, 0] == 1 and g.raw[1, 1] == 2 and np.isinf(g.raw[2, 1])


@pytest.mark.parametrize(("rows", "manifest", "words"), [
    (["0,1,2", "0.01,1,x2"], None, "samples.csv:3, field 'b': 'x2' is not a number"),
    (["0,1,2", "0.01,1"], None, "samples.csv:3: 2 cells, expected 3"),
    (["0,1,2", "0.01,1,2,3"], None, "samples.csv:3: 4 cells, expected 3"),
    (["0,1,2", ",1,2"], None, "samples.csv:3, field 't': empty time"),
    (["0,1,2", "-1,1,2"], None, "samples.csv:3, field 't': time goes backwards"),
    (["0,1,2"], {"schema": "rimu.flight/2"}, "field 'schema': unsupported version 'rimu.flight/2'"),
    (["0,1,2"], {"schema": "rimu.session/1"}, "field 'schema': expected 'rimu.flight/1'"),
    (["0,1,2"], {"sample_rate_hz": -1}, "field 'sample_rate_hz'"),
    (["0,1,2"], {"sensor_names": "ab"}, "field 'sensor_names'"),
    (["0,1,2"], {"columns": ["t", "b", "a"]}, "field 'columns'"),
    (["0,1,2"], {"samples": 5}, "field 'samples': says 5 samples"),
])
def test_load_errors_are_precise(tmp_path, rows, manifest, words):
    d = _write_dir(tmp_path, rows, manifest=manifest)
    with pytest.raises(FileFormatError) as ei:
        load_flight_dir(d)
    assert words in str(ei.value), str(ei.value)


def test_header_and_truth_errors(tmp_path):
    d = _write_dir(tmp_path, ["0,1,2"])
    (d / "samples.csv").write_text("t,b,a\n0,1,2\n")
    with pytest.raises(FileFormatError, match=r"samples\.csv:1: header"):
        load_flight_dir(d)
    d = _write_dir(tmp_path, ["0,1,2"])
    (d / "truth.json").write_text(json.dumps({"schema": "rimu.flight-truth/1",
                                              "faults": [{"kind": "step"}]}))
    with pytest.raises(FileFormatError, match=r"truth.json, field 'faults\[0\]'"):
        load_flight_dir(d)
    np.save(d / "truth_rates.npy", np.zeros((2, 3)))
    (d / "truth.json").write_text(json.dumps({"schema": "rimu.flight-truth/1", "faults": [],
                                              "rates_file": "truth_rates.npy"}))
    with pytest.raises(FileFormatError, match=r"truth_rates.npy: expected shape \(1, 3\)"):
        load_flight_dir(d)
    (d / "manifest.json").unlink()
    with pytest.raises(FileFormatError, match=r"manifest\.json: cannot read"):
        load_flight_dir(d)
