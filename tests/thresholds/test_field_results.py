"""Issue 17's Must-hold list on measured data, recomputed from ``../shared/data``.

One call (:func:`studies.field.field_results`, about 3 min) computes what
``docs/field-results.md`` shows: held-out false alarms of the two ArduCopter flights and the
4×MPU9250 static set, runs from the start of each flight, faults injected into every
sensor of both flights. Each claim of :func:`studies.field_claims.must_hold` is one test; the
claims and their numbers come from the issue (no tolerance chosen here). Skipped when the
data are absent (``RIMU_SHARED_DATA`` overrides the folder).

Eight of the ten hold (statistical isolation, envelope with the calibrated range, tail thresholds
with the timing-jitter term, the static set's tail and parity-drift thresholds,
docs/drift.md, the clearing floor, the targets ``rimu tune`` refuses, correction flights
inside the calibration's validated range and a flight simulator whose drawn bias keeps the
calibrated output at rest). A claim that stops holding fails here; :data:`OPEN` is where
one that cannot hold yet would be listed as a strict xfail, with the reason.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

DATA = Path(os.environ.get("RIMU_SHARED_DATA",
                           Path(__file__).parents[2] / ".." / "shared" / "data"))
NEEDED = [DATA / "erle_pxf_dual_imu" / "pxf_copter_22-12-2014_41.BIN",
          DATA / "erle_pxf_dual_imu" / "pxf_copter_31-3-2015_83.BIN",
          DATA / "multi_imu_4x_mpu9250" / "imu1_raw.mat"]
CLAIMS = (
    "from the start of 41 and 83: no healthy sensor excluded",
    "two-IMU set: no isolation claimed (from the start and with injected faults)",
    "injected faults: no healthy sensor excluded",
    "injected faults at or above the detectable size: detected within 10 s",
    "10 deg/s step on any axis of either IMU: detected within 1 s",
    "the faulted direction is unverified from the first alarm on",
    "out-of-envelope periods: at most 10 % of flying time, each with a reason",
    "held out, outside the envelope: false alarms within 3x of the target where the length "
    "resolves it",
    "held out at 1/h: at most one alarm over all real flights together",
    "4x MPU9250: time in alarm at most 3x what the target implies, no exclusion",
)

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def verdicts():
    missing = [str(p) for p in NEEDED if not p.exists()]
    if missing:
        pytest.skip(f"real data absent: {', '.join(missing)}")
    from studies.field import field_results
    from studies.field_claims import must_hold

    res = field_results(DATA, progress=False)
    return res, {c: (h, d) for c, h, d in must_hold(res)}


def test_the_evidence_covers_what_the_issue_asks(verdicts):
    res, v = verdicts
    assert set(v) == set(CLAIMS)
    def covered(rec):
        """Every target either counted both ways round or refused by ``rimu tune`` (alarms
        that would merge at the recording's rate), with the reason."""
        done = [r["target_per_hour"] for r in rec["rows"]]
        refused = {x["target_per_hour"] for x in rec["refused"]}
        assert all("refused by rimu tune" in x["reason"] for x in rec["refused"])
        assert set(done) | refused == {1, 10, 100, 1000} and not set(done) & refused
        assert len(done) == 2 * len(set(done))                     # both ways round
        assert {1, 10, 100} <= set(done)

    for k in ("41", "83"):
        f = res["flights"][k]
        assert len(f["injection"]["rows"]) == 6 * 4 * len(f["injection"]["onsets_s"])
        assert len(f["injection"]["onsets_s"]) == 3
        covered(f["holdout"])
    covered(res["static_4x_mpu9250"])
    # some target must be resolved by each recording, or the rate claim tests nothing
    for rows in [f["holdout"]["rows"] for f in res["flights"].values()] + [
            res["static_4x_mpu9250"]["rows"]]:
        assert any(r["resolved"] for r in rows)


OPEN: dict[str, str] = {
    "the faulted direction is unverified from the first alarm on":
        "detections end (issue 27 item 3: hysteresis, clear_samples below the clearing level): "
        "a fault near the detectable size whose evidence falls back clears and the axis is "
        "verified again while the fault persists; 12 of 242 detected runs (5 deg/s steps on "
        "83, one 2 deg/s step on 41), docs/field-results.md regenerated 2026-12-02",
    "held out, outside the envelope: false alarms within 3x of the target where the length "
    "resolves it":
        "41 at 100/h, second half: 6 alarm episodes against 1.90 expected (3x = 5.7) since the "
        "per-IMU in-flight calibration (a8b94ff); the other 6 resolved rows hold",
}
"""Claims that do not hold yet (issue 17 stays open on them): strict xfail, so a change that
makes one hold fails here until it moves to the holding list."""


@pytest.mark.parametrize("claim", [pytest.param(c, marks=pytest.mark.xfail(
    reason=OPEN[c], strict=True)) if c in OPEN else c for c in CLAIMS])
def test_must_hold(verdicts, claim):
    holds, detail = verdicts[1][claim]
    assert holds, f"{claim}: {detail}"
