"""Parity drift model (fdi.drift, calibration.drift): file form, the random-walk prediction,
and what ``tune`` does with it (variance factors and detectable sizes grow)."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from calibration.drift import fit_drift_model
from fdi.calfile import CALIBRATION_SCHEMA, CALIBRATION_SCHEMA_DRIFT, calibration_from_dict
from fdi.drift import DriftModel, drift_variance_factors, offset_levels
from fdi.errors import ConfigError, FileFormatError
from studies.realnoise import static_calibration
from studies.tails_holdout import without_tails
from thresholds.tune import tune

NAMES = tuple(f"imu{k}_{a}" for k in range(1, 5) for a in "xyz")
FS = 50.0


def _static(seed: int, n_samples: int = 12_000, q: float = 0.0, sensor: int = 4,
            sd: float = 0.002) -> np.ndarray:
    """Four aligned triads at rest: white noise of ``sd`` (rad/s) per channel, and on
    ``sensor`` a random-walk bias with increment sd ``q`` (rad/s per sample)."""
    rng = np.random.default_rng(seed)
    y = rng.standard_normal((n_samples, 12)) * sd
    if q:
        y[:, sensor] += np.cumsum(rng.standard_normal(n_samples)) * q
    return y


def _cal(y: np.ndarray, drift: bool = True):
    return static_calibration(y, FS, NAMES, drift=drift)


def test_file_round_trip_schema_and_fingerprint():
    y = _static(1, q=2e-5)
    with_drift, plain = _cal(y), _cal(y, drift=False)
    assert with_drift.gyro.drift is not None and plain.gyro.drift is None
    doc = with_drift.to_dict()
    assert doc["schema"] == CALIBRATION_SCHEMA_DRIFT and "gyro" in doc["parity_drift"]
    back = calibration_from_dict(json.loads(json.dumps(doc)))
    assert back.gyro.drift == with_drift.gyro.drift
    assert back.fingerprint() == with_drift.fingerprint()
    # without a drift model the file is what it was (/3, no key), and the model is in the
    # fingerprint: it changes the thresholds
    pd = plain.to_dict()
    assert pd["schema"] == CALIBRATION_SCHEMA and "parity_drift" not in pd
    assert plain.fingerprint() != with_drift.fingerprint()
    # a /3 file with the key is refused (unknown field), a /4 file without it loads
    bad = dict(doc, schema=CALIBRATION_SCHEMA)
    with pytest.raises(FileFormatError, match="parity_drift"):
        calibration_from_dict(bad)
    assert calibration_from_dict({k: v for k, v in doc.items() if k != "parity_drift"}
                                 ).gyro.drift is None


@pytest.mark.parametrize(("field", "value", "msg"), [
    ("excess", "neg", "excess"), ("tau_s", "rev", "tau_s"), ("blocks", [3], "blocks"),
    ("method", "rimu.drift/9", "method")])
def test_bad_drift_record_names_the_field(field, value, msg):
    doc = _cal(_static(2, q=2e-5)).to_dict()
    rec = doc["parity_drift"]["gyro"]
    if value == "neg":
        rec["excess"][-1] = -1.0
    elif value == "rev":
        rec["tau_s"] = rec["tau_s"][::-1]
    else:
        rec[field] = value
    with pytest.raises(FileFormatError, match=f"parity_drift.gyro.{msg}"):
        calibration_from_dict(doc)


def test_random_walk_offset_predicted_from_the_calibration_half():
    """A random-walk bias on one sensor: the model fitted on the first half predicts the
    variance of the whitened parity offset at the end of a horizon of the same length
    (K²·(h + T_c/3)·|u_i|², IEEE 952 rate random walk).

    Over 60 seeds the mean prediction must match the truth within 3 standard errors of
    the mean (from the spread of the 60 predictions)."""
    n, q, i = 12_000, 2e-5, 4
    half = n // 2
    preds = []
    for seed in range(60):
        y = _static(100 + seed, n_samples=n, q=q, sensor=i)
        cal = _cal(y[:half])
        preds.append(cal.gyro.drift.offset_variance())
    s = cal.gyro
    from thresholds.tune import _parity_geometry

    _, u2, _, _, _ = _parity_geometry(cal, "gyro")
    truth = q * q * (half + half / 3.0) * u2[i]              # per sample: h = T_c
    preds = np.array(preds)
    se = preds.std(ddof=1) / math.sqrt(preds.size)
    assert preds.mean() == pytest.approx(truth, abs=3 * se)
    assert s.drift.span_s == pytest.approx(half / FS)


def test_white_noise_shows_little_drift():
    """White noise: an excess counts at 1 % per τ and three τ of the long end can set δ²
    (2 % of 300 white fits showed a drift); 5 or more of 40 has a binomial probability
    below 0.01 at a rate of 3 %."""
    d2 = np.array([_cal(_static(200 + s)).gyro.drift.offset_variance() for s in range(40)])
    assert np.sum(d2 > 0.0) <= 4


def test_variance_factors_and_horizon():
    m = DriftModel(df=9, samples=1000, sample_rate_hz=50.0, span_s=20.0,
                   tau_s=(1.0, 2.0), blocks=(20, 10), excess=(0.01, 0.002))
    # random walk from tau_L = 2 s to tau_h = 1.5 h + T_c/2; never below the long end's max
    assert m.offset_variance() == pytest.approx(2 * 0.002 * (30 + 10) / 2.0)
    assert m.offset_variance(0.0) == pytest.approx(2 * max(0.002 * 10 / 2.0, 0.01))
    assert drift_variance_factors(m, (1, 8), (1.0, 2.0), 0.0) == pytest.approx(
        (1.0 + 0.02, 2.0 + 8 * 0.02))
    assert drift_variance_factors(None, (1, 8), (1.0, 2.0)) == (1.0, 2.0)


def test_tune_adds_the_drift_and_states_what_it_gives_up():
    cal = without_tails(_cal(_static(3, q=3e-5)))
    a = tune(cal, false_alarms_per_hour=100.0, simulate_hours=0.0)
    b = tune(cal, false_alarms_per_hour=100.0, simulate_hours=0.0, drift_horizon_s=0.0)
    plain = tune(replace(cal, sets={"gyro": replace(cal.gyro, drift=None)}),
                 false_alarms_per_hour=100.0, simulate_hours=0.0)
    d2 = cal.gyro.drift.offset_variance()
    assert d2 > 0
    ws = a.thresholds.scales
    vf_plain = plain.thresholds.variance_factor
    assert a.thresholds.variance_factor == pytest.approx(drift_variance_factors(
        cal.gyro.drift, ws, vf_plain, None, a.thresholds.alpha))
    # the level at each alpha lies between no drift and the end-of-horizon offset put on
    # every direction (f + w·δ²(h), the rule without alpha)
    for w, f, fa in zip(ws, vf_plain, a.thresholds.variance_factor, strict=True):
        assert f < fa <= f + w * d2, (w, f, fa, d2)
    # a shorter horizon gives up less, and every detectable size grows with the drift
    assert all(x <= y for x, y in zip(b.thresholds.variance_factor,
                                      a.thresholds.variance_factor, strict=True))
    assert all(da.size > dp.size for da, dp in zip(a.detectable, plain.detectable,
                                                   strict=True))
    dr = a.assumptions["drift"]
    assert dr["horizon_s"] == pytest.approx(cal.gyro.drift.span_s)
    assert dr["offset_variance_whitened"] == pytest.approx(d2)
    assert plain.assumptions["drift"]["model"] is None
    assert "parity drift" in a.thresholds.notes
    with pytest.raises(ConfigError, match="drift-horizon"):
        tune(cal, false_alarms_per_hour=100.0, simulate_hours=0.0, drift_horizon_s=-1.0)


def test_fit_needs_a_parity_space():
    assert fit_drift_model(np.zeros((100, 3)), np.eye(3), np.eye(3), FS) is None


def test_tune_cli_states_the_drift_given_up(tmp_path, capsys):
    from rimu.cli import main

    cal = without_tails(_cal(_static(4, q=3e-5)))
    path = tmp_path / "cal.json"
    cal.save(path)
    out = tmp_path / "t.json"
    assert main(["tune", "--cal", str(path), "--false-alarms-per-hour", "100",
                 "--simulate-hours", "0", "--drift-horizon-s", "60", "--out", str(out),
                 "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "parity drift over 60 s" in text and "taken as healthy" in text
    doc = json.loads(out.read_text())
    assert doc["assumptions"]["drift"]["horizon_s"] == 60.0
    assert main(["tune", "--cal", str(path), "--false-alarms-per-hour", "100",
                 "--drift-horizon-s", "-5", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--drift-horizon-s" in err[0]


def test_default_thresholds_carry_the_drift_over_the_calibration_span():
    from fdi.detector import default_thresholds

    cal = without_tails(_cal(_static(5, q=3e-5)))
    plain = replace(cal, sets={"gyro": replace(cal.gyro, drift=None)})
    a, b = default_thresholds(cal), default_thresholds(plain)
    d2 = cal.gyro.drift.offset_variance()
    assert d2 > 0
    assert a.variance_factor == pytest.approx(drift_variance_factors(
        cal.gyro.drift, b.scales, b.variance_factor, None, a.alpha))
    for w, f, fa in zip(b.scales, b.variance_factor, a.variance_factor, strict=True):
        assert f < fa <= f + w * d2, (w, f, fa, d2)
    assert "parity drift" in a.notes and "parity drift" not in b.notes


def test_drift_and_validated_range_in_one_file():
    cal = _cal(_static(6, q=2e-5))
    g = replace(cal.gyro, validated_rate=np.array([1.0, 2.0, 3.0]),
                validated_specific_force=12.0)
    cal = replace(cal, sets={"gyro": g})
    back = calibration_from_dict(json.loads(json.dumps(cal.to_dict())))
    assert back.gyro.drift == cal.gyro.drift
    assert back.gyro.validated_rate.tolist() == [1.0, 2.0, 3.0]
    assert back.fingerprint() == cal.fingerprint()


@pytest.mark.parametrize("df, alpha", [(3, 1e-3), (9, 1e-3), (2, 1e-2)])
def test_offset_levels_are_exceeded_at_alpha_over_the_horizon(df, alpha):
    """Monte Carlo: the time t is drawn over the horizon (the quadrature nodes' weights), an
    offset of variance δ²(t) is put along one direction or spread over all, noise is χ²(df);
    each shape's level is exceeded with probability α (binomial 3σ), the larger of the two
    levels (what the thresholds use) at most α for both shapes, and both below the bare
    rule's level (the end-of-horizon offset on every direction)."""
    from scipy import stats

    rng = np.random.default_rng(df * 1000 + int(-math.log10(alpha)))
    m = DriftModel(df=df, samples=10_000, sample_rate_hz=50.0, span_s=200.0,
                   tau_s=(5.0, 10.0, 20.0), blocks=(40, 20, 10), excess=(0.0, 0.01, 0.02))
    d2_t, wts = m.offset_variances()
    assert wts.sum() == pytest.approx(1.0) and d2_t[-1] <= m.offset_variance()
    w, f = 64, 1.3
    lam = w * d2_t / f                              # offset variance per noise variance
    one, spread = offset_levels(alpha, df, lam, wts)
    n = 400_000
    j = rng.choice(lam.size, size=n, p=wts)
    noise = rng.standard_normal((n, df))
    along = noise.copy()
    along[:, 0] += rng.standard_normal(n) * np.sqrt(lam[j])
    even = noise + rng.standard_normal((n, df)) * np.sqrt(lam[j] / df)[:, None]
    d_one, d_even = np.sum(along**2, axis=1), np.sum(even**2, axis=1)
    sd = math.sqrt(n * alpha * (1 - alpha))
    for name, d, q in (("one direction", d_one, one), ("spread", d_even, spread)):
        k = int(np.sum(d > q))
        assert abs(k - n * alpha) < 3 * sd, (name, k, n * alpha)
    top = max(one, spread)
    for name, d in (("one direction", d_one), ("spread", d_even)):
        assert np.sum(d > top) < n * alpha + 3 * sd, name
    assert top < (1 + w * m.offset_variance() / f) * stats.chi2.isf(alpha, df)
