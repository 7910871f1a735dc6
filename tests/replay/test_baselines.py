"""The autopilot baselines (replay.baselines): each rule against an independent computation
of the description in docs/baselines.md, the streaming and block forms equal, the two-IMU
and primary caveats, the validator's stale and timeout rules, and the CLI's --baseline."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.signal import lfilter

from fdi.errors import ConfigError
from fdi.units import DPS
from replay.baselines import (
    ArduPilotConsistency,
    PX4Selector,
    PX4Settings,
    Triads,
    ardupilot_consistency,
    parse_baselines,
    px4_selector,
    triads_from_flight,
)
from replay.baselines.ardupilot import ARMING_ACCTHRESH_MPS2, ArduPilotSettings
from replay.baselines.px4 import EKF2_SEL_IMU_ANG_DEG, EKF2_SEL_IMU_RAT_DPS


def _triads(k=3, N=3000, fs=100.0, seed=0, noise_dps=0.3, kind="gyro"):
    rng = np.random.default_rng(seed)
    t = np.arange(N) / fs
    body = np.column_stack([np.sin(0.7 * t), np.cos(0.3 * t), 0.5 * np.sin(1.1 * t)])
    x = body[:, None, :] + noise_dps * DPS * rng.standard_normal((N, k, 3))
    return Triads(t=t, values=x, valid=np.ones((N, k), bool),
                  imus=tuple(f"imu{j + 1}" for j in range(k)), kind=kind,
                  sensors=tuple(tuple(range(3 * j, 3 * j + 3)) for j in range(k)))


def _with(tri, values=None, valid=None):
    return Triads(tri.t, tri.values if values is None else values,
                  tri.valid if valid is None else valid, tri.imus, tri.kind, tri.sensors)


def _px4_reference(t, x, mean_of="all", keep=0.95, rate=7 * DPS):
    """The selector's accumulated error, computed another way: lfilter for the low-pass,
    a plain loop for the clamped integral."""
    k = x.shape[1]
    s = x.sum(axis=1, keepdims=True)
    ref = s / k if mean_of == "all" else (s - x) / (k - 1)
    lp = lfilter([1.0 - keep], [1.0, -keep], x - ref, axis=0)
    inc = np.linalg.norm(lp, axis=2)
    acc = np.zeros_like(inc)
    dt = np.diff(t, prepend=t[0])
    for r in range(1, t.size):
        acc[r] = np.maximum(0.0, acc[r - 1] + (inc[r] - rate) * dt[r])
    return acc


@pytest.mark.parametrize("mean_of", ["all", "others"])
def test_px4_accumulated_error_matches_an_independent_computation(mean_of):
    tri = _triads()
    x = tri.values.copy()
    x[1000:, 1, 1] += 20 * DPS                     # 20 deg/s step on imu2.y at t = 10 s
    res = px4_selector(_with(tri, x), PX4Settings.defaults("gyro", mean_of=mean_of))
    acc = _px4_reference(tri.t, x, mean_of) / DPS
    np.testing.assert_allclose(res.measure, acc, rtol=1e-9, atol=1e-9)
    # the fault is declared where the largest accumulator first passes 15 deg, imu2 blamed
    first = int(np.flatnonzero(acc.max(axis=1) > EKF2_SEL_IMU_ANG_DEG)[0])
    ev = res.first_flag()
    assert ev is not None and ev.t == pytest.approx(tri.t[first]) and ev.imu == "imu2"
    assert res.flagged[first] and not res.flagged[first - 1]


def test_px4_below_the_rate_threshold_never_flags():
    """A 10 deg/s step on one of three IMUs is 6.7 deg/s from the mean of all three: below
    the 7 deg/s threshold, PX4's rule never sees it; against the mean of the others (10 deg/s)
    it accumulates 3 deg/s and flags after about 15 / 3 = 5 s (plus the filter's lag)."""
    tri = _triads(N=3000)
    x = tri.values.copy()
    x[1000:, 2, 0] += 10 * DPS
    assert px4_selector(_with(tri, x)).first_flag() is None
    ev = px4_selector(_with(tri, x), PX4Settings.defaults(mean_of="others")).first_flag()
    assert ev is not None and ev.imu == "imu3"
    assert 5.0 < ev.t - 10.0 < 5.0 + 0.5        # lag of the 0.95 filter: ~20 samples


def test_px4_two_imus_flag_without_blame():
    tri = _triads(k=2)
    x = tri.values.copy()
    x[500:, 0, 2] += 40 * DPS
    res = px4_selector(_with(tri, x))
    ev = res.first_flag()
    assert ev is not None and ev.imu is None and "two IMUs" in ev.reason
    assert (res.blamed == -1).all()


def test_px4_validator_stale_blames_even_with_two_imus():
    tri = _triads(k=2)
    x = tri.values.copy()
    x[1000:, 1, :] = x[999, 1, :]                  # frozen: the exact same value repeats
    res = px4_selector(_with(tri, x))
    ev = res.first_flag()
    # three equal components per sample: the count passes 100 at the 34th repeat, row 1033
    assert ev is not None and ev.imu == "imu2" and ev.reason == "validator: stale"
    assert ev.t == pytest.approx(tri.t[1033])
    # one frozen axis among moving ones resets the count at every sample: never stale
    x = tri.values.copy()
    x[1000:, 1, 0] = x[999, 1, 0]
    ev = px4_selector(_with(tri, x)).first_flag()
    assert ev is None or ev.reason != "validator: stale"


def test_px4_validator_timeout_only_where_the_log_rate_allows():
    tri = _triads(k=3, N=3000, fs=1000.0)
    ok = tri.valid.copy()
    ok[1500:1530, 0] = False                       # imu1 silent 30 ms while the others speak
    res = px4_selector(_with(tri, valid=ok))
    ev = res.first_flag()
    assert ev is not None and ev.imu == "imu1" and ev.reason == "validator: timeout"
    # the first sample more than 20 ms after imu1's last one (t[1499])
    assert ev.t == pytest.approx(tri.t[1499 + 21])
    slow = _triads(k=3, fs=50.0)                   # 20 ms period: the timeout is left out
    ok = slow.valid.copy()
    ok[100:110, 0] = False
    res = px4_selector(_with(slow, valid=ok))
    assert res.first_flag() is None
    assert any(x.startswith("validator timeout") for x in res.left_out)
    # every IMU silent together is the logger's gap, not a sensor's timeout
    ok = tri.valid.copy()
    ok[1500:1530, :] = False
    assert px4_selector(_with(tri, valid=ok)).first_flag() is None


def _random_stream(seed):
    tri = _triads(k=4, N=1500, seed=seed)
    rng = np.random.default_rng(seed + 100)
    x = tri.values.copy()
    x[400:, 1, 0] += 30 * DPS
    x[900:1200, 3, :] = x[899, 3, :]
    ok = rng.random(tri.valid.shape) > 0.002      # a few single missing samples
    x[~ok] = np.nan
    t = tri.t.copy()
    t[700:] += 2.0                                  # a log gap: the filters restart
    return t, x, ok, tri.imus


@pytest.mark.parametrize("rule", ["px4", "ardupilot"])
def test_step_and_block_forms_are_equal(rule):
    t, x, ok, imus = _random_stream(3)

    def make():
        return PX4Selector(imus) if rule == "px4" else ArduPilotConsistency(imus)

    block = make().run(t, x, ok)
    s = make()
    answers = [s.step(t[r], x[r], ok[r]) for r in range(t.size)]
    flag = np.array([a.flagged for a in answers])
    blame = np.array([a.blamed for a in answers])
    meas = np.array([a.accumulated * (1.0 / DPS) if rule == "px4" else a.ratio for a in answers])
    np.testing.assert_array_equal(flag, block.flagged)
    np.testing.assert_array_equal(blame, block.blamed)
    np.testing.assert_array_equal(meas, block.measure)
    assert tuple(e for a in answers for e in a.events) == block.events
    assert len(block.events) >= 2
    # blocks of any cut give the same answers too
    s = make()
    parts = [s.run(t[a:b], x[a:b], ok[a:b]) for a, b in ((0, 333), (333, 334), (334, None))]
    np.testing.assert_array_equal(np.concatenate([p.flagged for p in parts]), block.flagged)
    assert tuple(e for p in parts for e in p.events) == block.events


def test_ardupilot_matches_an_independent_computation():
    tri = _triads(k=3)
    x = tri.values.copy()
    x[1000:1200, 2, 1] += 6 * DPS                  # 6 deg/s on imu3.y for 2 s
    res = ardupilot_consistency(_with(tri, x))
    d = np.linalg.norm(x[:, 1:] - x[:, :1], axis=2) / (5 * DPS)
    np.testing.assert_allclose(res.measure[:, 1:], d, rtol=1e-12)
    bad = (d > 1).any(axis=1)
    last = np.where(bad, tri.t, -np.inf)
    last = np.maximum.accumulate(last)
    want = tri.t - last < 10.0
    np.testing.assert_array_equal(res.flagged, want)
    on = res.first_flag()
    assert on is not None and on.imu == "imu3" and on.t == pytest.approx(10.0)
    off = next(e for e in res.events if e.type == "cleared")
    assert off.t == pytest.approx(tri.t[int(np.flatnonzero(bad)[-1])] + 10.0, abs=0.011)


def test_ardupilot_accelerometer_rules():
    """z difference halved; threshold tripled from the third IMU."""
    tri = _triads(k=3, kind="accel", noise_dps=0.0)
    x = tri.values.copy() * 0.0 + 9.8
    a = ARMING_ACCTHRESH_MPS2
    x[:, 1, 2] += 1.9 * a                            # imu2 z: halved to 0.95·a: consistent
    x[:, 2, 0] += 2.9 * a                            # imu3 x: below 3·a: consistent
    assert ardupilot_consistency(_with(tri, x)).first_flag() is None
    x[100:, 1, 0] += 1.1 * a                         # imu2 x beyond a
    ev = ardupilot_consistency(_with(tri, x)).first_flag()
    assert ev is not None and ev.imu == "imu2" and ev.t == pytest.approx(tri.t[100])
    assert ArduPilotSettings.defaults("accel").autopilot_units("accel")[
        "ARMING_ACCTHRESH_m_s2"] == a


def test_ardupilot_never_names_the_primary():
    """A fault of IMU 1 (the primary) makes every other IMU inconsistent: the check names
    IMU 2, as ArduPilot's does; with two IMUs it names nobody."""
    tri = _triads(k=3)
    x = tri.values.copy()
    x[500:, 0, 0] += 8 * DPS
    ev = ardupilot_consistency(_with(tri, x)).first_flag()
    assert ev is not None and ev.imu == "imu2"
    tri2 = _triads(k=2)
    x = tri2.values.copy()
    x[500:, 0, 0] += 8 * DPS
    ev = ardupilot_consistency(_with(tri2, x)).first_flag()
    assert ev is not None and ev.imu is None


def test_never_raises_on_bad_numbers():
    tri = _triads(k=3, N=400)
    x = tri.values.copy()
    x[50:60, 1] = np.nan
    x[70, 2] = np.inf
    x[80, 0] = 1e300
    for fn in (px4_selector, ardupilot_consistency):
        r = fn(_with(tri, x))
        assert r.flagged.shape == (400,) and np.isfinite(r.measure[:, 0]).any()


def test_settings_in_autopilot_units():
    s = PX4Settings.defaults("gyro")
    assert s.rate_threshold == pytest.approx(EKF2_SEL_IMU_RAT_DPS * DPS)
    u = s.autopilot_units("gyro")
    assert u["EKF2_SEL_IMU_RAT_deg_s"] == pytest.approx(7.0)
    assert u["EKF2_SEL_IMU_ANG_deg"] == pytest.approx(15.0)
    with pytest.raises(ConfigError, match="mean_of"):
        PX4Settings.defaults("gyro", mean_of="primary")


def test_parse_baselines():
    assert parse_baselines("px4, ardupilot") == ("px4", "ardupilot")
    assert parse_baselines("all") == ("px4", "px4-others", "ardupilot")
    assert parse_baselines(None) == ()
    with pytest.raises(ConfigError, match=r"unknown.*px4, px4-others, ardupilot"):
        parse_baselines("px4,betaflight")


def test_triads_from_flight_and_refusal():
    from replay.imu_set import ImuSetSpec, simulate_imu_set

    f = simulate_imu_set(ImuSetSpec(imus=3, duration_s=5.0, seed=2))
    tri = triads_from_flight(f)
    assert tri.imus == ("imu1", "imu2", "imu3") and tri.values.shape == (250, 3, 3)
    assert tri.imu_of_sensor(5) == 1 and tri.how == "as logged"
    np.testing.assert_array_equal(tri.values[:, 2, :], f.raw[:, 6:9])
    from dataclasses import replace

    bad = replace(f, raw=f.raw[:, :8], valid=f.valid[:, :8],
                  sensor_names=f.sensor_names[:8], imu=f.imu[:8])
    with pytest.raises(ConfigError, match="two or more IMUs of three axes"):
        triads_from_flight(bad)


def test_monitor_file_baseline_cli(tmp_path, capsys):
    """rimu monitor-file --baseline on a simulated three-IMU flight with a stuck IMU: the
    text, the JSON block and the plot say when each rule flagged and whom it blamed."""
    from calibration.inflight import calibration_from_fit, fit_inflight
    from replay.faults import Fault
    from replay.flight import save_flight_dir
    from replay.imu_set import ImuSetSpec, simulate_imu_set
    from replay.scenario import inject
    from rimu.cli import main

    f = simulate_imu_set(ImuSetSpec(imus=3, duration_s=40.0, seed=5, max_rate_dps=60.0))
    cal = calibration_from_fit(fit_inflight(f), f)
    cal_path = tmp_path / "cal.json"
    cal.save(cal_path)
    faults = tuple(Fault("stuck", s, 0.0, 20.0, None, f"stuck:{s}::20") for s in (4, 5, 6))
    faulty = inject(f, faults, cal)           # imu2 frozen whole
    save_flight_dir(faulty, tmp_path / "flight")
    rc = main(["monitor-file", str(tmp_path / "flight"), "--cal", str(cal_path),
               "--baseline", "px4,ardupilot", "--baseline-plot", str(tmp_path / "b.png"),
               "--report", str(tmp_path / "r.json")])
    out = capsys.readouterr().out
    assert rc == 0
    assert "baselines on the same samples" in out and "fault stuck:4::20 (imu2)" in out
    rep = json.loads((tmp_path / "r.json").read_text())
    b = rep["baselines"]
    assert b["schema"] == "rimu.baselines/1" and [r["name"] for r in b["results"]] == [
        "px4", "ardupilot"]
    row = b["faults"][0]
    # PX4's validator: the frozen IMU is stale after 34 repeats (0.68 s at 50 Hz), imu2
    assert row["px4"]["blamed"] == "imu2" and row["px4"]["blame_correct"] is True
    assert row["px4"]["detection_delay_s"] == pytest.approx(34 / 50.0, abs=0.025)
    assert "rimu" in row and set(row["rimu"]) >= {"detected", "blamed"}
    assert (tmp_path / "b.png").stat().st_size > 10_000
    assert not math.isnan(rep["duration_s"])


def test_monitor_file_baseline_plot_needs_baseline(tmp_path, capsys):
    from rimu.cli import main

    rc = main(["monitor-file", str(tmp_path), "--cal", str(tmp_path / "c.json"),
               "--baseline-plot", str(tmp_path / "b.png")])
    assert rc == 2


def test_a_mounting_far_from_the_logged_axes_is_rotated():
    """An IMU mounted 90° about z (its rows of H̃ say so) is read through that rotation, as an
    autopilot user would configure it; a mounting within 10° is read as logged."""
    from dataclasses import replace
    from types import SimpleNamespace

    from replay.imu_set import ImuSetSpec, simulate_imu_set

    f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=4.0, seed=3))
    Rz = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])   # u = Rz·ω
    raw = f.raw.copy()
    raw[:, 3:6] = f.raw[:, 3:6] @ Rz.T
    g = replace(f, raw=raw)
    H = np.vstack([np.eye(3), Rz])
    cal = SimpleNamespace(kind=lambda kind: SimpleNamespace(H=H))
    tri = triads_from_flight(g, cal)
    np.testing.assert_allclose(tri.values[:, 1], f.raw[:, 3:6], atol=1e-12)
    assert "imu2 rotated" in tri.how
    small = np.vstack([np.eye(3), np.eye(3) + 0.05 * np.array([[0, -1, 0], [1, 0, 0],
                                                                [0, 0, 0]])])
    tri = triads_from_flight(f, SimpleNamespace(kind=lambda kind: SimpleNamespace(H=small)))
    assert tri.how == "as logged"
    np.testing.assert_array_equal(tri.values[:, 1], f.raw[:, 3:6])
