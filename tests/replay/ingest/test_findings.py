"""Each finding of docs/findings.md, recomputed from the shared data (skipped without it).

Every test recomputes its number through ``studies/make_findings.py`` (the script that wrote
``studies/findings.json``), checks the documented value is the one the data give (to a tenth
of its σ), and checks the claim the documentation makes with a tolerance of 3 σ, σ being
the block scatter the number carries.
"""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
from ingest_helpers import data_file, shared_data

from fdi.units import DPS

ROOT = Path(__file__).resolve().parents[3]


def _script():
    spec = importlib.util.spec_from_file_location("make_findings",
                                                  ROOT / "studies" / "make_findings.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


MF = _script()
DOC = json.loads((ROOT / "studies" / "findings.json").read_text())


def _same(got, doc, sd):
    """The documented number is the one recomputed (within a tenth of its σ)."""
    np.testing.assert_allclose(got, doc, rtol=0, atol=0.1 * np.max(sd) + 1e-15)


@pytest.fixture(scope="module")
def erle41():
    data_file("erle_pxf_dual_imu", "pxf_copter_22-12-2014_41.BIN")
    return MF.erle(shared_data(), "41")


@pytest.fixture(scope="module")
def erle83():
    data_file("erle_pxf_dual_imu", "pxf_copter_31-3-2015_83.BIN")
    return MF.erle(shared_data(), "83")


def test_flight41_imu2_lags_by_14_ms(erle41):
    tau = erle41["time_offset_s"]
    doc = DOC["erle"]["41"]["time_offset_s"]
    _same(tau["value"], doc["value"], tau["sd"])
    assert tau["value"] / tau["sd"] > 5                      # a lag, not noise
    assert 0.010 < tau["value"] < 0.020
    raw = np.array(erle41["rms_raw_rps"])
    lag = np.array(erle41["rms_lag_rps"])
    assert np.all(lag < 0.75 * raw)                          # the lag explains >= 25 % RMS


def test_flight41_heavy_tails(erle41):
    k = erle41["excess_kurtosis"]
    _same(k["value"], DOC["erle"]["41"]["excess_kurtosis"]["value"], k["sd"])
    assert np.all(np.array(k["value"]) - 3 * np.array(k["sd"]) > 50)


def test_flight83_no_lag_but_a_misalignment(erle83):
    tau, rot = erle83["time_offset_s"], erle83["rotation_deg"]
    _same(tau["value"], DOC["erle"]["83"]["time_offset_s"]["value"], tau["sd"])
    _same(rot["value"], DOC["erle"]["83"]["rotation_deg"]["value"], rot["sd"])
    assert abs(tau["value"]) < 3 * tau["sd"]                 # no lag claimed
    assert rot["value"] > 3 * rot["sd"]                      # 0.7°: real
    z_before, z_after = erle83["rms_lag_rps"][2], erle83["rms_lag_aligned_rps"][2]
    assert z_after < 0.75 * z_before
    assert erle83["lines"] == []                             # no line: unexplained rest


@pytest.fixture(scope="module")
def mpu4():
    for k in (1, 2, 3, 4):
        data_file("multi_imu_4x_mpu9250", f"imu{k}_raw.mat")
    return MF.mpu4(shared_data())


def test_mpu9250_noise_is_white_and_aliased(mpu4):
    fs = mpu4["sample_rate_hz"]
    for got, doc in zip(mpu4["imus"], DOC["mpu4"]["imus"], strict=True):
        sd = np.array(got["std_rps"]["value"])
        _same(sd, doc["std_rps"]["value"], got["std_rps"]["sd"])
        dens = np.array(got["density_rps_rthz"]["value"])
        dens_sd = np.array(got["density_rps_rthz"]["sd"])
        # white over the logged band: all the variance folded into 0..fs/2 (to 2 %: the
        # drift below the 0.5 Hz band edge holds about 1 % of the variance)
        want = sd / np.sqrt(fs / 2)
        for k in (0, 2):                                     # x, z: no shared motion
            assert abs(dens[k] - want[k]) < 3 * dens_sd[k] + 0.03 * want[k]
        assert np.all(dens / DPS > 2 * MF.DATASHEET["mpu9250"]["density_dps_rthz"])


def test_mpu9250_one_shared_motion_and_parity_removes_it(mpu4):
    cm = mpu4["common_mode"]
    assert cm["n_common"] == 1
    assert cm["eigenvalues"][0] > 1.3 > cm["edge"]
    kt = cm["kurtosis_top"]
    assert kt["value"][0] > 3 * kt["sd"][0]                  # bursts: heavy tails
    kp = cm["kurtosis_parity"]
    assert np.max(np.array(kp["value"]) - 3 * np.array(kp["sd"])) < kt["value"][0] / 4
    # the 20.6 Hz line of every IMU is in the shared motion, not in the parity
    assert all(abs(imu["lines"][0]["f_hz"] - 20.6) < 0.2 for imu in mpu4["imus"])


def test_mpu9250_imu1_accelerometer_reads_18_percent_low(mpu4):
    norm = np.array(mpu4["accel_norm_mps2"])
    _same(norm, DOC["mpu4"]["accel_norm_mps2"], 0.01)
    assert norm[0] / 9.80665 == pytest.approx(0.815, abs=0.01)
    assert np.all(np.abs(norm[1:] / 9.80665 - 1) < 0.02)


@pytest.fixture(scope="module")
def adis(tmp_path_factory):
    data_file("smac_adis16405", "adis_16405_imu1.rda")
    return MF.adis(shared_data(), tmp_path_factory.mktemp("adis"))


def test_adis16405_against_its_datasheet(adis):
    ds = MF.DATASHEET["adis16405"]
    dens = np.array(adis["density_rps_rthz"]["value"]) / DPS
    dens_sd = np.array(adis["density_rps_rthz"]["sd"]) / DPS
    _same(dens, np.array(DOC["adis"]["density_rps_rthz"]["value"]) / DPS, dens_sd)
    # 7-20 % above the typical density, each well beyond its σ
    ratio = dens / ds["density_dps_rthz"]
    assert np.all((ratio > 1.05) & (ratio < 1.25)) and np.all(dens_sd < 0.01 * dens)
    arw = np.array(adis["allan_n_at_1s_rps_rthz"]) / DPS * 60.0     # °/√h
    assert np.all((arw / ds["arw_deg_rth"] > 1.1) & (arw / ds["arw_deg_rth"] < 1.35))
    bmin = np.array(adis["allan_min_rps"]) / DPS
    assert np.all(np.abs(bmin / ds["in_run_bias_dps"] - 1) < 0.3)


def test_adis16405_z_resonance_near_20_hz(adis):
    k = adis["excess_kurtosis"]
    assert k["value"][2] < -3 * k["sd"][2] - 0.1               # platykurtic: a tone
    assert all(abs(k["value"][j]) < 0.05 for j in (0, 1))
    assert adis["lines"] and 19.0 < adis["lines"][0]["f_hz"] < 21.0
    peaks = np.array(adis["z_band_peak_hz_per_1000s"])
    np.testing.assert_allclose(peaks, DOC["adis"]["z_band_peak_hz_per_1000s"])
    assert peaks[0] - np.median(peaks[3:]) > 1.0             # moves 2 Hz, then holds
    assert np.ptp(peaks[3:]) < 0.5
    assert 0.25 < adis["z_band_power_fraction"] < 0.45


def test_px4_raw_biases_differ_between_instances():
    data_file("px4_ulog", "sample_log_small.ulg")
    got = MF.px4(shared_data())["sample_log_small.ulg"]
    doc = DOC["px4"]["sample_log_small.ulg"]
    raw, cal = got["sensor_gyro"], got["vehicle_imu"]
    d = np.array(raw["diff_to_imu1_rps"])
    sd = np.array(raw["diff_to_imu1_sd_rps"])
    _same(d, doc["sensor_gyro"]["diff_to_imu1_rps"], sd)
    assert abs(d[1, 0]) / sd[1, 0] > 10                       # imu2 x: 3.5 °/s apart
    dc = np.array(cal["diff_to_imu1_rps"])
    sdc = np.array(cal["diff_to_imu1_sd_rps"])
    _same(dc, doc["vehicle_imu"]["diff_to_imu1_rps"], sdc)
    assert np.all(np.abs(dc) < np.radians(0.4))               # calibrated: within 0.4 °/s
    np.testing.assert_allclose(got["temperature_degc"], [40.2, 28.3, 29.6], atol=0.3)
