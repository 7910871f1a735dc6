"""thresholds: compute, file round trip and validation, Allan from residuals, oracle."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fdi.errors import FileFormatError
from fdi.settings import load_thresholds
from studies.oracle import oracle_detect
from studies.synthetic import raw_samples, synthetic_calibration
from thresholds import compute_thresholds

CAL = synthetic_calibration("cone6", seed=2)


def test_round_trip_and_schema(tmp_path):
    th = compute_thresholds(CAL, false_alarms_per_hour=1e-3, scales=5, detector="both")
    p = tmp_path / "th.json"
    th.save(p)
    doc = json.loads(p.read_text())
    assert doc["schema"] == "rimu.thresholds/2"
    assert doc["calibration_fingerprint"] == CAL.fingerprint()
    assert doc["noise_model"] == "gaussian-white"
    assert load_thresholds(p) == th
    assert th.scales == (1, 2, 4, 8, 16, 32)
    assert sum(th.alpha) + th.alpha[0] == pytest.approx(1e-3 / 360000.0)   # 6 scales + CUSUM


def test_version_1_file_still_loads(tmp_path):
    doc = compute_thresholds(CAL, scales=3).to_dict()
    doc["schema"] = "rimu.thresholds/1"
    del doc["calibration_fingerprint"], doc["noise_model"]
    p = tmp_path / "old.json"
    p.write_text(json.dumps(doc))
    th = load_thresholds(p)
    assert th.calibration_fingerprint == "" and th.noise_model == "gaussian-white"
    assert th.scales == (1, 2, 4, 8)
    th.save(tmp_path / "new.json")                          # migrated on save
    assert json.loads((tmp_path / "new.json").read_text())["schema"] == "rimu.thresholds/2"


@pytest.mark.parametrize(("key", "value"), [("schema", "rimu.thresholds/3"), ("alpha", [2.0]),
                                           ("calibration_fingerprint", "xyz"),
                                           ("noise_model", "laplace"),
                                           ("n", None), ("kind", "magnetometer"),
                                           ("variance_factor", [1.0, "x"]),
                                           ("false_alarm_per_hour", 1.0)])
def test_bad_files_name_the_field(tmp_path, key, value):
    doc = compute_thresholds(CAL, scales=0).to_dict()
    if value is None:
        del doc[key]
    else:
        doc[key] = value
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(FileFormatError) as ei:
        load_thresholds(p)
    assert ei.value.field is not None and ei.value.field.startswith(key)


def test_cusum_detector_without_threshold_names_the_field(tmp_path):
    """Regression: the combination was refused by Thresholds.__post_init__ with a
    ConfigError that did not name the file."""
    doc = compute_thresholds(CAL, scales=0).to_dict()
    doc["detector"] = "cusum"
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(FileFormatError) as ei:
        load_thresholds(p)
    assert ei.value.field == "cusum_threshold" and "bad.json" in str(ei.value)


def test_variance_factors_from_residuals_via_allantools():
    rng = np.random.default_rng(0)
    sd = CAL.gyro.noise_sd
    white = rng.standard_normal((40_000, 6)) * sd
    f_white = compute_thresholds(CAL, residuals=white, scales=8).variance_factor
    assert max(f_white) < 1.35                   # estimation noise of the worst of six
    walk = white + np.cumsum(rng.standard_normal((40_000, 6)), axis=0) * sd * 0.01
    f_walk = compute_thresholds(CAL, residuals=walk, scales=8).variance_factor
    assert f_walk[-1] > 2.0 * f_walk[0]          # rate random walk: long means vary more


def test_oracle_detects_a_step_at_once_and_nothing_before():
    N, onset = 3000, 1500
    t = np.arange(N) / 100.0
    om = np.stack([np.sin(t), np.cos(t), 0.5 * np.sin(0.3 * t)], axis=1)
    f = np.zeros((N, 6))
    f[onset:, 3] = 15 * CAL.gyro.noise_sd[3]
    raw = raw_samples(CAL, om, seed=1, fault=f)
    r = oracle_detect(CAL, t, raw, 4, onset / 100.0)
    assert r.false_alarms == 0
    assert r.delay_s == 0.0 and r.scale == 1
