"""rimu evaluate --baseline: the autopilot rules' answer to each campaign run is the one
they give on the same simulated samples, summarised as rimu's own numbers are."""

from __future__ import annotations

import json
import math

import pytest

from fdi.units import DPS
from replay.baselines import run_baselines
from replay.flight_sim import simulate_flight
from replay.threshold_choice import select
from thresholds.campaign import RunSpec, run_one
from thresholds.evaluate import summarise


@pytest.fixture(scope="module")
def cal3():
    from calibration.inflight import calibration_from_fit, fit_inflight
    from replay.imu_set import ImuSetSpec, simulate_imu_set

    f = simulate_imu_set(ImuSetSpec(imus=3, duration_s=40.0, seed=8, max_rate_dps=60.0))
    return calibration_from_fit(fit_inflight(f), f)


def test_run_one_baselines_are_those_of_the_same_samples(cal3):
    thr = select(cal3, false_alarms_per_hour=10.0).thresholds
    spec = RunSpec(0, 11, "step", 30 * DPS, 30.0, 5, 10.0, 30.0, 60.0)
    r = run_one(cal3, thr, spec, baselines=("px4-others", "ardupilot"))
    from replay.faults import Fault

    flight = simulate_flight(cal3, 30.0, seed=11, max_rate_dps=60.0,
                             faults=(Fault("step", 5, 30 * DPS, 10.0, None, "x"),))
    _, res = run_baselines(flight, ("px4-others", "ardupilot"), cal3)
    for b, (nm, direct) in zip(r.baselines, res.items(), strict=True):
        assert b.name == nm
        ev = direct.first_flag(10.0)
        assert b.detected == (ev is not None)
        if ev is not None:
            assert b.delay_s == pytest.approx(ev.t - 10.0)
    # a 30 deg/s step on imu2.y is 30 deg/s from the mean of the others: PX4 flags it and,
    # with three IMUs, blames imu2 (sensor 5's IMU) after about 15/23 s plus the filter lag
    px4 = r.baselines[0]
    assert px4.detected and px4.blamed == 1 and px4.blame_correct is True
    assert 0.5 < px4.delay_s < 1.5
    assert r.faulted_imu == 1
    healthy = run_one(cal3, thr, RunSpec(1, 12, "healthy", 0.0, 0.0, 0, 10.0, 30.0, 60.0),
                      baselines=("px4-others",))
    ev = summarise([r, healthy], thr, n_sensors=9)
    rules = ev["baselines"]["rules"]
    assert set(rules) == {"px4-others", "ardupilot"}
    cell = rules["px4-others"]["faults"][0]
    assert cell["runs"] == 1 and cell["pd"] == 1.0 and cell["p_blame_correct"] == 1.0
    fa = rules["px4-others"]["false_alarms"]
    assert fa["exposure_h"] == pytest.approx(
        (min(healthy.baselines[0].exposure_s, 30.0) + px4.exposure_s) / 3600.0)
    assert not math.isnan(fa["per_hour"])
    json.dumps(ev, allow_nan=True)


def test_evaluate_cli_refuses_a_set_that_is_not_imus(tmp_path, capsys):
    from rimu.cli import main
    from studies.synthetic import synthetic_calibration

    cal = synthetic_calibration("cone6")
    cal.save(tmp_path / "c.json")
    rc = main(["evaluate", "--cal", str(tmp_path / "c.json"), "--runs", "2",
               "--baseline", "px4", "--out", str(tmp_path / "ev")])
    assert rc == 2
    assert "not a set of two or more IMUs of three axes" in capsys.readouterr().err
