"""Ferraris (known-angle rotation) calibration: imucal's own result on its real session,
honest σ over simulated sessions with truth, loader and CLI."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pytest
import scipy.stats

from calibration.ferraris import FerrarisOptions, ferraris_calibrate
from calibration.ferraris_io import load_ferraris
from fdi.calfile import load_calibration, misalignment_angles
from fdi.errors import CalibrationError, FileFormatError
from rimu.cli import main
from studies.ferraris_sim import imucal_like_truth, simulate_ferraris

DATA = Path(os.environ.get("RIMU_SHARED_DATA",
                           Path(__file__).resolve().parents[2] / ".." / "shared" / "data")
            ) / "imucal"
ANNOTATED = DATA / "annotated_session.csv"
needs_data = pytest.mark.skipif(not ANNOTATED.exists(),
                                reason=f"imucal example data not found at {DATA}")


@pytest.fixture(scope="module")
def imucal_result():
    """imucal's FerrarisCalibration of annotated_session.csv (its test snapshot)."""
    return json.loads((DATA / "annotated_session_expected_cal.json").read_text())


@pytest.fixture(scope="module")
def rimu_result():
    s = load_ferraris(ANNOTATED, 204.8, gyro_raw_unit="count", accel_raw_unit="count")
    return ferraris_calibrate(s, FerrarisOptions(gravity=9.81))    # imucal's g


def _K_b(cal, kind):
    s = cal.sets[kind]
    im = cal.extra["ferraris"]["imucal"][kind]
    K, b = np.diag(im["K"]), np.array(im["b"])
    K_sd = K * np.array([c.scale_factor_sd / c.scale_factor for c in s.sensors])
    b_sd = np.array([c.bias_sd / c.scale_factor for c in s.sensors])
    return K, K_sd, b, b_sd, np.array(im["R"])


@needs_data
def test_gyro_parameters_match_imucal(rimu_result, imucal_result):
    """Same procedure, same data: the gyro gains, axes, offsets and g-sensitivity equal
    imucal's to a tiny fraction of their σ (differences: rimu removes the offset at the
    nominal specific force, imucal at the measured one; rimu's offset is a least-squares
    fit with the g-sensitivity, imucal's the sample mean of the static data)."""
    K, K_sd, b, b_sd, R = _K_b(rimu_result, "gyro")
    Kr = np.diag(imucal_result["K_g"])
    np.testing.assert_allclose(K, Kr, rtol=2e-5)
    assert np.all(np.abs(K - Kr) < 0.01 * K_sd)
    np.testing.assert_allclose(R, imucal_result["R_g"], atol=1e-5)
    assert np.all(np.abs(b - imucal_result["b_g"]) < 0.1 * b_sd)
    fe = rimu_result.extra["ferraris"]
    k, k_sd = np.asarray(fe["g_sensitivity_raw_per_m_s2"]), np.asarray(
        fe["g_sensitivity_raw_per_m_s2_sd"])
    assert np.all(np.abs(k - np.asarray(imucal_result["K_ga"])) < 0.2 * k_sd)
    # the σ of a hand-turned rotation are the stated angle sd (1° of 360°), not nonsense
    np.testing.assert_allclose(K_sd / K, np.deg2rad(1.0) / (2 * np.pi), rtol=0.1)


@needs_data
def test_accel_parameters_match_imucal(rimu_result, imucal_result):
    """The generalised least squares weights the positions as imucal's formulas do (offset
    and gain of a sensor from the two positions with its axis vertical): axes to 1e-6,
    offsets to 0.05σ; the gains differ by +1.5e-4, rimu's second-order tilt correction
    for a 1° position sd (E[cos tilt] = 1 − δ², less the norm bias), within 1σ."""
    K, K_sd, b, b_sd, R = _K_b(rimu_result, "accel")
    Kr = np.diag(imucal_result["K_a"])
    np.testing.assert_allclose(K / Kr - 1, 1.5e-4, atol=2e-5)
    assert np.all(np.abs(K - Kr) < K_sd)
    np.testing.assert_allclose(R, imucal_result["R_a"], atol=1e-6)
    assert np.all(np.abs(b - imucal_result["b_a"]) < 0.05 * b_sd)
    assert rimu_result.extra["warnings"] == []


@needs_data
def test_zero_position_sd_shows_the_tilted_positions():
    """Claiming perfect positions makes the static fit fail its χ² check (the two z
    positions read ≈ 0.7° of tilt): a warning, not silently tighter σ."""
    s = load_ferraris(ANNOTATED, 204.8)
    cal = ferraris_calibrate(s, FerrarisOptions(gravity=9.81, position_sd_deg=0.0))
    assert any("accel" in w and "position" in w for w in cal.extra["warnings"])


def _zscores(seeds, opt):
    Z: dict[str, list[float]] = {"warned": []}
    for seed in seeds:
        tr = imucal_like_truth(seed)
        s = simulate_ferraris(tr, seed=seed, options=opt)
        cal = ferraris_calibrate(s, opt)
        Z["warned"].append(bool(cal.extra["warnings"]))
        for kind, H, SF, B in (("gyro", tr.gyro_axes, tr.gyro_sf, tr.gyro_bias),
                               ("accel", tr.accel_axes, tr.accel_sf, tr.accel_bias)):
            for i, c in enumerate(cal.sets[kind].sensors):
                Z.setdefault(f"{kind} scale factor", []).append(
                    (c.scale_factor - SF[i]) / c.scale_factor_sd)
                Z.setdefault(f"{kind} bias", []).append((c.bias - B[i]) / c.bias_sd)
                Z.setdefault(f"{kind} misalignment", []).extend(
                    (c.misalignment - misalignment_angles(c.axis_nominal, H[i]))
                    / c.misalignment_sd)
        fe = cal.extra["ferraris"]
        Z.setdefault("g-sensitivity", []).extend(
            ((np.asarray(fe["g_sensitivity_raw_per_m_s2"]) - tr.g_sensitivity)
             / np.asarray(fe["g_sensitivity_raw_per_m_s2_sd"])).ravel())
    return {k: np.array(v) for k, v in Z.items()}


# The accelerometer scale factor and bias errs by g·(1 − cos tilt) of the vertical
# positions: exponential, not normal, so their z have Laplace-like tails
# (P(|z| > 3) = exp(−3·√2) = 1.4 % at unit sd instead of 0.27 %).
TAIL_P = {"accel scale factor": np.exp(-3 * np.sqrt(2)), "accel bias": np.exp(-3 * np.sqrt(2))}


def _check_honest(Z):
    # six χ² checks at 0.1 % per session: false warnings in at most the binomial 99.9 %
    # quantile of p = 0.6 % (measured: 1 of 100)
    warned = Z.pop("warned")
    assert sum(warned) <= scipy.stats.binom.ppf(0.999, len(warned), 0.006), sum(warned)
    for name, z in Z.items():
        n = z.size
        # |z| > 3: at most the binomial 99.9 % quantile of the rate for honest σ
        lim = scipy.stats.binom.ppf(0.999, n, TAIL_P.get(name, 0.0027))
        assert np.sum(np.abs(z) > 3) <= lim, (name, np.sum(np.abs(z) > 3), lim)
        # RMS of z near 1: MC sd of the RMS is ≈ 1/sqrt(2n) (≤ 0.04 here) for normal z,
        # larger for the Laplace-tailed ones (measured 0.91-1.10 over 200 seeds)
        rms = float(np.sqrt(np.mean(z**2)))
        assert 0.8 < rms < 1.2, (name, rms)
        assert abs(z.mean()) < 4 / np.sqrt(n) + 0.1, (name, z.mean())


def test_sigma_honest_over_simulated_sessions():
    """100 simulated hand-held sessions (1° tilts, 1° angle errors, Earth rate at 49.6°)."""
    opt = FerrarisOptions(latitude_deg=49.6)
    _check_honest(_zscores(range(100), opt))


@pytest.mark.slow
def test_sigma_honest_other_procedures():
    """Sloppier and tighter procedures, latitude unknown: still honest."""
    for pos, ang in ((2.0, 3.0), (0.2, 0.3)):
        opt = FerrarisOptions(position_sd_deg=pos, angle_sd_deg=ang)
        _check_honest(_zscores(range(1000, 1150), opt))


def test_understated_procedure_is_caught():
    """Sessions made with 3° tilts calibrated as if 0.2°: the static χ² warns in most."""
    sim = FerrarisOptions(position_sd_deg=3.0)
    told = dataclasses.replace(sim, position_sd_deg=0.2)
    warned = 0
    for seed in range(10):
        s = simulate_ferraris(imucal_like_truth(seed), seed=seed, options=sim)
        warned += bool(ferraris_calibrate(s, told).extra["warnings"])
    assert warned >= 8


def test_loader_errors(tmp_path):
    p = tmp_path / "f.csv"
    p.write_text("part,acc_x,acc_y,acc_z,gyr_x,gyr_y\nx_p,1,2,3,4,5\n")
    with pytest.raises(FileFormatError, match="gyr_z") as ei:
        load_ferraris(p, 100.0)
    assert ei.value.line == 1
    p.write_text("part,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z\nx_p,1,2,3,4,5,6\nx_p,1,2,x,4,5,6\n")
    with pytest.raises(FileFormatError) as ei:
        load_ferraris(p, 100.0)
    assert ei.value.line == 3 and ei.value.field == "acc_z"
    p.write_text("part,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z\nx_p,1,2,3,4,5,6\n")
    with pytest.raises(FileFormatError, match="x_a"):
        load_ferraris(p, 100.0)


def test_section_list_equals_annotation(tmp_path):
    """The same samples given by a section list (imucal's other format) calibrate alike."""
    s = simulate_ferraris(imucal_like_truth(3), seed=3)
    N = s.gyro.shape[0]
    part = np.full(N, "", dtype=object)
    for k, idx in s.sections.items():
        part[idx] = k
    rows = ["part,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z"] + [
        f"{part[i]}," + ",".join(repr(float(v)) for v in (*s.gyro[i], *s.accel[i]))
        for i in range(N)]
    (tmp_path / "a.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "b.csv").write_text("\n".join(r.split(",", 1)[1] for r in rows) + "\n")
    (tmp_path / "b.json").write_text(json.dumps(
        {k: {"start": int(v[0]), "end": int(v[-1]) + 1} for k, v in s.sections.items()}))
    a = ferraris_calibrate(load_ferraris(tmp_path / "a.csv", 100.0))
    b = ferraris_calibrate(load_ferraris(tmp_path / "b.csv", 100.0,
                                         sections=tmp_path / "b.json"))
    direct = ferraris_calibrate(s)
    for kind in ("gyro", "accel"):
        np.testing.assert_allclose(a.sets[kind].scale_factors, b.sets[kind].scale_factors,
                                   rtol=1e-13)
        np.testing.assert_allclose(a.sets[kind].scale_factors,
                                   direct.sets[kind].scale_factors, rtol=1e-13)


def test_missing_section_and_bad_samples():
    s = simulate_ferraris(imucal_like_truth(1), seed=1)
    secs = dict(s.sections)
    del secs["y_rot"]
    with pytest.raises(CalibrationError, match="y_rot"):
        ferraris_calibrate(dataclasses.replace(s, sections=secs))
    g = s.gyro.copy()
    g[s.sections["z_p"][3], 1] = np.nan
    with pytest.raises(CalibrationError, match="non-finite gyro"):
        ferraris_calibrate(dataclasses.replace(s, gyro=g))


@needs_data
def test_cli_ferraris(tmp_path, capsys):
    out = tmp_path / "cal.json"
    rc = main(["calibrate", "ferraris", str(ANNOTATED), "--sample-rate-hz", "204.8",
               "--gravity", "9.81", "--out", str(out)])
    assert rc == 0
    cal = load_calibration(out)
    assert set(cal.sets) == {"gyro", "accel"} and cal.gyro.n == 3
    text = capsys.readouterr().out
    assert "imucal K" in text and "wrote" in text


def test_cli_ferraris_errors(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    rc = main(["calibrate", "ferraris", str(bad), "--sample-rate-hz", "100",
               "--out", str(tmp_path / "c.json")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "bad.csv" in err
    rc = main(["calibrate", "ferraris", str(bad), "--out", str(tmp_path / "c.json")])
    assert rc == 2 and "--sample-rate-hz" in capsys.readouterr().err
    rc = main(["calibrate", "ferraris", str(bad), "--sample-rate-hz", "100", "--compare",
               "t.json", "--out", str(tmp_path / "c.json")])
    assert rc == 2 and "--compare" in capsys.readouterr().err
    rc = main(["calibrate", "turntable", "--out", str(tmp_path / "c.json")])
    err = capsys.readouterr().err
    assert rc == 2 and "required: SESSION" in err and len(err.strip().splitlines()) == 1
