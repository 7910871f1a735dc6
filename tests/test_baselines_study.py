"""The rimu-against-the-autopilots campaign (studies/baselines_campaign.py, docs/baselines.md):
a small cut recomputed against the stored studies/baselines.json (fast), the whole campaign
recomputed (``--campaign``), and the must-hold verdicts computed as the doc states them."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:               # studies/ is not installed: import it from the clone
    sys.path.insert(0, str(ROOT))

from studies import baselines_campaign as bc  # noqa: E402

STORED = ROOT / "studies" / "baselines.json"
MONITORS = bc.MONITORS


def _stored() -> dict:
    if not STORED.exists():
        pytest.skip(f"{STORED} not generated")
    return json.loads(STORED.read_text(encoding="utf-8"))


def _same(a: dict, b: dict, period: float) -> None:
    for m in MONITORS:
        x, y = a[m], b[m]
        for k in ("detected", "blamed", "blame_correct", "wrong_exclusions"):
            assert x[k] == y[k], (m, k, x, y)
        for k in ("delay_s", "blame_delay_s"):
            if x[k] is None or y[k] is None:
                assert x[k] == y[k], (m, k)
            else:
                assert abs(x[k] - y[k]) <= period + 1e-9, (m, k, x[k], y[k])


def test_a_cut_of_the_stored_campaign_recomputes():
    """erle 83 monitored with the calibration of 41: steps of 10 deg/s and a stuck axis on
    one axis of each IMU at the first onset, the clean flight too, as stored."""
    ev = _stored()
    if not (bc.SHARED / "erle_pxf_dual_imu").is_dir():
        pytest.skip(f"no {bc.SHARED / 'erle_pxf_dual_imu'}")
    stored = next((c for c in ev["cases"] if c["case"].startswith("erle 83")), None)
    assert stored is not None, "the stored campaign has no erle 83 case"
    cases, _ = bc.build_cases(("erle",))
    case = next(c for c in cases if c.name == stored["case"])
    faults = [f for f in bc.FAULTS if f[0] in ("step 10 deg/s", "stuck")]
    got = bc.run_case(case, faults, bc.ONSET_FRACTIONS[:1], sensors=[1, 5])
    period = 1.0 / got["sample_rate_hz"]
    for m in MONITORS:
        assert got["clean"][m] == stored["clean"][m], m
    want = {(r["fault"], r["sensor"], round(r["onset_s"], 6)): r for r in stored["runs"]}
    assert len(got["runs"]) == 4
    for r in got["runs"]:
        _same(r, want[(r["fault"], r["sensor"], round(r["onset_s"], 6))], period)


@pytest.mark.campaign
def test_the_whole_campaign_recomputes():
    ev = _stored()
    new = bc.run_campaign([g for g in ev["groups"]] or ["erle", "sim3", "sim4", "xsens"])
    assert new["must_hold"] == ev["must_hold"]
    assert new["groups"] == ev["groups"]


def _run(fault, rimu, px4, imu="imu1"):
    def o(d, b):
        return {"detected": d is not None, "delay_s": d, "blamed": b,
                "blame_delay_s": None if b is None else d,
                "blame_correct": None if b is None else b == imu, "wrong_exclusions":
                0 if b in (None, imu) else 1, "wrong_exclusion_before_onset": False}
    return {"fault": fault, "sensor": 1, "axis": "imu1.x", "imu": imu, "onset_s": 10.0,
            "rimu": o(*rimu), "px4": o(*px4), "px4-others": o(*px4),
            "ardupilot": o(None, None)}


def test_must_hold_verdicts_follow_their_definitions():
    clean = {"duration_s": 60.0, **{m: {"alarms": 0, "excluded": []} for m in MONITORS}}
    good = {"case": "a", "group": "xsens", "clean": dict(clean),
            "runs": [_run("step 5 deg/s", (0.1, "imu1"), (4.0, "imu1")),
                     _run("step 2 deg/s", (1.0, None), (None, None))]}
    mh = bc.summarise([good])["must_hold"]
    assert mh["detects_no_later_than_px4"]["met"]
    assert mh["right_blame_at_least_as_often"]["met"]
    assert mh["clean_alarms_no_more"]["met"]
    assert mh["four_imu_xsens"]["met"]
    late = {**good, "runs": [_run("step 5 deg/s", (5.0, "imu2"), (4.0, "imu1"))],
            "clean": {**clean, "rimu": {"alarms": 3, "excluded": []}}}
    mh = bc.summarise([late])["must_hold"]
    assert not mh["detects_no_later_than_px4"]["met"]
    assert mh["detects_no_later_than_px4"]["rimu_later_or_missed"] == 1
    assert not mh["right_blame_at_least_as_often"]["met"]
    assert not mh["clean_alarms_no_more"]["met"]
    assert not mh["four_imu_xsens"]["met"]
    assert mh["four_imu_xsens"]["runs_with_wrong_exclusion"] == 1
