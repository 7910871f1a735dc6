"""Held-out false alarms on the measured recordings, with the residual tail model (slow).

Erle ArduCopter flights 41 and 83 (two IMUs, ``../shared/data/erle_pxf_dual_imu``) and the
4×MPU9250 static set: each split in time, calibrated on one half, counted on the other,
both ways (:mod:`studies.tails_holdout`; flights: the in-flight calibration's left-out
periods are not counted). Data read in place (``RIMU_SHARED_DATA`` overrides); skipped when
absent. What is asserted is what docs/noise-tails.md states:

- with the tail model, every resolvable target (three times the target gives at least
  three expected alarms in the held-out time) is met within 3× (the exact Poisson 95 %
  interval of the held-out rate reaches 3 × target or below);
- at 1 false alarm per hour, at most one alarm over both flights, both ways, together;
- today's Gaussian thresholds do not meet 1 per hour (several alarms in minutes);
- the calibrations carry the timing jitter of imu2 and their tail models are relative to
  the monitor's inflation (:func:`calibration.inflight.calfile.calibration_from_fit`);
  the statistic so normalised is still not Gaussian, but the jitter term explains most
  of flight 41's kurtosis (against the bare statistic, ``jitter=False``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "calibration"))
from _erle import DATA, FLIGHTS, SHARED, read_erle

TARGETS = (1.0, 10.0, 100.0)
"""1000/h is refused by ``rimu tune`` at these rates (50 and 43.5 Hz: alarms would merge,
:func:`thresholds.tune.max_false_alarms_per_hour`)."""
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def flights():
    if not all((DATA / f).exists() for f in FLIGHTS.values()):
        pytest.skip(f"real data absent: {DATA}")
    from studies.tails_holdout import flight_holdout

    return {name: flight_holdout(read_erle(name), targets=TARGETS) for name in FLIGHTS}


@pytest.fixture(scope="module")
def bare_41():
    """Flight 41 held out as before the jitter term (tails of the bare statistic), the tail
    models only."""
    if not (DATA / FLIGHTS["41"]).exists():
        pytest.skip(f"real data absent: {DATA}")
    from studies.tails_holdout import flight_holdout

    return flight_holdout(read_erle("41"), targets=(), jitter=False)


def _records(report):
    for way in report["ways"]:
        for target, rec in way["results"]["tune"].items():
            yield way["fit"], float(target), rec


def test_flights_meet_resolvable_targets_within_3x(flights):
    checked = 0
    for name, rep in flights.items():
        for fit, target, rec in _records(rep):
            a = rec["after"]
            if a["resolvable"]:
                checked += 1
                assert a["within_3x"], (name, fit, target, a["alarms"], a["hours"])
    assert checked >= 4                     # 100/h on both flights, both ways


def test_one_per_hour_at_most_one_alarm_over_all_flights(flights):
    after = sum(rec["after"]["alarms"] for rep in flights.values()
                for _, target, rec in _records(rep) if target == 1.0)
    before = sum(rec["before"]["alarms"] for rep in flights.values()
                 for _, target, rec in _records(rep) if target == 1.0)
    assert after <= 1
    assert before >= 5                      # today's Gaussian thresholds: far above 1/h


def test_flight_residuals_fail_the_normality_check(flights, bare_41):
    for rep in flights.values():
        for way in rep["ways"]:
            assert not way["tail_model"][0]["gaussian"]
            assert way["tail_model"][0]["excess_kurtosis"] > 1
            assert way["timing_jitter_ms"][3] > 0.5          # imu2: about 1–2.3 ms
            assert way["timing_jitter_ms"][0] == 0.0         # the reference
    for way, bare in zip(flights["41"]["ways"], bare_41["ways"], strict=True):
        k_bare = bare["tail_model"][0]["excess_kurtosis"]
        k = way["tail_model"][0]["excess_kurtosis"]
        assert k_bare > 5 and k < k_bare / 3, (k, k_bare)


def test_mpu_static_set_held_out():
    mpu = SHARED / "multi_imu_4x_mpu9250"
    if not (mpu / "imu1_raw.mat").exists():
        pytest.skip(f"real data absent: {mpu}")
    from studies.realnoise import load_mpu9250_static
    from studies.tails_holdout import static_holdout_tails

    t, y, names = load_mpu9250_static(mpu)
    rep = static_holdout_tails(t, y, names, targets=TARGETS)
    checked = 0
    for _, target, rec in _records(rep):
        a = rec["after"]
        if a["resolvable"]:
            checked += 1
            assert a["within_3x"], (target, a["alarms"], a["hours"])
    assert checked >= 2
