"""Cross-flight evidence on the erle flights (studies/cross_flight.py, docs/next-flight.md;
``pytest --campaign tests/replay/test_cross_flight.py``).

Calibrated and tuned (1/h) on one flight, monitored on the other. What holds and is checked
here: no exclusion in either pair, before or after; the chain finds the rest stretch before
take-off on both flights and moves the biases by what it measured there; the parameter
check names the scale, time offset and noise mismatch of both pairs; with the chain's
defaults (the two logs name two firmware builds, so IMU2's relative scale, mounting and
time offset are held at the calibration's prior, replay.firmware_prior) at most one alarm
inside the envelope per pair and at most 10 % of the samples unverified (the issue's
must-hold; before the firmware prior 83 -> 41 gave 13-15 alarms and 54-69 %). The 10 °/s
step within 1 s is NOT met (4 of 24 with the prior: docs/next-flight.md).
"""

from __future__ import annotations

import pytest

from tests.replay.ingest.ingest_helpers import data_file


@pytest.mark.campaign          # two tunes and four fits: about 2 min on a loaded machine
def test_erle_pairs_exclude_nothing_and_name_what_does_not_fit():
    from studies.cross_flight import ERLE, cross_pairs, load_log

    folder, names = ERLE
    flights = {n.split("_")[-1].split(".")[0]: load_log(data_file(folder, n)) for n in names}
    doc = cross_pairs(flights, steps=False)
    assert len(doc["pairs"]) == 2
    for r in doc["pairs"]:
        assert r["before"]["excluded"] == [] and r["after"]["excluded"] == [], r
        assert r["turn_on"]["method"] == "rest", r["turn_on"]
        rest = r["turn_on"]["rest"]
        assert rest["samples"] >= 100 and rest["takeoff_s"] > rest["t1_s"]
        flagged = {(m["imu"], m["parameter"]) for m in r["misfit"]}
        assert {("imu2", "scale"), ("imu2", "time offset")} <= flagged, flagged
        assert any(p == "noise" for _, p in flagged)
        assert r["after"]["alarms_in_envelope"] <= 1, r["after"]
        assert r["after"]["unverified_fraction"] <= 0.10, r["after"]
    assert doc["after"]["hours"] > 0 and doc["after"]["ci95_per_hour"][0] >= 0


def test_the_docs_blocks_are_the_studys_json():
    """docs/next-flight.md and docs/field-results.md carry the block the study writes from
    studies/cross_flight.json (regenerated, not hand-typed), with a verdict per must-hold."""
    import json
    from pathlib import Path

    from studies.cross_flight import markdown

    root = Path(__file__).resolve().parents[2]
    doc = json.loads((root / "studies" / "cross_flight.json").read_text(encoding="utf-8"))
    block = markdown(doc)
    assert "erle" in doc and "no exclusion:" in block
    for name in ("next-flight.md", "field-results.md"):
        assert block in (root / "docs" / name).read_text(encoding="utf-8"), name
