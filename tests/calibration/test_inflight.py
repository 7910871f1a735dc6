"""In-flight calibration of an IMU set against itself (fast checks; Monte Carlo in
test_inflight_mc.py under --slow)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from statsmodels.stats.sandwich_covariance import S_hac_simple

from calibration.inflight.calfile import calibration_from_fit
from calibration.inflight.diagnose import diagnose_flight
from calibration.inflight.fit import decompose, fit_inflight
from calibration.inflight.regression import long_run_covariance, stacked_lstsq
from fdi.calfile import load_calibration
from fdi.units import DPS, G0
from replay.flight_io import save_flight_dir
from replay.imu_set import ImuEffects, ImuSetSpec, simulate_imu_set

ROOT = Path(__file__).resolve().parents[2]


def test_long_run_covariance_matches_statsmodels_newey_west() -> None:
    rng = np.random.default_rng(0)
    e = rng.standard_normal((20000, 3))
    s = e.copy()
    for k in range(1, s.shape[0]):                      # AR(1), rho 0.6
        s[k] += 0.6 * s[k - 1]
    s -= s.mean(axis=0)
    ours = long_run_covariance(s, 20)
    ref = S_hac_simple(s, nlags=20) / s.shape[0]        # Bartlett weights 1 - l/(L+1)
    np.testing.assert_allclose(ours, ref, rtol=0.01, atol=0.005 * np.abs(ref).max())


def test_hac_sd_is_honest_for_coloured_errors() -> None:
    """Slope of a regression with AR(1) errors: the HAC sd matches the spread over seeds
    (the white-noise formula underestimates it)."""
    errs, sds, sds_white = [], [], []
    for seed in range(60):
        rng = np.random.default_rng([seed, 7])
        N = 2000
        x = rng.standard_normal(N)
        for k in range(1, N):
            x[k] += 0.8 * x[k - 1]
        u = rng.standard_normal(N)
        for k in range(1, N):
            u[k] += 0.8 * u[k - 1]
        X = np.stack([np.ones(N), x], axis=1)[:, None, :]
        fit = stacked_lstsq(X, (0.5 * x + u)[:, None])
        errs.append(fit.beta[1] - 0.5)
        sds.append(fit.sd[1])
        sds_white.append(np.sqrt(fit.cov_white[1, 1]))
    z = np.array(errs) / np.array(sds)
    assert 0.75 < np.std(z) < 1.3                      # 60 seeds: sd of sd ~ 0.09
    assert np.mean(sds_white) < 0.7 * np.std(errs)


def _flight(seed: int = 3, **kw):
    return simulate_imu_set(ImuSetSpec(imus=2, duration_s=60, seed=seed, **kw))


def test_alignment_bias_and_time_offset_within_3_sigma() -> None:
    f = _flight(time_offset_s=(0.0, 0.005))
    a = fit_inflight(f).alignments["imu2"]
    tr = f.truth["relative_to_reference"]["imu2"]
    assert a.model == "full"
    z_tau = (a.time_offset_s - tr["time_offset_s"]) / a.time_offset_sd_s
    assert abs(z_tau) < 3
    assert a.time_offset_sd_s < 1e-4
    est, sd = decompose(a.A, a.A_cov)["rotation"]
    true = decompose(np.array(tr["A"]))["rotation"][0]
    assert np.all(np.abs((est - true) / sd) < 3)
    assert np.all(np.abs((a.c - tr["c"]) / np.sqrt(np.diag(a.c_cov))) < 3)


def test_static_flight_holds_every_gain_at_the_prior_with_its_sd() -> None:
    """Was: refused ("does not excite rotation about x"). Issue 27 asks for a calibration
    that says what it does not know: a flight at rest excites no gain parameter, so every
    one is held at the prior mean with the prior's sd (the bias is still estimated)."""
    from calibration.inflight.fit import HELD
    from calibration.inflight.prior import Prior

    f = _flight(max_rate_dps=0.01)
    a = fit_inflight(f).alignments["imu2"]
    pr = Prior()
    gains = [p for p in a.parameters if p.name != "time offset"]
    assert len(gains) == 9 and all(p.status == HELD for p in gains)
    assert all(abs(p.value) < 1e-3 * p.prior_sd for p in gains)
    assert np.allclose([p.sd for p in gains], pr.sds(), rtol=1e-3)
    tr = f.truth["relative_to_reference"]["imu2"]
    assert np.all(np.abs((a.c - tr["c"]) / np.sqrt(np.diag(a.c_cov))) < 4)


def test_one_axis_motion_holds_rotation_about_x_at_the_prior() -> None:
    """Rates about x only: rotation about x is not observable. Was: refused naming it; now
    (issue 27) held at the prior with the prior's sd, and scale x estimated."""
    from dataclasses import replace

    from calibration.inflight.fit import ESTIMATED, HELD

    f = _flight()
    keep_x = f.raw.copy()
    w = f.omega_true.copy()
    w[:, 1:] = 0.0
    tr = f.truth["imus"]
    rng = np.random.default_rng(1)
    for j in (1, 2):
        G = np.array(tr[f"imu{j}"]["gain_matrix"])
        keep_x[:, 3 * j - 3:3 * j] = w @ G.T + 2e-3 * rng.standard_normal((w.shape[0], 3))
    a = fit_inflight(replace(f, raw=keep_x)).alignments["imu2"]
    st = {p.name: p for p in a.parameters}
    assert st["rotation x"].status == HELD
    assert st["rotation x"].sd > 0.9 * st["rotation x"].prior_sd
    assert st["scale x"].status == ESTIMATED


def test_calibration_file_round_trips_and_monitor_is_quiet(tmp_path: Path) -> None:
    from fdi.monitor import Monitor
    from thresholds.compute import compute_thresholds

    f = _flight(seed=5)
    fit = fit_inflight(f)
    cal = calibration_from_fit(fit, f)
    cal.save(tmp_path / "cal.json")
    back = load_calibration(tmp_path / "cal.json")
    assert back.gyro.n == 6
    np.testing.assert_allclose(back.gyro.H[:3], np.eye(3), atol=1e-12)
    assert back.extra["inflight"]["reference"] == "imu1"
    thr = compute_thresholds(back, false_alarms_per_hour=1e-3)
    res = Monitor(back, thr).run(f.t, f.raw, f.valid)
    assert res.events == []
    assert res.healthy.all()


def test_diagnose_finds_injected_g_sensitivity_and_nothing_in_a_clean_flight() -> None:
    eff = ImuEffects(g_sensitivity=0.05 * DPS / G0, imus=(2,))
    for effects, want in ((eff, {"g_sensitivity"}), (ImuEffects(), set())):
        f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=120, seed=5, effects=effects))
        doc = diagnose_flight(f, calibration_from_fit(fit_inflight(f), f))
        assert {e["name"] for e in doc["effects"]} == want
        assert not doc["unexplained"]
        if want:
            assert all(b >= a for a, b in zip(doc["error_after"]["rms"],
                                              doc["error_before"]["rms"], strict=True))
            e = doc["effects"][0]
            assert e["sensors"] == [4, 5, 6] and e["p_value"] < 1e-6
            G = np.array(f.truth["imus"]["imu2"]["g_sensitivity"]).ravel() * G0 / DPS
            z = (np.array(e["estimate"]) - G) / np.array(e["estimate_sd"])
            assert np.all(np.abs(z) < 3.5)


def _rimu(*args: str) -> subprocess.CompletedProcess:
    code = "from rimu.cli import main; raise SystemExit(main())"
    return subprocess.run([sys.executable, "-c", code, *args],
                          capture_output=True, text=True, cwd=ROOT,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})


def test_cli_simulate_calibrate_diagnose(tmp_path: Path) -> None:
    d = tmp_path / "f"
    r = _rimu("simulate", "flight", "--imus", "2", "--duration", "60", "--seed", "2",
              "--time-offset-ms", "0,5", "--out", str(d))
    assert r.returncode == 0, r.stderr
    r = _rimu("calibrate", "in-flight", str(d), "--out", str(tmp_path / "cal.json"),
              "--report", str(tmp_path / "crep"))
    assert r.returncode == 0, r.stderr
    assert "time offset +5.0" in r.stdout
    assert "sign: time offset" in r.stdout and "belongs to this flight" in r.stdout
    for png in ("residual.png", "offset.png"):
        assert (tmp_path / "crep" / png).stat().st_size > 1000
    r = _rimu("monitor-file", str(d), "--cal", str(tmp_path / "cal.json"), "--report",
              str(tmp_path / "rep.json"))
    assert r.returncode == 0, r.stderr
    assert "moved onto the reference's timing: imu2 +5.0" in r.stdout
    moved = json.loads((tmp_path / "rep.json").read_text())["time_offsets_applied_ms"]
    assert abs(moved["imu2"] - 5.0) < 0.1
    r = _rimu("diagnose", str(d), "--cal", str(tmp_path / "cal.json"), "--json",
              "--report", str(tmp_path / "rep"))
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert json.loads((tmp_path / "rep" / "diagnosis.json").read_text()) == doc
    assert (tmp_path / "rep" / "residual.png").stat().st_size > 1000
    assert "residual.png" in (tmp_path / "rep" / "report.md").read_text()
    # the monitor's picture (replay.plots) with diagnose's and beside monitor-file's report
    assert (tmp_path / "rep" / "monitor.png").stat().st_size > 10_000
    assert "monitor.png" in (tmp_path / "rep" / "report.md").read_text()
    assert (tmp_path / "rep.png").stat().st_size > 10_000
    # diagnose applies the calibration's offset exactly: nothing of the 5 ms is left
    assert "time_skew" not in {e["name"] for e in doc["effects"]}
    (tm,) = doc["timing"]
    assert abs(tm["calibration_ms"] - 5.0) < 3 * tm["calibration_sd_ms"]
    assert not tm["left"] and abs(tm["left_ms"]) < 3 * tm["left_sd_ms"]
    assert "later than the reference" in doc["time_offset_sign"]
    # a calibration without the offset leaves it all: diagnose finds it as time_skew
    r = _rimu("calibrate", "in-flight", str(d), "--no-time-offset", "--out",
              str(tmp_path / "cal0.json"))
    assert r.returncode == 0, r.stderr
    r = _rimu("diagnose", str(d), "--cal", str(tmp_path / "cal0.json"), "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    skew = [e for e in doc["effects"] if e["name"] == "time_skew"]
    assert len(skew) == 1 and abs(skew[0]["estimate"] - 5.0) < 3 * skew[0]["estimate_sd"]
    assert doc["timing"][0]["left"] and doc["timing"][0]["calibration_ms"] == 0.0


def test_cli_calibrates_a_static_flight_saying_what_it_holds(tmp_path: Path) -> None:
    """Was: refused in one line. Now a calibration whose output names every parameter held
    at the prior (issue 27), and whose file carries the prior's sd."""
    d = tmp_path / "f"
    save_flight_dir(_flight(max_rate_dps=0.01), d)
    r = _rimu("calibrate", "in-flight", str(d), "--out", str(tmp_path / "cal.json"))
    assert r.returncode == 0, r.stderr
    assert "imu2: estimated: none; held at the prior: rotation x" in r.stdout
    doc = json.loads((tmp_path / "cal.json").read_text())
    g = doc["sensors"]["gyro"][3]
    assert 1e3 * 0.5 * np.radians(2.0) < min(g["misalignment_mrad_sd"])


def test_cli_errors_are_one_line(tmp_path: Path) -> None:
    from replay.flight import simulate_flight
    from studies.synthetic import synthetic_calibration

    cal = synthetic_calibration("cone6", seed=2)
    save_flight_dir(simulate_flight(cal, 2.0, seed=1), tmp_path / "plain")
    cases = [(("calibrate", "in-flight", str(tmp_path / "plain"), "--out",
               str(tmp_path / "c.json")), "at least two IMU groups"),
             (("calibrate", "--out", str(tmp_path / "c.json")), "in-flight"),
             (("calibrate", "in-flight", str(tmp_path / "nope"), "--out",
               str(tmp_path / "c.json")), "no such directory")]
    for args, word in cases:
        r = _rimu(*args)
        assert r.returncode == 2, (args, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and word in lines[0], lines


def test_noise_split_three_cornered_hat_recovers_each_imus_noise() -> None:
    from calibration.inflight.calfile import noise_split

    sd, scale = 2e-3, (1.0, 2.0, 0.5)
    f = simulate_imu_set(ImuSetSpec(imus=3, duration_s=60, seed=8, noise_sd=sd,
                                    noise_scale=scale))
    noise = noise_split(fit_inflight(f))
    # the hat's share of IMU j is mean(n_j² − n_j n_k − n_j n_l + n_k n_l): its variance is
    # (2 v_j² + v_j v_k + v_j v_l + v_k v_l)/N for white noise of variances v
    N = f.t.shape[0]
    v = [(s * sd) ** 2 for s in scale]
    for j, g in enumerate(("imu1", "imu2", "imu3")):
        vj, (vk, vl) = v[j], [v[i] for i in range(3) if i != j]
        share_sd = np.sqrt((2 * vj**2 + vj * vk + vj * vl + vk * vl) / N)
        assert np.all(np.abs(np.diag(noise[g]) - vj) < 4 * share_sd), (g, noise[g], vj)
    assert np.all(np.diag(noise["imu2"]) > 2 * np.diag(noise["imu1"]))    # not split equally


def test_cli_timing_jitter_simulated_and_estimated(tmp_path: Path) -> None:
    """``--timing-jitter-ms`` on a simulated flight; ``calibrate in-flight`` prints the
    estimate with its sd and writes it on imu2's sensors only."""
    d = tmp_path / "f"
    r = _rimu("simulate", "flight", "--imus", "2", "--duration", "60", "--seed", "2",
              "--timing-jitter-ms", "0,2", "--out", str(d))
    assert r.returncode == 0, r.stderr
    r = _rimu("calibrate", "in-flight", str(d), "--out", str(tmp_path / "cal.json"))
    assert r.returncode == 0, r.stderr
    line = next(x for x in r.stdout.splitlines() if "timing jitter imu2:" in x)
    est, sd = (float(v) for v in line.split(":")[1].split("ms")[0].split("±"))
    assert abs(est - 2.0) < 3 * sd, line                 # the simulated 2 ms
    cal = json.loads((tmp_path / "cal.json").read_text())["sensors"]["gyro"]
    assert [c.get("timing_jitter_ms", 0.0) for c in cal][:3] == [0.0] * 3
    assert cal[3]["timing_jitter_ms"] == pytest.approx(est, abs=0.01)


def test_calibration_states_the_range_its_samples_covered() -> None:
    """``validated_rate``/``validated_specific_force``: what the samples the fit used
    reached (the smallest estimate over the IMUs), and the flight's own samples are inside."""
    from dataclasses import replace

    from fdi.envelope import RANGE
    from replay.envelope import flight_accel, flight_envelope

    f = _flight(seed=5)
    fit = fit_inflight(f)
    cal = calibration_from_fit(fit, f)
    s = cal.gyro
    y = (f.raw * s.scale_factors - s.biases)[fit.used]
    w1 = y[:, :3] @ np.linalg.pinv(s.H[:3]).T
    w2 = y[:, 3:] @ np.linalg.pinv(s.H[3:]).T
    np.testing.assert_allclose(s.validated_rate,
                               np.max(np.minimum(np.abs(w1), np.abs(w2)), axis=0),
                               rtol=1e-12, err_msg="validated_rate")
    acc = flight_accel(f)
    assert acc is not None
    assert s.validated_specific_force == pytest.approx(
        float(np.max(np.min(np.linalg.norm(acc[fit.used], axis=2), axis=1))), rel=1e-12)
    codes = flight_envelope(f, cal)
    assert not (codes[fit.used] & RANGE).any(), "the calibration's own samples are inside"
    # the same flight turning 1.5x faster leaves the calibrated range
    fast = flight_envelope(replace(f, raw=f.raw * 1.5), cal)
    assert (fast & RANGE).any()


def test_drift_model_is_measured_on_request_and_costs_nothing_on_a_white_flight(tmp_path):
    """``drift_model=True`` (``--drift-model``) keeps the parity drift model of the fit's
    residual (rimu.calibration/4); on a simulated flight with white noise it finds no
    excess, so ``tune`` states the same detectable sizes as without it."""
    from fdi.calfile import load_calibration
    from thresholds.tune import tune

    f = _flight(seed=5)
    fit = fit_inflight(f)
    plain = calibration_from_fit(fit, f)
    cal = calibration_from_fit(fit, f, drift_model=True)
    assert plain.gyro.drift is None
    d = cal.gyro.drift
    from calibration.inflight.calfile import sensor_residuals

    used = int(np.all(np.isfinite(sensor_residuals(fit, f)), axis=1).sum())
    assert d is not None and d.df == 3 and d.samples == used
    assert not any(d.excess), f"white flight: excess {d.excess}"
    cal.save(tmp_path / "c.json")
    assert '"rimu.calibration/4"' in (tmp_path / "c.json").read_text()
    back = load_calibration(tmp_path / "c.json")
    np.testing.assert_allclose(back.gyro.drift.excess, d.excess, err_msg="drift excess")
    a = [x.size_unit_value for x in tune(plain, false_alarms_per_hour=10.0).detectable]
    b = [x.size_unit_value for x in tune(cal, false_alarms_per_hour=10.0).detectable]
    np.testing.assert_allclose(b, a, rtol=1e-9, err_msg="detectable sizes")
