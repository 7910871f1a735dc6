"""fdi.envelope: each rule fires on its physical condition, never on one sensor's word
alone, holds for ``hold_s``, and gives the same codes whole or in blocks of any size."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fdi.envelope import (
    DECLARED,
    RANGE,
    SATURATION,
    SHOCK,
    TUMBLE,
    DeclaredInterval,
    EnvelopeSettings,
    EnvelopeTracker,
    covered_jolt,
    covered_rate,
    covered_specific_force,
    independent_estimates,
    reason_names,
)
from fdi.errors import ConfigError
from fdi.units import DPS, G0

FS = 50.0
H2 = np.vstack([np.eye(3), np.eye(3)])          # two IMUs, sensors imu1.x..z, imu2.x..z
GROUPS = [(0, 1, 2), (3, 4, 5)]


def _calm(n: int = 500, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """t (s), rates (n, 6) rad/s: one body rate seen by both IMUs plus noise; accel
    (n, 2, 3) m/s²: gravity plus noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    w = np.column_stack([0.3 * np.sin(0.7 * t), 0.2 * np.cos(0.5 * t), 0.1 * np.sin(t)])
    rates = np.hstack([w, w]) + rng.normal(0, 0.3 * DPS, (n, 6))
    acc = np.zeros((n, 2, 3))
    acc[:, :, 2] = G0
    acc += rng.normal(0, 0.3, acc.shape)
    return t, rates, acc


def _run(rates, acc, t=None, s=None, declared=(), H=H2, groups=GROUPS, **kw):
    t = np.arange(rates.shape[0]) / FS if t is None else t
    return EnvelopeTracker(s, H=H, groups=groups, declared=declared, **kw).update(t, rates, acc)


def test_reason_names():
    assert reason_names(0) == ()
    assert reason_names(SHOCK | TUMBLE) == ("shock", "tumble")
    assert reason_names(DECLARED | SATURATION) == ("saturation", "declared")
    assert reason_names(RANGE) == ("range",)
    assert reason_names(32) == ("bit5",)
    assert reason_names("x") == ()        # never raises


@pytest.mark.parametrize("kw", [{"shock_limit_g": float("nan")}, {"hold_s": -1.0},
                                {"gyro_range_dps": 0.0}, {"repeat_samples": 1},
                                {"saturation_fraction": 1.5}, {"tumble_rate_dps": True}])
def test_settings_refuse_bad_values(kw):
    with pytest.raises(ConfigError, match=next(iter(kw))):
        EnvelopeSettings(**kw)


def test_calm_flight_is_inside():
    _t, r, a = _calm()
    assert not _run(r, a).any()


def test_shock_confirmed_by_every_accelerometer_and_held():
    t, r, a = _calm()
    a[200, 0, 2] = 6 * G0              # IMU1 sees 6 g ...
    a[201, 1, 2] = 3 * G0              # ... IMU2 3 g one sample later (within 0.1 s)
    c = _run(r, a)
    on = np.flatnonzero(c & SHOCK)
    assert on[0] == 201                 # causal: marked once confirmed
    # held while both are within the window (0.1 s after 6 g) and then hold_s = 0.5 s
    assert t[on[-1]] == pytest.approx(t[200] + 0.1 + 0.5, abs=1.5 / FS)
    assert not (c & ~SHOCK).any()


def test_one_accelerometer_alone_marks_nothing():
    _t, r, a = _calm()
    a[100:300, 0, :] = 10 * G0         # a broken accelerometer on IMU1
    assert not _run(r, a).any()


def test_tumble_needs_every_imu():
    _t, r, a = _calm()
    r[200:230, 2] = r[200:230, 5] = 600 * DPS          # both IMUs: vehicle spins
    c = _run(r, a)
    assert (c[200:230] & TUMBLE).all()
    _t, r, a = _calm()
    r[200:230, 2] = 600 * DPS                          # one gyro alone reads 600 deg/s
    assert not _run(r, a).any()


def test_disagreement_spike_counts_only_in_a_fast_turn():
    _t, r, a = _calm()
    r[200:260, 2] += 250 * DPS                         # both turn at 250 deg/s ...
    r[200:260, 5] += 250 * DPS
    r[230:233, 5] += 150 * DPS                         # ... and IMU2 jumps by 150
    c = _run(r, a)
    assert (c[230:233] & TUMBLE).all()
    _t, r, a = _calm()
    r[230:233, 5] += 150 * DPS                         # the same jump in calm flight
    assert not _run(r, a).any()


def test_ramp_or_step_fault_in_a_fast_turn_is_not_a_tumble():
    """A ramp's or step's disagreement is absorbed by the slow baseline (after onset)."""
    t, r, a = _calm(3000)
    r[:, 2] += 250 * DPS
    r[:, 5] += 250 * DPS
    r[500:, 5] += np.minimum(0.5 * (t[500:] - t[500]), 80.0) * DPS     # ramp to 80 deg/s
    r[2000:, 4] += 10 * DPS                                             # 10 deg/s step
    assert not _run(r, a).any()


def test_saturation_needs_a_second_estimate_or_a_shock():
    s = EnvelopeSettings(gyro_range_dps=500.0)
    _t, r, a = _calm()
    r[200:220, 2] = 500 * DPS                          # IMU1 z at full scale, IMU2 calm
    assert not _run(r, a, s=s).any()
    r[200:220, 5] = 300 * DPS                          # IMU2 confirms a fast turn
    c = _run(r, a, s=s)
    assert (c[200:220] & SATURATION).all()
    # a single IMU has nothing to confirm with
    c1 = _run(r[:, :3], a[:, :1], s=s, H=np.eye(3), groups=[(0, 1, 2)])
    assert (c1[200:220] & SATURATION).all()


def test_repeated_large_value_is_clipping():
    s = EnvelopeSettings(gyro_range_dps=2000.0, tumble_rate_dps=2000.0)
    _t, r, a = _calm()
    r[200:205, 0] = 900 * DPS                          # clipped at an unknown lower range
    r[200:205, 3] = 899.5 * DPS                        # IMU2 sees the same fast rotation
    c = _run(r, a, s=s)
    assert (c[202:205] & SATURATION).all() and not (c[200:202] & SATURATION).any()


def test_declared_interval_with_hold():
    t, r, a = _calm()
    c = _run(r, a, declared=[DeclaredInterval(2.0, 3.0, "crash"),
                             DeclaredInterval(8.0, math.inf, "to the end")])
    on = (c & DECLARED) != 0
    assert np.array_equal(on, ((t >= 2.0) & (t <= 3.5)) | (t >= 8.0))


def test_bad_numbers_never_raise():
    t, r, a = _calm(50)
    r[3] = np.nan
    r[4] = np.inf
    r[5, 2] = -np.inf
    a[6] = np.nan
    tt = t.copy()
    tt[7] = np.nan
    tt[8] = tt[2]                                      # time goes back
    c = _run(r, a, t=tt)
    assert c.shape == (50,) and c.dtype == np.int64


def test_range_marks_turning_beyond_the_calibrated_rate_on_any_axis_and_holds():
    _t, r, a = _calm(400)
    lim = np.array([30.0, 30.0, 30.0]) * DPS           # calm flight stays below 20 deg/s
    assert not _run(r, a, validated_rate=lim).any()
    r[200:210, 2] = r[200:210, 5] = 40 * DPS           # both IMUs: yaw at 40 deg/s
    c = _run(r, a, validated_rate=lim)
    hold = int(EnvelopeSettings().hold_s * FS)
    on = np.flatnonzero(c & RANGE)
    assert on[0] == 200 and on[-1] == 209 + hold, "range: marked from the first fast sample, held"
    assert not (c & ~RANGE).any()
    # a calibration that states no range marks nothing
    assert not _run(r, a).any()


def test_range_is_not_raised_by_one_sensor_alone():
    _t, r, a = _calm(300)
    r[100:200, 5] = 300 * DPS                          # imu2.z fails high
    c = _run(r, a, validated_rate=np.full(3, 30 * DPS))
    assert not (c & RANGE).any(), "one faulty gyro must not take the set out of the envelope"


def test_range_on_specific_force_needs_every_imu():
    _t, r, a = _calm(300)
    a[100:105, 0, 2] = 3.0 * G0                        # one accelerometer alone
    assert not _run(r, a, validated_specific_force=2.5 * G0).any()
    a[100:105, 1, 2] = 3.0 * G0                        # both: beyond what was calibrated
    c = _run(r, a, validated_specific_force=2.5 * G0)
    assert (c[100:105] & RANGE).all() and not (c & SHOCK).any()


def test_covered_range_is_what_the_used_samples_reached():
    _t, r, a = _calm(300)
    r[50, 0] = r[50, 3] = 80 * DPS                     # seen by both: covered
    r[60, 1] = 200 * DPS                               # one sensor only: not covered
    r[70, 2] = r[70, 5] = 90 * DPS                     # both, but not a used sample
    used = np.ones(300, bool)
    used[70] = False
    cov = covered_rate(H2, GROUPS, r, used)
    floor = np.min(np.abs(np.stack([r[:, :3], r[:, 3:]])), axis=0)[used]
    np.testing.assert_allclose(cov, floor.max(axis=0), err_msg="covered rate")
    assert cov[0] == pytest.approx(80 * DPS) and cov[1] < 20 * DPS and cov[2] < 20 * DPS
    a[40, :, 2] = 2.2 * G0
    a[41, 0, 2] = 5 * G0
    f = covered_specific_force(a, used)
    assert f == pytest.approx(float(np.min(np.linalg.norm(a[40], axis=1))))
    # the tracker marks nothing on the samples the range came from
    assert not (_run(r[used], a[used], validated_rate=cov,
                     validated_specific_force=f) & RANGE).any()


def test_range_settings_refuse_bad_values():
    with pytest.raises(ConfigError, match="validated_rate"):
        EnvelopeTracker(H=H2, validated_rate=[1.0, -1.0, 1.0])
    with pytest.raises(ConfigError, match="validated_specific_force"):
        EnvelopeTracker(H=H2, validated_specific_force=float("nan"))
    with pytest.raises(ConfigError, match="validated_jolt"):
        EnvelopeTracker(H=H2, validated_jolt=-1.0)


def test_jolt_beyond_the_covered_one_needs_every_imu():
    """A knock: the specific force of every IMU jumps from one sample to the next by more
    than the calibration covered (RANGE, for hold_s); one accelerometer alone jumping does
    not take the set out of the envelope; the covered jolt of the calm samples is what the
    smallest jump over the IMUs reached, and marks nothing on them."""
    _t, r, a = _calm(300)
    j = covered_jolt(a)
    d = np.min(np.linalg.norm(np.diff(a, axis=0), axis=2), axis=1)
    assert j == pytest.approx(float(d.max())), "covered jolt"
    assert not (_run(r, a, validated_jolt=j) & RANGE).any()
    one = a.copy()
    one[150, 0, 0] += 20.0                             # imu1's accelerometer alone
    assert not (_run(r, one, validated_jolt=j) & RANGE).any()
    knock = a.copy()
    knock[150, :, 0] += 20.0 * j                       # both IMUs: a knock
    c = _run(r, knock, validated_jolt=j)
    assert (c[150] & RANGE) and not (c[:150] & RANGE).any() and not (c & SHOCK).any()
    hold = EnvelopeSettings().hold_s
    t = np.arange(300) / FS
    assert ((c & RANGE) != 0).sum() == int(np.sum((t >= t[150]) & (t <= t[151] + hold)))
    used = np.ones(300, bool)
    used[150:152] = False                              # left out: not covered
    assert covered_jolt(knock, used) == pytest.approx(j)


def test_leave_one_out_estimates_for_an_ungrouped_set():
    H = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]]) / np.array(
        [[1], [1], [1], [math.sqrt(3)]])
    est = independent_estimates(H, None)
    assert len(est) == 4 and all(len(g) == 3 for g in est)
    # one sensor reading 800 deg/s cannot make a tumble: the estimate without it is calm
    rates = np.zeros((10, 4))
    rates[:, 3] = 800 * DPS
    assert not _run(rates, None, H=H, groups=None).any()


@settings(max_examples=30, deadline=None)
@given(cuts=st.lists(st.integers(1, 599), max_size=12, unique=True))
def test_blocks_of_any_size_give_identical_codes(cuts):
    t, r, a = _calm(600, seed=3)
    r[100:140, 2] = r[100:140, 5] = 450 * DPS          # tumble
    r[120:122, 5] += 200 * DPS                         # disagreement spike in it
    a[300, 0, 0] = 5 * G0                              # confirmed shock
    a[302, 1, 0] = 2.5 * G0
    r[400:404, 1] = r[400:404, 4] = 1950 * DPS         # saturation, confirmed
    r[450:455, 0] = 700 * DPS                          # clipping of one sensor (repeat)
    r[450:455, 3] = 1200 * DPS
    dec = [DeclaredInterval(9.0, 9.2, "x")]
    rng_kw = {"validated_rate": np.array([100, 100, 300]) * DPS,
              "validated_specific_force": 2.0 * G0, "validated_jolt": 3.0}
    a[500, :, 1] += 5.0                                # a knock every IMU feels: jolt
    whole = _run(r, a, t=t, declared=dec, **rng_kw)
    assert (whole & SHOCK).any() and (whole & TUMBLE).any() and (whole & SATURATION).any()
    assert (whole & RANGE).any()
    tr = EnvelopeTracker(H=H2, groups=GROUPS, declared=dec, **rng_kw)
    edges = [0, *sorted(cuts), 600]
    parts = [tr.update(t[i:j], r[i:j], a[i:j]) for i, j in itertools.pairwise(edges)]
    assert np.array_equal(np.concatenate(parts), whole)


_BAD = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=64),
                 st.sampled_from([0.0, 1e308, -1e308, 35.0, -35.0]))


@settings(max_examples=60, deadline=None)
@given(data=st.data(), b=st.integers(1, 12))
def test_any_numbers_never_raise(data, b):
    """The runtime never raises on bad numbers: NaN, inf, huge, in times, rates, accel."""
    t = np.array(data.draw(st.lists(_BAD, min_size=b, max_size=b)))
    r = np.array(data.draw(st.lists(_BAD, min_size=6 * b, max_size=6 * b))).reshape(b, 6)
    a = np.array(data.draw(st.lists(_BAD, min_size=6 * b, max_size=6 * b))).reshape(b, 2, 3)
    tr = EnvelopeTracker(H=H2, groups=GROUPS, declared=[DeclaredInterval(0.0, 1.0)],
                         validated_rate=np.full(3, 0.5), validated_specific_force=15.0,
                         validated_jolt=1.0)
    for _ in range(2):
        c = tr.update(t, r, a)
        assert c.shape == (b,) and c.dtype == np.int64 and np.all((c >= 0) & (c < 32))
