"""The commands compensate the effect terms: ``monitor-file`` (with the flight's
accelerometers), ``replay`` (the sensors' own outputs only); they print what is and is not
applied, record it in the report, and ``--no-effects`` gives the old behaviour bit for bit."""

from __future__ import annotations

import dataclasses
import json

import pytest
from _effects_flight import effect_calibration, flight_with_effects

from fdi.calfile import EffectTerm, load_calibration
from replay.can_write import write_flight_log
from replay.flight import save_flight_dir
from rimu.cli import main


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("eff")
    cal = effect_calibration()
    step = EffectTerm("bias_step", "gyro", 4, 3.0, 0.2, "deg/h", ("time",), {"time_s": 50.0})
    cal = dataclasses.replace(cal, effects=(*cal.effects, step))
    cal.save(d / "cal.json")
    dataclasses.replace(cal, effects=()).save(d / "plain.json")
    fl = flight_with_effects(load_calibration(d / "cal.json"), seed=2, duration_s=30.0)
    save_flight_dir(fl, d / "flight")
    write_flight_log(fl, d / "flight.log")
    return d


def _run(capsys, *argv):
    assert main([str(a) for a in argv]) == 0
    return capsys.readouterr().out


def _detections(report):
    return sum(e["type"] == "detected" for e in report["events"])


def test_monitor_file_compensates_and_says_what_it_cannot(files, capsys):
    d = files
    out = _run(capsys, "monitor-file", d / "flight", "--cal", d / "cal.json",
               "--report", d / "on.json")
    first = out.splitlines()[0]
    assert first == ("compensating: scale_asymmetry on x1 (from rate sign), g_sensitivity on "
                     "y1 (from specific force), g_sensitivity on x2 (from specific force); "
                     "not applied: bias_step on y2 (session-specific (a jump at a time of the "
                     "calibration session), not a sensor property)"), first
    rep = json.loads((d / "on.json").read_text())
    eff = rep["effects"]
    assert eff["schema"] == "rimu.effects-runtime/1" and eff["enabled"]
    assert [(a["name"], a["sensor"]) for a in eff["applied"]] == [
        ("scale_asymmetry", 1), ("g_sensitivity", 2), ("g_sensitivity", 4)]
    assert eff["not_applied"][0]["name"] == "bias_step"
    assert all(m["samples"] == 0 for m in eff["samples_without_input"])
    assert _detections(rep) == 0


def test_monitor_file_no_effects_is_the_old_behaviour(files, capsys):
    d = files
    out_off = _run(capsys, "monitor-file", d / "flight", "--cal", d / "cal.json",
                   "--no-effects", "--report", d / "off.json")
    out_plain = _run(capsys, "monitor-file", d / "flight", "--cal", d / "plain.json",
                     "--report", d / "plain_rep.json")
    off = json.loads((d / "off.json").read_text())
    plain = json.loads((d / "plain_rep.json").read_text())
    assert off.pop("effects")["applied"] == []
    assert off == plain
    assert out_off.splitlines()[0] == (
        "compensating: nothing (--no-effects: 4 effect term(s) switched off: scale_asymmetry "
        "on x1, g_sensitivity on y1, g_sensitivity on x2, bias_step on y2)")
    def _said(out):         # the lines naming the files written differ by their paths
        return [ln for ln in out.splitlines() if not ln.startswith("wrote ")]

    assert _said(out_off)[1:] == _said(out_plain)
    assert _detections(off) > 0, "the premise: uncompensated, the effects raise alarms"


def test_monitor_file_without_accelerometers(files, capsys, tmp_path):
    from replay.flight import load_flight_dir

    fl = dataclasses.replace(load_flight_dir(files / "flight"), aux=None)
    save_flight_dir(fl, tmp_path / "noacc")
    out = _run(capsys, "monitor-file", tmp_path / "noacc", "--cal", files / "cal.json")
    assert "g_sensitivity on y1 (needs specific force: no accelerometers in the stream)" \
        in out.splitlines()[0]


def test_replay_compensates_the_rate_terms(files, capsys):
    d = files
    out = _run(capsys, "replay", d / "flight.log", "--cal", d / "cal.json", "--no-progress",
               "--report", d / "r_on.json")
    assert out.splitlines()[0].startswith(
        "compensating: scale_asymmetry on x1 (from rate sign); not applied: g_sensitivity on "
        "y1 (needs specific force: the default channel map (give --map with [[auxiliary]] "
        "channels) names no specific-force (accelerometer) channel for this sensor)")
    on = json.loads((d / "r_on.json").read_text())
    assert [a["name"] for a in on["effects"]["applied"]] == ["scale_asymmetry"]
    _run(capsys, "replay", d / "flight.log", "--cal", d / "cal.json", "--no-progress",
         "--no-effects", "--report", d / "r_off.json")
    _run(capsys, "replay", d / "flight.log", "--cal", d / "plain.json", "--no-progress",
         "--report", d / "r_plain.json")
    off = json.loads((d / "r_off.json").read_text())
    plain = json.loads((d / "r_plain.json").read_text())
    off.pop("effects")
    for r in (off, plain):
        r.pop("timing_s", None)
    assert off == plain


def test_calibrate_effects_then_monitor_file(tmp_path, capsys):
    """The whole chain through files: ``simulate calibration`` with scale_nonlinearity and
    temperature on gyro 2, ``calibrate --effects``, a 300 s flight of the true sensors with
    the same effects and a temperature channel, ``monitor-file``. The terms round-trip with
    their parameters (table rate, reference temperature) and are applied; the residual mean
    is within 3 σ with them (σ: flight noise and the calibration's reported uncertainties)
    and beyond 3 σ without."""
    import numpy as np

    from calibration.truth import load_truth
    from fdi.effects import Compensator
    from fdi.parity import parity_matrix
    from fdi.units import DPH, DPS
    from replay.effect_inputs import flight_effect_inputs
    from replay.flight import load_flight_dir
    from replay.flight_data import AuxChannels

    s = tmp_path / "S"
    _run(capsys, "simulate", "calibration", "--preset", "tetrad-paper", "--effect",
         "scale_nonlinearity=3e-4,temperature=2", "--effect-sensors", "2", "--out", s,
         "--seed", "3")
    _run(capsys, "calibrate", "turntable",
                 s, "--effects", "scale_nonlinearity,temperature", "--out",
         tmp_path / "cal.json")
    cal = load_calibration(tmp_path / "cal.json")
    nl = next(t for t in cal.effects if t.name == "scale_nonlinearity" and t.sensor == 1)
    tc = next(t for t in cal.effects if t.name == "temperature" and t.sensor == 1)
    assert nl.params["table_rate_dps"] == 10.0 and 20 < tc.params["reference_degC"] < 35
    truth, _, _ = load_truth(s / "truth.json")
    fl = flight_with_effects(cal, 1, truth=truth, duration_s=300.0, max_rate_dps=30.0,
                             effects={("scale_nonlinearity", 1): 3e-4}, table_rate_dps=10.0)
    T = 20.0 + 20.0 * (1 - np.exp(-(fl.t - fl.t[0]) / 100.0))    # the simulator's T0 = 20
    raw = fl.raw.copy()
    raw[:, 1] += 2.0 * DPH * (T - 20.0) / truth.gyro.scale_factors[1]
    a = fl.aux
    fl = dataclasses.replace(fl, raw=raw, aux=AuxChannels(
        (*a.kinds, "temperature"), (*a.names, "board"), (*a.imu, ""),
        np.column_stack([a.values, T]), np.column_stack([a.valid, np.ones(T.size, bool)])))
    save_flight_dir(fl, tmp_path / "F")
    out = _run(capsys, "monitor-file", tmp_path / "F", "--cal", tmp_path / "cal.json",
               "--report", tmp_path / "r.json")
    assert "scale_nonlinearity on g2 (from rate squared), temperature on g2 (from " \
           "temperature)" in out.splitlines()[0]
    assert "not applied" not in out.splitlines()[0]
    rep = json.loads((tmp_path / "r.json").read_text())
    assert len(rep["effects"]["applied"]) == 8
    # the residual mean, from the folder as monitor-file read it
    fl = load_flight_dir(tmp_path / "F")
    force, temp, avail = flight_effect_inputs(fl)
    comp = Compensator(cal, available=avail)
    g = cal.gyro
    s_hat = fl.raw * g.scale_factors - g.biases
    w = fl.omega_true.mean(axis=0)
    var = np.array([c.bias_sd ** 2 + w @ c.input_error_cov @ w for c in g.sensors])
    for ap in comp.applied:
        i, t = ap.term.sensor, ap.term
        zbar = (np.mean(s_hat[:, i] ** 2 - g.noise_covariance[i, i]) / (10.0 * DPS)
                if t.name == "scale_nonlinearity"
                else DPH * np.mean(temp[:, i] - t.params["reference_degC"]))
        var[i] += (t.estimate_sd * zbar) ** 2
    V = parity_matrix(g.H)
    P = V.T @ V
    sd = np.sqrt(np.diag(P @ (np.diag(var) + g.noise_covariance / len(fl.t)) @ P.T))
    z_on = ((s_hat - comp.block(fl.raw, force, temp)) @ P.T).mean(axis=0) / sd
    z_off = (s_hat @ P.T).mean(axis=0) / sd
    assert np.all(np.abs(z_on) < 3), z_on
    assert np.max(np.abs(z_off)) > 5, z_off
