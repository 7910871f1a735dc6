"""replay.threshold_choice: one policy for the monitor's thresholds, with provenance."""

from __future__ import annotations

import json

import pytest

from fdi.errors import ConfigError, FileFormatError
from replay.threshold_choice import TUNING_SCHEMA, select
from studies.synthetic import synthetic_calibration
from thresholds import compute_thresholds

CAL = synthetic_calibration("cone6", seed=2)


def same(a, b) -> bool:
    """Thresholds equal field by field (their to_dict maps NaN to None)."""
    return a.to_dict() == b.to_dict()


def test_default_is_computed_from_the_calibration():
    ch = select(CAL)
    assert ch.source == "calibration"
    assert same(ch.thresholds, compute_thresholds(CAL, false_alarms_per_hour=1e-3))
    ch2 = select(CAL, false_alarms_per_hour=10.0)
    assert ch2.thresholds.false_alarms_per_hour == 10.0
    assert ch2.thresholds.threshold[0] < ch.thresholds.threshold[0]


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan")])
def test_non_positive_budget_refused(bad):
    with pytest.raises(ConfigError, match="positive"):
        select(CAL, false_alarms_per_hour=bad)


def test_file_and_tuned_file(tmp_path):
    th = compute_thresholds(CAL, false_alarms_per_hour=5.0)
    p = tmp_path / "t.json"
    th.save(p)
    ch = select(CAL, thresholds_file=p, false_alarms_per_hour=99.0)   # the file wins
    assert ch.source == "file" and same(ch.thresholds, th)
    assert ch.to_dict()["file"] == str(p)
    q = tmp_path / "tuned.json"
    q.write_text(json.dumps({"schema": TUNING_SCHEMA, "thresholds": th.to_dict(),
                             "assumptions": {"noise_model": "white"}}))
    ch = select(CAL, thresholds_file=q)
    assert ch.source == "tuned" and same(ch.thresholds, th)
    assert ch.assumptions["noise_model"] == "white"


def test_file_for_another_set_refused(tmp_path):
    th = compute_thresholds(synthetic_calibration("tetrad"), false_alarms_per_hour=5.0)
    p = tmp_path / "t.json"
    th.save(p)
    with pytest.raises(ConfigError, match="4 gyro sensors"):
        select(CAL, thresholds_file=p)


def test_bad_tuned_file_names_the_field(tmp_path):
    doc = compute_thresholds(CAL).to_dict()
    doc["alpha"] = [2.0] * len(doc["alpha"])
    q = tmp_path / "tuned.json"
    q.write_text(json.dumps({"schema": TUNING_SCHEMA, "thresholds": doc}))
    with pytest.raises(FileFormatError) as ei:
        select(CAL, thresholds_file=q)
    assert ei.value.field == "thresholds.alpha"
