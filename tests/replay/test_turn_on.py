"""The turn-on bias on a new flight: the rest stretch, the estimate, the bound (issue 27)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fdi.errors import ConfigError
from fdi.units import DPS
from replay.flight_data import AuxChannels, Flight
from replay.turn_on import (
    DEFAULT_BIAS_BOUND_DPS,
    apply_turn_on,
    find_rest,
    turn_on_for_flight,
)
from studies.synthetic import synthetic_calibration

CAL = synthetic_calibration("cone6")
FS = CAL.sample_rate_hz


def _flight(rest_s: float, move_s: float, *, turn_on_dps: np.ndarray, seed: int = 0,
            accel: bool = True, noise_dps: float | None = 0.3) -> Flight:
    """Raw outputs of CAL's sensors: ``rest_s`` still (only the turn-on bias and noise), then
    a manoeuvre of 40-60 °/s per axis; with ``accel``, one accelerometer triad that reads
    1 g plus noise at rest and swings in the manoeuvre."""
    s = CAL.gyro
    rng = np.random.default_rng(seed)
    N0, N1 = round(rest_s * FS), round(move_s * FS)
    t = np.arange(N0 + N1) / FS
    w = np.zeros((t.size, 3))
    tm = t[N0:] - t[N0]
    w[N0:] = np.stack([40 * np.sin(2 * np.pi * 0.5 * tm), 60 * np.sin(2 * np.pi * 0.3 * tm),
                       50 * np.sin(2 * np.pi * 0.2 * tm)], axis=1) * DPS
    sd = s.noise_sd if noise_dps is None else noise_dps * DPS      # None: the calibration's
    y = w @ s.H.T + s.biases + turn_on_dps * DPS + rng.normal(size=(t.size, s.n)) * sd
    raw = y / s.scale_factors
    aux = None
    if accel:
        a = np.tile([0.0, 0.0, -9.81], (t.size, 1)) + rng.normal(0, 0.05, (t.size, 3))
        a[N0:] += 3.0 * np.sin(2 * np.pi * 1.0 * tm)[:, None]
        aux = AuxChannels(("accel",) * 3, ("imu.x", "imu.y", "imu.z"), ("imu",) * 3, a,
                          np.ones_like(a, bool))
    return Flight(t=t, raw=raw, valid=np.ones_like(raw, bool), sample_rate_hz=FS,
                  sensor_names=tuple(c.name for c in s.sensors), aux=aux)


TURN_ON = np.array([0.8, -0.5, 0.3, 0.0, -1.2, 0.6])


@pytest.mark.parametrize("accel", [True, False])
def test_rest_stretch_found_before_take_off_and_bias_recovered(accel):
    fl = _flight(8.0, 20.0, turn_on_dps=TURN_ON, accel=accel)
    ton = turn_on_for_flight(fl, CAL, mode="rest")
    assert ton.method == "rest"
    st = ton.stretch
    assert st.t0_s == pytest.approx(0.0, abs=1.01) and 6.0 <= st.t1_s <= 8.0
    assert st.takeoff_s == pytest.approx(8.0, abs=1.01)
    assert st.judged_on == ("gyros and accelerometers" if accel else "gyros")
    shift = np.asarray(ton.shift) / DPS
    sd = np.asarray(ton.bias_sd) / DPS
    # the estimate is the turn-on bias within 4 of its stated sd, and that sd is the
    # white-noise sd of a mean of the stretch (0.3 deg/s over ~350 samples) or more
    assert np.all(np.abs(shift - TURN_ON) < 4 * sd), (shift, sd)
    assert np.all(sd >= 0.3 / np.sqrt(st.samples) * 0.8)
    cal = apply_turn_on(CAL, ton)
    assert np.allclose(cal.gyro.biases, ton.bias)
    assert [c.bias_sd for c in cal.gyro.sensors] == list(ton.bias_sd)


def test_a_log_that_starts_moving_gets_the_bound_and_says_which():
    fl = _flight(0.0, 20.0, turn_on_dps=TURN_ON)
    ton = turn_on_for_flight(fl, CAL, mode="rest")
    assert ton.method == "bound" and ton.stretch is None
    assert np.allclose(ton.bound, DEFAULT_BIAS_BOUND_DPS * DPS)
    assert "default" in ton.bound_source and "--bias-bound-dps" in ton.bound_source
    given = turn_on_for_flight(fl, CAL, mode="rest", bias_bound_dps=0.25)
    assert np.allclose(given.bound, 0.25 * DPS) and "--bias-bound-dps" in given.bound_source
    s = CAL.gyro
    spread = replace(CAL, sets={**CAL.sets, "gyro": replace(s, sensors=tuple(
        replace(c, bias_turn_on_sd=0.1 * DPS) for c in s.sensors))}) \
        if hasattr(s.sensors[0], "bias_turn_on_sd") else None
    if spread is not None:
        b = turn_on_for_flight(fl, spread, mode="auto")
        assert np.allclose(b.bound, 0.3 * DPS) and "bias_turn_on_sd" in b.bound_source


def test_short_or_shaken_rest_is_not_a_rest_stretch():
    """One second of rest is too short; a rest whose gyros wander (a slow turn of 2 °/s
    changing direction) is not still."""
    fl = _flight(1.0, 20.0, turn_on_dps=TURN_ON)
    assert turn_on_for_flight(fl, CAL, mode="rest").method == "bound"
    fl = _flight(8.0, 20.0, turn_on_dps=TURN_ON, accel=False)
    t = fl.t
    wander = 2.0 * DPS * np.sin(2 * np.pi * t / 3.0)[:, None] * CAL.gyro.H[:, :1].T
    shaken = replace(fl, raw=fl.raw + wander / CAL.gyro.scale_factors)
    assert find_rest(shaken.t, shaken.raw * CAL.gyro.scale_factors - CAL.gyro.biases,
                     None, CAL.gyro.H, FS) is None


def test_auto_leaves_a_turntable_calibration_as_calibrated_and_modes_are_checked():
    fl = _flight(8.0, 20.0, turn_on_dps=TURN_ON)
    ton = turn_on_for_flight(fl, CAL)
    assert ton.method == "calibrated" and "records no flight" in ton.reason
    assert apply_turn_on(CAL, ton) is CAL
    assert turn_on_for_flight(fl, CAL, mode="off").method == "calibrated"
    with pytest.raises(ConfigError, match="--turn-on"):
        turn_on_for_flight(fl, CAL, mode="sometimes")
    with pytest.raises(ConfigError, match="--bias-bound-dps"):
        turn_on_for_flight(_flight(0.0, 5.0, turn_on_dps=TURN_ON), CAL, mode="bound",
                           bias_bound_dps=float("nan"))


def test_chain_monitors_with_the_rest_estimate_and_reports_it():
    """A turn-on bias of up to 1.2 °/s on a turntable-calibrated set: as calibrated the
    monitor alarms at once; with the rest estimate (``--turn-on rest``) it stays quiet on
    the healthy flight, and the report says what it did."""
    from replay.chain import ChainOptions, chain_for_flight, run_flight

    fl = _flight(8.0, 30.0, turn_on_dps=TURN_ON, noise_dps=None)
    quiet = {}
    for mode in ("off", "rest"):
        ch = chain_for_flight(fl, CAL, ChainOptions(false_alarms_per_hour=1.0, turn_on=mode,
                                                    envelope=False))
        res, rep = run_flight(ch, fl)
        quiet[mode] = not any(e.type == "detected" for e in res.events)
        assert rep["extra"]["turn_on_bias"]["method"] == ("calibrated" if mode == "off"
                                                          else "rest") \
            if "extra" in rep else True
    assert quiet == {"off": False, "rest": True}


def test_auto_without_measured_spread_or_given_bound_keeps_the_calibrated_biases(monkeypatch):
    """No rest stretch, no ``bias_turn_on_sd``, no ``--bias-bound-dps``: ``auto`` does not
    guess a bound (it would raise the thresholds by the fault sizes they must see); the
    reason says how to cover the spread. Asked for (``mode="bound"``) the default applies."""
    import replay.turn_on as turn_on

    # a calibration of another flight: not the same power-up
    monkeypatch.setattr(turn_on, "same_power_up", lambda cal, flight: False)
    fl = _flight(0.0, 20.0, turn_on_dps=TURN_ON)
    ton = turn_on_for_flight(fl, CAL, mode="auto")
    assert ton.method == "calibrated", ton
    assert "no measured run-to-run bias spread" in ton.reason and "--bias-bound-dps" in ton.reason
    bound = turn_on_for_flight(fl, CAL, mode="bound")
    assert bound.method == "bound" and np.allclose(bound.bound, DEFAULT_BIAS_BOUND_DPS * DPS)
    given = turn_on_for_flight(fl, CAL, mode="auto", bias_bound_dps=0.25)
    assert given.method == "bound" and np.allclose(given.bound, 0.25 * DPS)


def test_same_file_name_in_another_folder_is_another_power_up():
    """Every Xsens DOT path is IMU_1.csv ... IMU_4.csv and autopilots number their logs
    from 1 on every card: a file name and times inside the calibrated flight's do not make
    a part of the same log; the whole source does; several flights together are none's."""
    from calibration.inflight.calfile import calibration_from_fit
    from calibration.inflight.fit import fit_inflight
    from replay.imu_set import ImuSetSpec, simulate_imu_set
    from replay.turn_on import same_power_up
    from studies.cross_flight import calibrate_together

    def sim(seed: int, source: str) -> Flight:
        f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=8.0, seed=seed,
                                        max_rate_dps=150))
        return replace(f, source=source)

    a, b = sim(1, "/logs/card1/00000001.BIN"), sim(2, "/logs/card2/00000001.BIN")
    fa, fb = fit_inflight(a, check=False), fit_inflight(b, check=False)
    cal = calibration_from_fit(fa, a, tails=False)
    n = a.t.shape[0] // 2
    part = replace(a, t=a.t[n:], raw=a.raw[n:], valid=a.valid[n:],
                   aux=a.aux.slice(slice(n, None)) if a.aux is not None else None,
                   omega_true=None if a.omega_true is None else a.omega_true[n:])
    assert same_power_up(cal, a) is True
    assert same_power_up(cal, part) is True
    other = replace(b, t=b.t[n:], raw=b.raw[n:], valid=b.valid[n:],
                    aux=b.aux.slice(slice(n, None)) if b.aux is not None else None,
                    omega_true=None if b.omega_true is None else b.omega_true[n:])
    assert same_power_up(cal, other) is False
    joint = calibrate_together([a, b], [fa, fb])
    assert same_power_up(joint, a) is False
