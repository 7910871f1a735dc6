"""The session simulator: model step means, noise, Earth rate, effects, truth, presets."""

from __future__ import annotations

import json

import numpy as np
import pytest

from calibration.effects import EFFECTS, WARMUP_TAU_S, parse_effect_sensors, parse_effects
from calibration.presets import preset, random_truth
from calibration.simulate import SessionNoise, simulate_session, true_raw_means
from calibration.truth import load_truth, save_truth
from fdi.calfile import load_calibration
from fdi.errors import ConfigError, FileFormatError
from fdi.geometry import cone6, tetrad
from fdi.parity import calibrated_axes, parity_matrix
from fdi.units import DPH, DPS, G0, scale_factor_from_si


def _zscores(session, truth):
    """(step mean − model mean)/σ_mean for every step and sensor, per kind."""
    means = true_raw_means(session, truth)
    out = {}
    for kind, raw in (("gyro", session.raw_gyro), ("accel", session.raw_accel)):
        if raw is None:
            continue
        sd = truth.sets[kind].noise_sd / truth.sets[kind].scale_factors
        z = []
        for k, st in enumerate(session.steps):
            m = session.step == st.index
            z.append((raw[m].mean(0) - means[kind][k]) / (sd / np.sqrt(m.sum())))
        out[kind] = np.array(z)
    return out


@pytest.mark.parametrize("name", ["tetrad-paper", "cone-paper"])
def test_step_means_equal_model_within_noise(name, request):
    session = request.getfixturevalue("tetrad_session" if name == "tetrad-paper"
                                      else "cone_session")
    _, truth, _ = preset(name)
    for kind, z in _zscores(session, truth).items():
        assert np.abs(z).max() < 4.0, f"{name} {kind}: max |z| = {np.abs(z).max():.2f}"
        assert 0.75 < z.std() < 1.25, f"{name} {kind}: std of z = {z.std():.3f}"
        assert abs(z.mean()) < 4.0 / np.sqrt(z.size), f"{name} {kind}: mean z {z.mean():.3f}"


@pytest.mark.parametrize("name", ["tetrad-paper", "cone-paper"])
def test_noise_free_is_the_model_exactly(name, noise_free):
    seq, truth, _ = preset(name)
    s = simulate_session(None, seq, truth, seed=0, noise=noise_free)
    wt, we, fb = s.inputs()
    g = truth.gyro
    np.testing.assert_allclose(s.raw_gyro, ((wt + we) @ g.H.T + g.biases) / g.scale_factors,
                               rtol=1e-13, atol=0, err_msg="gyro raw")
    if "accel" in truth.sets:
        a = truth.sets["accel"]
        np.testing.assert_allclose(s.raw_accel, (fb @ a.H.T + a.biases) / a.scale_factors,
                                   rtol=1e-13, err_msg="accel raw")


def test_white_noise_level(tetrad_session, cone_session, noise_free):
    for name, s in (("tetrad-paper", tetrad_session), ("cone-paper", cone_session)):
        seq, truth, _ = preset(name)
        clean = simulate_session(None, seq, truth, seed=0, noise=noise_free)
        for kind, raw, ref in (("gyro", s.raw_gyro, clean.raw_gyro),
                               ("accel", s.raw_accel, clean.raw_accel)):
            if raw is None:
                continue
            st = truth.sets[kind]
            e = (raw - ref) * st.scale_factors                 # input units (SI)
            np.testing.assert_allclose(e.std(0), st.noise_sd, rtol=0.02,
                                       err_msg=f"{name} {kind} noise sd")
            c = np.corrcoef(e.T)
            assert np.abs(c - np.eye(st.n)).max() < 0.03, f"{name} {kind}: correlated noise"


def test_earth_rate_applied_and_switchable(tetrad_preset, noise_free):
    seq, truth, _ = tetrad_preset
    on = simulate_session(None, seq, truth, seed=0, noise=noise_free)
    off = simulate_session(None, seq, truth, seed=0, noise=noise_free,
                           effects={"no_earth_rate": 1})
    _, we, _ = on.inputs()
    g = truth.gyro
    np.testing.assert_allclose((on.raw_gyro - off.raw_gyro) * g.scale_factors, we @ g.H.T,
                               atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(we, axis=1), 15.041 * DPH, rtol=1e-4)
    assert off.meta["effect_sensors"]["no_earth_rate"] == [1, 2, 3, 4]


# -- effects: each changes what it should on the sensors it names, and nothing else ---------
def _effect_expected(name, value, session, truth, w_ref):
    """Expected change of the compensated gyro input (SI), per sample and sensor."""
    wt, we, fb = session.inputs()
    H = truth.gyro.H
    s = (wt + we) @ H.T
    t = session.t
    T = session.t.size / session.sample_rate_hz
    if name == "g_sensitivity":
        return value * DPH * (fb @ H.T) / G0
    if name == "scale_asymmetry":
        return 0.5 * value * np.abs(s)
    if name == "scale_nonlinearity":
        return value * s**2 / w_ref
    if name == "warmup":
        return value * DPH * np.exp(-t / WARMUP_TAU_S)[:, None] * np.ones_like(s)
    if name == "bias_drift":
        return value * DPH * (t / T)[:, None] * np.ones_like(s)
    raise AssertionError(name)


@pytest.mark.parametrize(("name", "value"), [("g_sensitivity", 50.0), ("scale_asymmetry", 0.01),
                                             ("scale_nonlinearity", 0.005), ("warmup", 30.0),
                                             ("bias_drift", 10.0)])
def test_gyro_effects_touch_only_named_sensors(cone_preset, name, value):
    seq, truth, noise = cone_preset
    base = simulate_session(None, seq, truth, seed=5, noise=noise)
    eff = simulate_session(None, seq, truth, seed=5, noise=noise, effects={name: value},
                           effect_sensors=[1, 3])
    d = (eff.raw_gyro - base.raw_gyro) * truth.gyro.scale_factors
    want = _effect_expected(name, value, base, truth, seq.table_rate)
    named = np.array([True, False, True, False, False, False])
    np.testing.assert_allclose(d[:, named], want[:, named], rtol=1e-6,
                               atol=1e-9 * np.abs(want).max(), err_msg=name)
    assert np.abs(want[:, named]).max() > 0, f"{name}: the check must see a change"
    np.testing.assert_array_equal(eff.raw_gyro[:, ~named], base.raw_gyro[:, ~named],
                                  err_msg=f"{name}: other gyros")
    np.testing.assert_array_equal(eff.raw_accel, base.raw_accel, err_msg=f"{name}: accels")
    for col in ("t", "inner", "outer", "inner_rate", "outer_rate", "step"):
        np.testing.assert_array_equal(getattr(eff, col), getattr(base, col), err_msg=col)
    assert eff.meta["effects"] == {name: value}
    assert eff.meta["effect_sensors"] == {name: [1, 3]}


def test_time_skew_delays_the_input(cone_preset, noise_free):
    seq, truth, _ = cone_preset
    fs = truth.sample_rate_hz
    k = 3
    base = simulate_session(None, seq, truth, seed=1, noise=noise_free)
    sk = simulate_session(None, seq, truth, seed=1, noise=noise_free,
                          effects={"time_skew": k / fs}, effect_sensors=[2])
    changed = False
    for st in seq.steps:
        idx = np.flatnonzero(base.step == st.index)
        for kind in ("raw_gyro", "raw_accel"):
            a, b = getattr(base, kind)[idx], getattr(sk, kind)[idx]
            # sensor 2 reads, at sample j, what it would have read at sample j - k
            np.testing.assert_allclose(b[k:, 1], a[:-k, 1], rtol=1e-12,
                                       err_msg=f"step {st.index} {kind}")
            others = [0, 2, 3, 4, 5]
            np.testing.assert_array_equal(b[:, others], a[:, others])
            changed |= bool(np.any(np.abs(b[:, 1] - a[:, 1]) > 1e-9 * np.abs(a[:, 1])))
    assert changed, "time skew must change a sensor whose input varies"


def test_effect_parsing_and_help():
    assert parse_effects(["g_sensitivity=10,time_skew=0.002", "no_earth_rate"]) == {
        "g_sensitivity": 10.0, "time_skew": 0.002, "no_earth_rate": 1.0}
    assert parse_effect_sensors("3, 1") == (1, 3)
    for bad in ("bogus=1", "warmup", "warmup=abc", "no_earth_rate=2", "warmup=nan"):
        with pytest.raises(ConfigError):
            parse_effects(bad)
    with pytest.raises(ConfigError):
        parse_effect_sensors("0")
    from calibration.effects import effects_help
    h = effects_help()
    for e in EFFECTS.values():
        assert e.name in h and e.unit in h


def test_effect_sensor_out_of_range(tetrad_preset):
    seq, truth, _ = tetrad_preset
    with pytest.raises(ConfigError, match="sensor 5"):
        simulate_session(None, seq, truth, seed=0, effects={"warmup": 1}, effect_sensors=[5])


def test_noise_processes(tiny_sequence, cone_preset):
    _, truth, _ = cone_preset
    q = 1e-3
    rw = simulate_session(None, tiny_sequence, truth, seed=2,
                          noise=SessionNoise(white=False, random_walk={"gyro": q}))
    clean = simulate_session(None, tiny_sequence, truth, seed=2, noise=SessionNoise(white=False))
    inc = np.diff((rw.raw_gyro - clean.raw_gyro) * truth.gyro.scale_factors, axis=0)
    # increments of a random walk of density q at fs: sd q/sqrt(fs); 6*299 increments
    np.testing.assert_allclose(inc.std(), q / np.sqrt(truth.sample_rate_hz), rtol=0.06)
    np.testing.assert_array_equal(rw.raw_accel, clean.raw_accel)
    seq, _, _ = cone_preset
    sd = 0.05 * DPS
    gm = simulate_session(None, seq, truth, seed=3,
                          noise=SessionNoise(white=False, bias_instability={"gyro": sd},
                                           bias_correlation_s=0.5))
    clean = simulate_session(None, seq, truth, seed=3, noise=SessionNoise(white=False))
    b = (gm.raw_gyro - clean.raw_gyro) * truth.gyro.scale_factors
    # stationary Gauss-Markov: sd as set; ~ 6 * 368 s / (2 * 0.5 s) independent pieces
    np.testing.assert_allclose(b.std(), sd, rtol=0.1)


def test_simulate_errors(tetrad_preset, cone_preset):
    seq, truth, _ = tetrad_preset
    with pytest.raises(ConfigError, match="gyros"):
        simulate_session(cone6(), seq, truth, seed=0)
    import dataclasses
    with pytest.raises(ConfigError, match="latitude"):
        simulate_session(tetrad(), seq, dataclasses.replace(truth, latitude_deg=None), seed=0)


# -- presets and truth -----------------------------------------------------------------------
def test_tetrad_preset_is_seed000():
    _, truth, _ = preset("tetrad-paper")
    g = truth.gyro
    sf = [scale_factor_from_si(c.scale_factor, c.scale_factor_unit) for c in g.sensors]
    np.testing.assert_allclose(sf, [26.6259, 26.0274, 26.0730, 26.7118], rtol=1e-12,
                               err_msg="Table 2 SF (mV/deg/s)")
    np.testing.assert_allclose(g.biases / DPS, [0.0015563, 0.0024357, 0.0031409, 0.0015402],
                               rtol=1e-12, err_msg="Table 2 bias (deg/s)")
    # seed 000 Eq. 25: the corrected parity vector of the true axes
    np.testing.assert_allclose(parity_matrix(g.H)[0], [-0.40955, -0.40903, -0.40585, 0.70729],
                               atol=5e-6, err_msg="Eq. 25 v_c")
    np.testing.assert_allclose(np.linalg.norm(g.H, axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(calibrated_axes(g.H_nominal, g.groups,
                                               list(g.misalignment_matrices)), g.H, atol=1e-15)
    assert truth.latitude_deg == -23.2 and truth.sample_rate_hz == 100.0


def test_cone_preset_is_seed001_order():
    _, truth, _ = preset("cone-paper")
    for kind in ("gyro", "accel"):
        s = truth.sets[kind]
        np.testing.assert_allclose(np.linalg.norm(s.H, axis=1), 1.0, atol=1e-12)
        ang = np.array([c.misalignment for c in s.sensors])
        assert np.abs(ang).max() < 0.05, f"{kind}: small-angle misalignments"
        for M in s.misalignment_matrices:
            np.testing.assert_allclose(np.linalg.norm(M, axis=1), 1.0, atol=1e-12)
    M1 = truth.gyro.misalignment_matrices[0]
    assert M1[0, 1] == pytest.approx(-1.8872e-2)          # printed -1.8872e-1, see presets
    assert M1[0, 0] == pytest.approx(0.99981, abs=1e-5)   # the printed m_xx, unit row
    sf = [scale_factor_from_si(c.scale_factor, c.scale_factor_unit) for c in truth.gyro.sensors]
    np.testing.assert_allclose(sf, [0.38228, 0.39791, 0.38469, 0.38673, 0.39207, 0.38685])
    assert truth.sets["accel"].sensors[0].scale_factor_unit == "(g)/LSB"


def test_truth_round_trip(tmp_path, cone_preset):
    _, truth, _ = cone_preset
    p = tmp_path / "truth.json"
    save_truth(truth, {"warmup": 20.0}, {"warmup": (1, 3)}, p, details={"warmup": {"tau_s": 300}})
    cal, eff, sens = load_truth(p)
    assert eff == {"warmup": 20.0} and sens == {"warmup": (1, 3)}
    for kind in ("gyro", "accel"):
        a, b = truth.sets[kind], cal.sets[kind]
        np.testing.assert_allclose(b.H, a.H, atol=1e-15)
        np.testing.assert_allclose(b.scale_factors, a.scale_factors, rtol=1e-14)
        np.testing.assert_allclose(b.biases, a.biases, rtol=1e-14)
        np.testing.assert_allclose(b.noise_covariance, a.noise_covariance, rtol=1e-14)
        assert all(c.scale_factor_sd == 0 and c.bias_sd == 0 for c in b.sensors)
    doc = json.loads(p.read_text())
    assert doc["schema"] == "rimu.truth/1"
    assert doc["effect_units"] == {"warmup": "deg/h"}
    assert doc["sensors"]["gyro"][0]["bias_unit"] == "deg/s"
    # a truth file is not a calibration file, and the other way round
    with pytest.raises(FileFormatError) as ei:
        load_calibration(p)
    assert ei.value.field == "schema"
    truth.save(tmp_path / "cal.json")
    with pytest.raises(FileFormatError) as ei:
        load_truth(tmp_path / "cal.json")
    assert ei.value.field == "schema"
    doc["effects"] = {"wobble": 1.0}
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(FileFormatError) as ei:
        load_truth(tmp_path / "bad.json")
    assert ei.value.field == "effects.wobble"


def test_random_truth_is_seeded():
    a = random_truth(cone6(), seed=4)
    b = random_truth(cone6(), seed=4)
    c = random_truth(cone6(), seed=5)
    np.testing.assert_array_equal(a.gyro.H, b.gyro.H)
    assert not np.array_equal(a.gyro.H, c.gyro.H)
    assert set(a.sets) == {"gyro", "accel"}
    t = random_truth(tetrad(), seed=1)
    assert set(t.sets) == {"gyro"} and t.gyro.sensors[0].raw_unit == "mV"
    ang = np.array([s.misalignment for s in a.gyro.sensors])
    assert 1e-3 < np.abs(ang).mean() < 1e-2


@pytest.mark.slow
def test_monte_carlo_step_means_honest(tetrad_preset):
    """Over 100 seeds, each step mean's error/σ has spread within ±25 % of 1 and no bias."""
    seq, truth, noise = tetrad_preset
    zs = np.array([_zscores(simulate_session(None, seq, truth, seed=1000 + k, noise=noise),
                            truth)["gyro"] for k in range(100)])       # (100, 16, 4)
    spread = zs.std(axis=0)
    assert np.all(np.abs(spread - 1) < 0.25), f"spread {spread.min():.3f}..{spread.max():.3f}"
    # mean of 100 error/σ has sd 0.1; 4 sd keeps the family-wise false failure of the 64
    # cells near 0.4 %
    assert np.all(np.abs(zs.mean(axis=0)) < 4 / np.sqrt(100)), "mean error/σ"
