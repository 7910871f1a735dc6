"""``rimu characterise DIR`` on flight folders with known noise, drift, line and tails."""

import json

import numpy as np
import pytest
from scipy import stats

from fdi.units import DPS
from replay.flight_data import Flight
from replay.flight_io import save_flight_dir
from replay.ingest.characterise_flight import allan_terms, characterise_flight, slow_drift
from rimu.cli import main

FS = 50.0


def _static(seed=0, n=30000, drift_dps=(0.0, 0.0, 0.0, 0.0, 0.0, 0.0), line=None,
            heavy=False):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    sigma = 0.1 * DPS
    x = rng.normal(0, sigma, (n, 6))
    if heavy:
        x[:, 5] = sigma * rng.standard_t(4, n) / np.sqrt(2.0)
    x += np.outer(t / t[-1], np.asarray(drift_dps) * DPS)
    if line is not None:
        x[:, :3] += 0.05 * DPS * np.sin(2 * np.pi * line * t)[:, None]
    names = tuple(f"imu{g}.{a}" for g in (1, 2) for a in "xyz")
    return Flight(t=t, raw=x, valid=np.ones_like(x, bool), sample_rate_hz=FS,
                  sensor_names=names, raw_unit="rad/s", source="synthetic", kind="gyro",
                  imu=("imu1",) * 3 + ("imu2",) * 3)


def test_allan_terms_recover_white_noise_arw():
    """White rate noise of density q: N = q, no B or K beyond a few per cent of N."""
    rng = np.random.default_rng(1)
    q = 0.01                                              # rad/s/√Hz
    x = rng.normal(0, q * np.sqrt(FS), 200000)
    import allantools
    tau, ad, _, _ = allantools.oadev(x, rate=FS, data_type="freq", taus="octave")
    tm = allan_terms(tau, ad, 200000 / (tau * FS))
    assert tm["N"] == pytest.approx(q, rel=0.03)
    assert tm["B"] < 0.1 * q and tm["K"] < 0.1 * q


def test_slow_drift_finds_a_trend_and_keeps_its_false_alarm_rate():
    t = np.arange(30000) / FS
    rng = np.random.default_rng(2)
    x = rng.normal(0, 1.0, (30000, 40))
    x[:, 0] += np.linspace(0, 0.2, 30000)                 # 0.2 against a 0.004 sd of the trend
    d = slow_drift(t, x)
    assert d["p_value"][0] < 1e-6 and d["change"][0] == pytest.approx(0.2, abs=0.05)
    # white noise: p-values of the 39 others uniform-ish; none below 1e-3 is the rule
    # (P(any < 1e-3) = 4 %): a level-0.01 test does not alarm more than binomially allowed
    p = np.array(d["p_value"][1:])
    assert np.sum(p < 0.01) <= stats.binom.isf(1e-3, p.size, 0.01)


def test_characterise_cli_names_drift_line_tail_and_shared_mode(tmp_path, capsys):
    f = _static(drift_dps=(0.0, 0.0, 0.0, 0.05, 0.0, 0.0), line=7.0, heavy=True)
    d = tmp_path / "f"
    save_flight_dir(f, d)
    assert main(["characterise", str(d), "--report", str(tmp_path / "rep")]) == 0
    out = capsys.readouterr().out
    assert "slow drift: imu2.x (+0.05" in out
    assert "at rest" in out
    doc = json.loads((tmp_path / "rep" / "characterise.json").read_text())
    assert doc["schema"] == "rimu.characterise/1"
    i1, i2 = doc["imus"]["imu1"], doc["imus"]["imu2"]
    assert i2["drift_significant"] == [True, False, False]
    assert not any(i1["drift_significant"])
    assert any(abs(ln["f_hz"] - 7.0) < 0.2 for ln in i1["lines"])
    # t(4) scaled: excess kurtosis is infinite in theory, large in a sample; the others ~0
    assert i2["excess_kurtosis"][2] > 1 and abs(i1["excess_kurtosis"][0]) < 0.2
    # white noise of 0.1 deg/s at 50 Hz: density 0.1/sqrt(25) = 0.02 deg/s/sqrt(Hz)
    # (imu2.y: no line, no drift, Gaussian)
    assert i2["density_dps_rthz"][1] == pytest.approx(0.02, rel=0.05)
    # Allan convention: sigma(1 s) = N, and N^2 = (one-sided density)^2 / 2
    assert i2["arw_deg_rth"][1] == pytest.approx(0.02 / np.sqrt(2) * 60, rel=0.05)
    # the 7 Hz line is on imu1 only: imu1's three axes share a mode
    assert doc["shared"]["n_shared"] >= 1
    assert (tmp_path / "rep" / "allan.png").stat().st_size > 1000
    assert (tmp_path / "rep" / "drift.png").stat().st_size > 1000


def test_characterise_one_imu_and_json(tmp_path, capsys):
    f = _static(n=6000)
    one = Flight(t=f.t, raw=f.raw[:, :3], valid=f.valid[:, :3], sample_rate_hz=FS,
                 sensor_names=f.sensor_names[:3], raw_unit="rad/s", source="one",
                 kind="gyro", imu=("imu1",) * 3)
    d = tmp_path / "one"
    save_flight_dir(one, d)
    assert main(["characterise", str(d), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert list(doc["imus"]) == ["imu1"] and doc["shared"] == {}
    assert characterise_flight(one)["imus"]["imu1"]["axes"] == ["imu1.x", "imu1.y", "imu1.z"]
