"""The in-flight time offsets move each IMU's accelerometer and temperature channels with it
(``calibration.inflight.timing.apply_time_offsets``), so that the effect terms' inputs
(``replay.effect_inputs.flight_effect_inputs``) stay on their samples.

A two-IMU flight (``replay.imu_set``) whose second IMU measures the motion 5 ms late (its
accelerometers too): noise-free accelerometers and no linear acceleration, so the specific
force is the smooth gravity reaction of the attitude and linear interpolation is exact to
``max|Δ²f|/8`` (Δ² the second difference over one sample). After the move the second IMU's
specific force equals the first's, which the simulator sampled at the shifted times, within
that bound; before it, the difference is more than ten times the bound (the premise).
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from calibration.inflight.calfile import calibration_from_fit
from calibration.inflight.fit import fit_inflight
from calibration.inflight.timing import apply_time_offsets, moved_aux_channels
from replay.effect_inputs import flight_effect_inputs
from replay.imu_set import ImuEffects, ImuSetSpec, simulate_imu_set

TAU = 0.005


@pytest.fixture(scope="module")
def flight_and_cal():
    f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=30, seed=3, time_offset_s=(0.0, TAU),
                                    accel_noise_sd=0.0, linear_accel=0.0,
                                    effects=ImuEffects(temperature_coeff=1e-5)))
    return f, calibration_from_fit(fit_inflight(f), f)


def _with_offset(cal, tau_s):
    ex = dict(cal.extra)
    inf = dict(ex["inflight"])
    inf["imus"] = {k: dict(v) for k, v in inf["imus"].items()}
    inf["imus"]["imu2"]["time_offset_ms"] = 1e3 * tau_s
    ex["inflight"] = inf
    return dataclasses.replace(cal, extra=ex)


def _cols(aux, kind, imu):
    return [j for j, (k, g) in enumerate(zip(aux.kinds, aux.imu, strict=True))
            if k == kind and g == imu]


@pytest.mark.parametrize("offset", ["true", "fitted"])
def test_moved_inputs_line_up_within_interpolation_error(flight_and_cal, offset):
    f, cal = flight_and_cal
    tau_hat = TAU if offset == "true" else float(
        cal.extra["inflight"]["imus"]["imu2"]["time_offset_ms"]) * 1e-3
    moved, applied = apply_time_offsets(f, _with_offset(cal, tau_hat))
    assert set(applied) == {"imu2"}
    assert moved_aux_channels(moved, applied) == [
        "accel:imu2.x", "accel:imu2.y", "accel:imu2.z", "temperature:imu2"]
    a0, a1 = f.aux, moved.aux
    ref, mov = _cols(a0, "accel", "imu1"), _cols(a0, "accel", "imu2")
    f_ref = a0.values[:, ref]
    dt = 1.0 / f.sample_rate_hz
    # linear interpolation error, plus the fitted offset's error times the largest slope
    bound = (np.abs(np.diff(f_ref, 2, axis=0)).max() / 8
             + np.abs(np.diff(f_ref, axis=0)).max() / dt * abs(tau_hat - TAU))
    before = np.abs(a0.values[:, mov] - f_ref).max()
    after = np.nanmax(np.abs(a1.values[:, mov] - f_ref))
    assert before > 10 * bound, (before, bound)               # the premise: a visible lag
    assert after <= bound, (after, bound)
    # the effect inputs of imu2's sensors are imu1's now
    force0, _, _ = flight_effect_inputs(f)
    force1, temp1, avail = flight_effect_inputs(moved)
    assert avail == {"specific_force": list(range(6)), "temperature": list(range(6))}
    assert np.nanmax(np.abs(force1[:, 3:] - force1[:, :3])) <= bound
    assert np.abs(force0[:, 3:] - force0[:, :3]).max() > 10 * bound
    # the temperature: its own record sampled at t - tau (the same interpolation)
    jt = _cols(a0, "temperature", "imu2")[0]
    want = np.interp(f.t - tau_hat, f.t, a0.values[:, jt])
    ok = a1.valid[:, jt]
    np.testing.assert_allclose(a1.values[ok, jt], want[ok], rtol=0, atol=1e-12)
    np.testing.assert_allclose(temp1[ok, 3], want[ok], rtol=0, atol=1e-12)
    # where the moved gyros have no sample, neither do their inputs; the reference is
    # untouched
    gyro_ok = moved.valid[:, [k for k, g in enumerate(f.imu) if g == "imu2"]]
    assert np.array_equal(a1.valid[:, mov], gyro_ok) and np.array_equal(ok, gyro_ok[:, 0])
    assert np.isnan(a1.values[~ok, jt]).all() and (~ok).sum() == 1
    for j in _cols(a0, "accel", "imu1") + _cols(a0, "temperature", "imu1"):
        np.testing.assert_array_equal(a1.values[:, j], a0.values[:, j])


def test_monitor_file_says_which_channels_moved(tmp_path, capsys):
    """``rimu simulate flight --imus 2 --time-offset-ms 0,5`` → ``calibrate in-flight`` →
    ``monitor-file``: the IMU and its four auxiliary channels are moved, and the report
    records them."""
    from rimu.cli import main

    d = tmp_path / "f"
    for argv in (["simulate", "flight", "--imus", "2", "--duration", "30", "--seed", "2",
                  "--time-offset-ms", "0,5", "--temperature-coeff", "0.01", "--out", d],
                 ["calibrate", "in-flight", d, "--out", tmp_path / "cal.json"],
                 ["monitor-file", d, "--cal", tmp_path / "cal.json", "--report",
                  tmp_path / "rep.json"]):
        assert main([str(a) for a in argv]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("moved onto"))
    assert line.startswith("moved onto the reference's timing: imu2 +5.0")
    assert line.endswith("ms (with 4 auxiliary channel(s): accel:imu2.x, accel:imu2.y, "
                         "accel:imu2.z, temperature:imu2)"), line
    rep = json.loads((tmp_path / "rep.json").read_text())
    assert rep["time_offsets_aux_moved"] == ["accel:imu2.x", "accel:imu2.y", "accel:imu2.z",
                                             "temperature:imu2"]
