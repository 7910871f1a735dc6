"""``rimu simulate flight --effects-from-cal`` from the command line, end to end.

``simulate calibration`` (tetrad-paper, g-sensitivity 30 °/h per g and 2 °/h per °C on
gyro 2) → ``calibrate --effects g_sensitivity,temperature`` → ``simulate flight
--effects-from-cal --accel-noise 0.05`` (the true sensors carry the fitted terms at their
estimates; an accelerometer triad, which the FOG tetrad lacks, and a board temperature as
auxiliary frames; the channel map written beside the log) →
``replay --map`` the written map: every gyro term is applied and the per-sensor parity
residual mean is within 3 σ of 0, σ from the flight noise and the calibration's own
reported uncertainties (the true sensors are drawn from them). With the default map (no
auxiliary tables) or ``--no-effects`` the same residual is far beyond 3 σ (the premise).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from fdi.calfile import load_calibration
from fdi.effects import Compensator
from fdi.errors import ConfigError
from fdi.parity import parity_matrix
from replay.can_files import truth_path
from replay.channel_map import channel_map_toml, load_channel_map
from replay.effect_inputs import map_available, map_effect_inputs
from replay.logio import read_log
from rimu.cli import main

DUR = 40.0


def _run(capsys, *argv):
    assert main([str(a) for a in argv]) == 0
    return capsys.readouterr().out


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    d = tmp_path_factory.mktemp("chain")
    for argv in (["simulate", "calibration", "--preset", "tetrad-paper", "--effect",
                  "g_sensitivity=30,temperature=2", "--effect-sensors", "2", "--out",
                  d / "S", "--seed", "3"],
                 ["calibrate", "turntable",
                  d / "S", "--effects", "g_sensitivity,temperature", "--out",
                  d / "cal.json"]):
        assert main([str(a) for a in argv]) == 0, argv
    return d


def _z(cal, log, cmap, *, effects=True):
    """Per-sensor parity residual mean over its σ (flight noise + the calibration's bias and
    axis uncertainty at the flight's mean rate), from the log read with ``cmap``."""
    flight, frames = read_log(log, cal, channel_map=cmap, progress=False)
    assert frames["balanced"] and frames["lost_samples"] == 0
    g = cal.gyro
    force, temp = map_effect_inputs(cmap, None if flight.aux is None else flight.aux.values)
    comp = Compensator(cal, available=map_available(cmap), enabled=effects)
    y = flight.raw * g.scale_factors - g.biases - comp.block(flight.raw, force, temp)
    w = flight.omega_true.mean(axis=0)
    var = np.array([c.bias_sd ** 2 + w @ c.input_error_cov @ w for c in g.sensors])
    V = parity_matrix(g.H)
    P = V.T @ V
    sd = np.sqrt(np.diag(P @ (np.diag(var) + g.noise_covariance / len(flight.t)) @ P.T))
    return (y @ P.T).mean(axis=0) / sd, comp


def test_simulate_calibrate_simulate_replay_with_the_written_map(chain, tmp_path, capsys):
    d = chain
    log = tmp_path / "flight.blf"
    out = _run(capsys, "simulate", "flight", "--cal", d / "cal.json", "--duration", DUR,
               "--seed", 1, "--out", log, "--effects-from-cal", "--accel-noise", 0.05)
    mp = tmp_path / "flight.map.toml"
    lines = out.splitlines()
    assert lines[1] == ("simulated effects (true value = the calibration's estimate): "
                        "g_sensitivity on g1, g2, g3, g4; temperature on g1, g2, g3, g4")
    assert f"  {mp}: its channel map (sensors and auxiliary channels)" in lines
    assert f"  {truth_path(log)}: its truth sidecar (true parameters, faults, effects " \
           "simulated)" in lines
    assert any(ln.startswith(f"  {log}: the CAN log (shipped rimu_imu.dbc: RIMU_GYRO_01..04; "
                             "auxiliary: specific force on 3 axes (RIMU_ACCEL_01..03")
               for ln in lines)
    assert lines[-1] == f"replay it with: rimu replay {log} --cal {d / 'cal.json'} --map {mp}"
    truth = json.loads(truth_path(log).read_text())["effects_simulated"]
    assert len(truth["terms"]) == 8 and truth["accel_noise_mps2"] == 0.05

    cmap = load_channel_map(mp)                               # the written map round-trips
    assert channel_map_toml(cmap) == mp.read_text()
    assert [(a.name, a.quantity, a.message) for a in cmap.auxiliary] == [
        ("accel:imu.x", "specific_force", "RIMU_ACCEL_01"),
        ("accel:imu.y", "specific_force", "RIMU_ACCEL_02"),
        ("accel:imu.z", "specific_force", "RIMU_ACCEL_03"),
        ("temperature:board", "temperature", "RIMU_TEMP_01")]
    assert map_available(cmap) == {"specific_force": list(range(4)),
                                   "temperature": list(range(4))}

    # the replay command with the written map: all gyro terms applied, every frame used
    rout = _run(capsys, "replay", log, "--cal", d / "cal.json", "--map", mp, "--no-progress",
                "--report", tmp_path / "on.json")
    assert "not applied: g_sensitivity" not in rout.splitlines()[0]
    rep = json.loads((tmp_path / "on.json").read_text())
    applied = {(a["name"], a["sensor"]) for a in rep["effects"]["applied"]}
    assert applied == {(n, i) for n in ("g_sensitivity", "temperature") for i in range(1, 5)}
    assert rep["frames"]["rejected"] == {} and rep["auxiliary"]["frames"]["lost_frames"] == 0
    from scipy.stats import poisson

    from fdi.monitor import Monitor

    cal = load_calibration(d / "cal.json")
    allowed = int(poisson.isf(1e-3, Monitor(cal).thresholds.false_alarms_per_hour * DUR
                              / 3600))
    assert sum(e["type"] == "detected" for e in rep["events"]) <= allowed
    nout = _run(capsys, "replay", log, "--cal", d / "cal.json", "--map", mp, "--no-progress",
                "--no-effects")
    assert nout.splitlines()[0].startswith("compensating: nothing (--no-effects: 8 effect "
                                           "term(s) switched off")

    z_on, comp = _z(cal, log, cmap)
    assert len(comp.applied) == 8
    assert np.all(np.abs(z_on) < 3), z_on
    # the premise: without the auxiliary tables, or with --no-effects, the bias shows
    from replay.channel_map import default_channel_map

    g = cal.gyro
    plain = default_channel_map(g.n, axes=g.H_nominal, names=tuple(c.name for c in g.sensors))
    z_plain, comp0 = _z(cal, log, plain)
    assert {a.term.name for a in comp0.applied} == set()
    assert np.max(np.abs(z_plain)) > 10, z_plain
    z_off, _ = _z(cal, log, cmap, effects=False)
    assert np.max(np.abs(z_off)) > 10, z_off


@pytest.mark.slow
def test_compensated_parity_bias_is_honest_over_flight_seeds(chain, tmp_path, capsys):
    """20 flights (seeds 10-29) of the same calibration, each with its own true sensors drawn
    from the calibration's uncertainty: the compensated z (one parity direction of the
    tetrad per flight) has an RMS within the chi-square(20) 99.8 % range [0.57, 1.50] and a
    mean within 3/sqrt(20); uncompensated the RMS is beyond 10 and at least 15 flights are
    beyond 3 (the g-sensitivity's mean depends on each flight's attitudes, so a few
    flights hide it)."""
    d = chain
    cal = load_calibration(d / "cal.json")
    z_on, z_off = [], []
    for seed in range(10, 30):
        log = tmp_path / f"f{seed}.log"
        _run(capsys, "simulate", "flight", "--cal", d / "cal.json", "--duration", DUR,
             "--seed", seed, "--out", log, "--effects-from-cal", "--accel-noise", 0.05)
        cmap = load_channel_map(tmp_path / f"f{seed}.map.toml")
        z_on.append(_z(cal, log, cmap)[0][0])
        z_off.append(_z(cal, log, cmap, effects=False)[0][0])
    z_on, z_off = np.array(z_on), np.array(z_off)
    rms = float(np.sqrt(np.mean(z_on ** 2)))
    assert 0.57 < rms < 1.50, z_on
    assert abs(z_on.mean()) < 3 / np.sqrt(z_on.size), z_on
    print(f"z on: RMS {rms:.2f}, mean {z_on.mean():+.2f}; z off: RMS "
          f"{np.sqrt(np.mean(z_off ** 2)):.1f}, beyond 3 in {np.sum(np.abs(z_off) > 3)} of 20")
    assert np.sqrt(np.mean(z_off ** 2)) > 10 and np.sum(np.abs(z_off) > 3) >= 15, z_off


def test_flight_folder_with_effects_through_monitor_file(chain, tmp_path, capsys):
    """``--out DIR``: the inputs go to the folder's aux.csv; ``monitor-file`` applies every
    gyro term from them, no sample lacks an input, and the residual z is within 3."""
    from replay.effect_inputs import flight_effect_inputs
    from replay.flight import load_flight_dir

    d = chain
    out = _run(capsys, "simulate", "flight", "--cal", d / "cal.json", "--duration", DUR,
               "--seed", 5, "--out", tmp_path / "F", "--effects-from-cal", "--accel-noise",
               0.05)
    assert f"monitor it with: rimu monitor-file {tmp_path / 'F'}" in out
    mout = _run(capsys, "monitor-file", tmp_path / "F", "--cal", d / "cal.json", "--report",
                tmp_path / "r.json")
    assert "not applied" not in mout.splitlines()[0]
    eff = json.loads((tmp_path / "r.json").read_text())["effects"]
    assert len(eff["applied"]) == 8
    assert all(m["samples"] == 0 for m in eff["samples_without_input"])
    cal = load_calibration(d / "cal.json")
    fl = load_flight_dir(tmp_path / "F")
    force, temp, avail = flight_effect_inputs(fl)
    g = cal.gyro
    y = fl.raw * g.scale_factors - g.biases - Compensator(cal, available=avail).block(
        fl.raw, force, temp)
    w = fl.omega_true.mean(axis=0)
    var = np.array([c.bias_sd ** 2 + w @ c.input_error_cov @ w for c in g.sensors])
    V = parity_matrix(g.H)
    P = V.T @ V
    sd = np.sqrt(np.diag(P @ (np.diag(var) + g.noise_covariance / len(fl.t)) @ P.T))
    z = (y @ P.T).mean(axis=0) / sd
    assert np.all(np.abs(z) < 3), z


def test_impossible_requests_are_refused(chain, tmp_path, capsys):
    import dataclasses

    d = chain
    cal = load_calibration(d / "cal.json")
    dataclasses.replace(cal, effects=()).save(tmp_path / "plain.json")

    def refused(*argv):
        assert main([str(a) for a in argv]) == 2
        return capsys.readouterr().err.strip()

    base = ("simulate", "flight", "--duration", 2, "--out", tmp_path / "f.blf")
    err = refused(*base, "--cal", d / "cal.json", "--effects-from-cal")
    assert "g_sensitivity on gyro 1, gyro 2, gyro 3, gyro 4 needs the specific force, and " \
           "the calibration (tetrad) has no accelerometers; give --accel-noise SD" in err, err
    assert not (tmp_path / "f.blf").exists() and not (tmp_path / "f.map.toml").exists()
    err = refused(*base, "--cal", tmp_path / "plain.json", "--effects-from-cal")
    assert "the calibration has no effect terms" in err, err
    err = refused(*base, "--cal", d / "cal.json", "--temperature", "20:40")
    assert "--temperature needs --effects-from-cal" in err, err
    err = refused(*base, "--cal", d / "cal.json", "--effects-from-cal", "--temperature",
                  "20:x")
    assert "--temperature '20:x': END 'x' is not a number" in err, err
    err = refused(*base, "--cal", d / "cal.json", "--effects-from-cal", "--truth",
                  d / "S" / "truth.json")
    assert "give one or the other" in err, err
    err = refused(*base, "--cal", d / "cal.json", "--effects-from-cal", "--accel-noise", 0.05,
                  "--rate", 1000)
    assert err.endswith("f.blf: at 1000 Hz one sample period holds at most 7 CAN frames of "
                        "130 us; this log needs 4 gyro + 4 auxiliary frames per sample: lower "
                        "--rate or write a flight folder"), err
    out = _run(capsys, *base, "--cal", d / "cal.json", "--effects-from-cal",
               "--accel-noise", 0.05, "--temperature", "15:45:10")
    assert "RIMU_ACCEL_01..03" in out and (tmp_path / "f.map.toml").is_file()
    truth = json.loads(truth_path(tmp_path / "f.blf").read_text())["effects_simulated"]
    assert truth["accel_noise_mps2"] == 0.05
    assert truth["temperature_profile"]["tau_s"] == 10.0


def test_plain_log_gets_the_default_map_beside_it(chain, tmp_path, capsys):
    """Without effects the written map is the shipped DBC's default map (no auxiliary
    tables), and replaying with it gives the same answers as without --map."""
    d = chain
    _run(capsys, "simulate", "flight", "--cal", d / "cal.json", "--duration", 3, "--out",
         tmp_path / "p.log", "--seed", 2)
    cmap = load_channel_map(tmp_path / "p.map.toml")
    assert cmap.auxiliary == () and cmap.n == 4
    _run(capsys, "replay", tmp_path / "p.log", "--cal", d / "cal.json", "--map",
         tmp_path / "p.map.toml", "--no-progress", "--report", tmp_path / "a.json")
    _run(capsys, "replay", tmp_path / "p.log", "--cal", d / "cal.json", "--no-progress",
         "--report", tmp_path / "b.json")
    a, b = (json.loads((tmp_path / f).read_text()) for f in ("a.json", "b.json"))
    for r in (a, b):
        r.pop("timing_s", None)
        r.pop("channel_map", None)
    assert a["events"] == b["events"] and a["frames"] == b["frames"]


def test_temperature_profile_parse():
    from replay.flight_effects import parse_temperature_profile

    p = parse_temperature_profile("20:40", 90.0)
    assert p.tau_s == 30.0 and p(0.0) == 20.0 and abs(p(1e6) - 40.0) < 1e-9
    with pytest.raises(ConfigError, match="TAU must be positive"):
        parse_temperature_profile("20:40:0", 9.0)
    with pytest.raises(ConfigError, match="expected START:END"):
        parse_temperature_profile("20", 9.0)


def test_accelerometers_of_the_calibration_set_the_triad_noise():
    """A calibration with accelerometers (cone-paper) needs no --accel-noise: the triad gets
    their RMS per-sample sd; the raw outputs gain exactly c/SF on the terms' sensors."""
    import dataclasses

    from calibration.presets import preset
    from fdi.calfile import EffectTerm
    from replay.flight import simulate_flight
    from replay.flight_effects import add_effects, plan_effects

    cal = preset("cone-paper").truth
    term = EffectTerm("g_sensitivity", "gyro", 1, 300.0, 10.0, "deg/h per g",
                      ("specific_force",))
    cal = dataclasses.replace(cal, effects=(term,))
    plan = plan_effects(cal, "gyro", duration_s=5.0, sample_rate_hz=200.0)
    sd = np.sqrt(np.diag(cal.kind("accel").noise_covariance).mean() * 200.0
                 / cal.sample_rate_hz)
    assert plan.accel_noise_mps2 == pytest.approx(sd, rel=1e-12) and plan.temperature is None
    fl = simulate_flight(cal, 5.0, seed=4, sample_rate_hz=200.0)
    fe = add_effects(fl, plan, seed=4)
    d = fe.raw - fl.raw
    assert np.all(d[:, [0, 2, 3, 4, 5]] == 0)
    f_meas = fe.aux.values                                  # triad = true force + noise
    h = np.asarray(fl.truth["true_parameters"]["axis"])[1]
    sf = fl.truth["true_parameters"]["scale_factor"][1]
    from fdi.units import DPH, G0

    approx = 300.0 * DPH * (f_meas @ h) / G0 / sf           # from the noisy triad
    assert np.abs(d[:, 1] - approx).max() < 300.0 * DPH * 5 * sd / G0 / sf   # 5 sd (triad)
    assert fe.aux.names == ("imu.x", "imu.y", "imu.z")
    # a stuck sensor keeps its held value: the effect is not added on top
    from replay.faults import parse_fault

    stuck = simulate_flight(cal, 5.0, seed=4, sample_rate_hz=200.0,
                            faults=[parse_fault("stuck:2::2:1", cal, kind="gyro")])
    se = add_effects(stuck, plan, seed=4)
    w = (stuck.t >= 2.0) & (stuck.t < 3.0)
    assert np.all(se.raw[w, 1] == stuck.raw[w, 1]) and np.ptp(se.raw[w, 1]) == 0
    assert np.all(se.raw[~w, 1] != stuck.raw[~w, 1])
