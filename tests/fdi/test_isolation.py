"""Statistical isolation: the decision's wrong-exclusion risk, verified exclusion, what a set
of nearly aligned triads can and cannot tell apart, suspects and unverified axes, the
operating envelope in the monitor. Truth from simulation (studies.synthetic)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy import stats

from fdi.capability import capability_report
from fdi.isolation import decide, rejection_level
from fdi.monitor import Monitor
from fdi.settings import MonitorSettings
from fdi.units import DPS
from studies.synthetic import draw_truth, raw_samples, synthetic_calibration

FS = 100.0


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix about a unit axis (Rodrigues)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def triads(tmp_path, k: int, angle_deg: float = 1.0, seed: int = 0):
    """A configuration of k triads, each rotated ``angle_deg`` about a random axis from the
    first (IMUs on one board), and its synthetic calibration."""
    rng = np.random.default_rng(seed)
    lines = ['schema = "rimu.configuration/1"', f'name = "triads{k}"']
    for j in range(k):
        R = np.eye(3) if j == 0 else _rot(rng.standard_normal(3), math.radians(angle_deg))
        for a, axis in enumerate(R.T if j else np.eye(3)):
            x, y, z = (float(v) for v in axis)
            lines += ["[[sensors]]", f'name = "imu{j + 1}.{"xyz"[a]}"',
                      f"axis = [{x!r}, {y!r}, {z!r}]", f"group = {j}"]
    p = tmp_path / f"triads{k}.toml"
    p.write_text("\n".join(lines) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cal = synthetic_calibration(str(p), seed=seed, misalignment_rad=0.0)
    return cal


def rates(N: int, seed: int, amp: float = 0.5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(N) / FS
    f = rng.uniform(0.05, 0.5, 3)
    return amp * np.sin(2 * np.pi * f[None, :] * t[:, None] + rng.uniform(0, 6, 3)[None, :])


def flight(cal, N: int, faults, seed: int):
    """(t, raw): faults = [(sensor 1-based, onset row, size rad/s)] as steps."""
    n = cal.gyro.n
    f = np.zeros((N, n))
    for s, row, size in faults:
        f[row:, s - 1] += size
    raw = raw_samples(cal, rates(N, seed), seed=seed + 1,
                      truth=draw_truth(cal, seed=seed + 2), fault=f)
    return np.arange(N) / FS, raw


# -- the decision ------------------------------------------------------------------------
@pytest.mark.parametrize("df,m", [(3, 6), (6, 9)])
def test_residual_of_the_true_hypothesis_is_chi2_whatever_the_fault_size(df, m):
    """Under H_j the residual r_j is χ²(df − 1) for any bias size: the rate at which j's
    hypothesis is wrongly rejected is P_we/(m − 1) (binomial 99.9 % interval over 20000
    draws at P_we = 0.1, fault sizes up to 1e4 σ)."""
    rng = np.random.default_rng(df * 10 + m)
    P = 0.1
    draws, rejected = 20000, 0
    for _ in range(draws):
        U = rng.standard_normal((df, m))
        j = int(rng.integers(m))
        b = 10 ** rng.uniform(-1, 4)
        s = b * U[:, j] + rng.standard_normal(df)
        dec = decide(U, s, 1.0, P, np.inf)
        rejected += j not in dec.consistent
    p = P / (m - 1)
    lo, hi = stats.binom.interval(0.999, draws, p)
    assert lo <= rejected <= hi, (rejected, draws * p)


def test_exclusion_needs_every_other_hypothesis_rejected_and_the_subset_to_pass():
    U = np.array([[1.0, 0.0, 0.7], [0.0, 1.0, 0.7]])
    dec = decide(U, np.array([50.0, 0.0]), 1.0, 1e-6, 10.0)      # clearly sensor 0
    assert dec.exclude == 0 and dec.consistent == (0,)
    dec = decide(U, np.array([50.0, 50.0]), 1.0, 1e-6, 10.0)     # along column 2
    assert dec.exclude == 2
    dec = decide(U, np.array([50.0, -50.0]), 1.0, 1e-6, 10.0)    # no single sensor fits
    assert dec.exclude is None and dec.consistent == ()
    dec = decide(U, np.array([3.0, 0.0]), 1.0, 1e-6, 10.0)       # too little evidence
    assert dec.exclude is None and len(dec.consistent) > 1
    dec = decide(U, np.array([np.nan, 0.0]), 1.0, 1e-6, 10.0)    # bad numbers: no exclusion
    assert dec.exclude is None


def test_rejection_level_is_the_bonferroni_chi2_quantile():
    assert rejection_level(3, 6, 1e-7) == pytest.approx(stats.chi2.isf(1e-7 / 5, 2))
    assert rejection_level(1, 4, 1e-7) == math.inf


# -- capability ----------------------------------------------------------------------------
def test_two_aligned_triads_detect_three_isolate(tmp_path):
    two = Monitor(triads(tmp_path, 2))
    three = Monitor(triads(tmp_path, 3))
    assert two.model.capability == "detect"
    assert three.model.capability == "isolate"
    rep = capability_report(two.model, two.sensor_names, 1 / DPS, "deg/s")
    worst = rep["pairs"][0]
    assert {n[-1] for n in worst["names"]} == {worst["names"][0][-1]}, worst   # same axis
    assert worst["isolable_from"] > 10 * max(rep["detectable"].values())
    for ax in rep["axes"]:
        assert len(ax["sensors"]) == 2 and ax["isolable_from"] > 10 * max(
            rep["detectable"].values()), ax


def test_isolable_size_is_where_the_rejection_becomes_reliable(tmp_path):
    """A bias of the reported size on sensor i over the longest window rejects the hypothesis
    of sensor j with probability 1 − P_md (Monte Carlo of the window sum, P_md = 0.1)."""
    cal = triads(tmp_path, 3)
    mset = MonitorSettings(missed_detection=0.1)
    mon = Monitor(cal, settings=mset)
    mdl = mon.model
    k = int(np.argmax(mon.thresholds.scales))
    w, f = mon.thresholds.scales[k], mon.thresholds.variance_factor[k]
    i, j = 0, 3                                          # imu1.x against imu2.x
    b = mdl.isolable_from[i, j]
    rng = np.random.default_rng(5)
    runs, hit = 4000, 0
    for _ in range(runs):
        s = w * b * mdl.U[:, i] + math.sqrt(w * f) * rng.standard_normal(mdl.df)
        dec = decide(mdl.U, s, w * f, mset.wrong_exclusion, np.inf)
        hit += j not in dec.consistent
    lo, hi = stats.binom.interval(0.999, runs, 0.9)
    assert lo <= hit <= hi, (hit / runs, b / DPS)


# -- the monitor ---------------------------------------------------------------------------
@pytest.mark.parametrize("sensor", [3, 6])
def test_two_triads_never_exclude_and_mark_the_disagreeing_axis(tmp_path, sensor):
    """A 20σ step on one z gyro of two aligned triads: detected at once, no exclusion, the
    two z gyros named as disagreeing, z (and only z) unverified from the first alarm on,
    no protection level while unverified."""
    cal = triads(tmp_path, 2, seed=1)
    sd = cal.gyro.noise_sd[sensor - 1]
    t, raw = flight(cal, 1500, [(sensor, 500, 20 * sd)], seed=3)
    res = Monitor(cal).run(t, raw)
    types = [e.type for e in res.events]
    assert "isolated" not in types and res.healthy.all(), res.events
    first = next(e for e in res.events if e.type == "detected")
    assert first.t >= t[500] and first.sensor is None
    dis = [e for e in res.events if e.type == "disagree"]
    assert dis and set(dis[0].sensors) == {3, 6} and dis[0].t == first.t, dis
    r0 = int(np.searchsorted(t, first.t))
    assert res.unverified[r0:].all(axis=0).tolist() == [False, False, True]
    assert not res.unverified[:r0].any()
    assert np.isinf(res.protection_level[r0:]).all()
    assert np.isfinite(res.protection_level[:r0]).all()


@pytest.mark.parametrize("sensor", [1, 5, 9])
def test_three_triads_exclude_the_faulty_sensor_only(tmp_path, sensor):
    cal = triads(tmp_path, 3, seed=2)
    sd = cal.gyro.noise_sd[sensor - 1]
    t, raw = flight(cal, 1500, [(sensor, 500, 20 * sd)], seed=4)
    res = Monitor(cal).run(t, raw)
    iso = [e for e in res.events if e.type == "isolated"]
    assert [e.sensor for e in iso] == [sensor], res.events
    assert np.isfinite(res.protection_level[-1]) and not res.unverified[-1].any()


def test_out_of_envelope_no_exclusion_and_windows_restart(tmp_path):
    """A fault during an envelope excursion is detected but not excluded; on re-entry the
    windows start afresh and the (still present) fault is then excluded."""
    cal = triads(tmp_path, 3, seed=2)
    sd = cal.gyro.noise_sd[0]
    t, raw = flight(cal, 2000, [(1, 500, 20 * sd)], seed=5)
    env = np.zeros(2000, np.int64)
    env[400:900] = 1
    res = Monitor(cal).run(t, raw, envelope=env)
    iso = [e for e in res.events if e.type == "isolated"]
    assert len(iso) == 1 and iso[0].sensor == 1 and iso[0].t >= t[900], res.events
    det = [e for e in res.events if e.type == "detected"]
    assert det[0].envelope == 1 and det[0].t < t[900]
    envs = [(e.t, e.reason) for e in res.events if e.type == "envelope"]
    assert [x[0] for x in envs] == [t[400], t[900]] and envs[1][1] == "in"
    np.testing.assert_array_equal(res.envelope, env)
    assert np.isinf(res.protection_level[400:900]).all()


def test_a_detection_open_at_reentry_stays_open_until_the_windows_refill(tmp_path):
    """Two triads (detect only): a persisting fault detected before an excursion stays
    detected through it and after re-entry (one detection event, its axis unverified every
    sample); a fault that ends inside the excursion clears only once every window has
    refilled after re-entry."""
    cal = triads(tmp_path, 2, seed=2)
    sd = cal.gyro.noise_sd[2]
    t, raw = flight(cal, 2000, [(3, 500, 30 * sd)], seed=5)
    env = np.zeros(2000, np.int64)
    env[800:850] = 16
    mon = Monitor(cal)
    res = mon.run(t, raw, envelope=env)
    det = [e for e in res.events if e.type == "detected"]
    assert len(det) == 1 and t[500] <= det[0].t < t[800], res.events
    k0 = int(np.searchsorted(t, det[0].t))
    assert res.unverified[k0:, 2].all(), "the faulted axis must stay unverified"
    assert np.isinf(res.protection_level[k0:]).all()
    # the fault ends inside the excursion
    t, raw = flight(cal, 2000, [(3, 500, 30 * sd), (3, 820, -30 * sd)], seed=5)
    res = Monitor(cal).run(t, raw, envelope=env)
    longest = max(Monitor(cal).thresholds.scales)
    still = np.flatnonzero(res.unverified[:, 2])
    assert still.size and still[-1] >= 850 + longest - 1, (still[-1], longest)
    assert not res.unverified[-1].any(), "cleared once the refilled windows saw no fault"


ENV = st.lists(st.tuples(st.integers(0, 399), st.integers(1, 60), st.integers(1, 15)),
               max_size=4)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.function_scoped_fixture])
@given(ENV, st.integers(0, 50), st.sampled_from([1, 4, 8]))
def test_step_and_run_identical_with_envelope_and_suspects(tmp_path, spans, seed, sensor):
    cal = triads(tmp_path, 3, seed=2)
    sd = cal.gyro.noise_sd[sensor - 1]
    t, raw = flight(cal, 400, [(sensor, 150, 12 * sd)], seed=seed)
    env = np.zeros(400, np.int64)
    for a, L, code in spans:
        env[a:a + L] = code
    res = Monitor(cal).run(t, raw, envelope=env)
    mon = Monitor(cal)
    answers = [mon.step(t[r], raw[r], envelope=int(env[r])) for r in range(400)]
    np.testing.assert_array_equal(np.array([a.protection_level for a in answers]),
                                  res.protection_level)
    np.testing.assert_array_equal(np.array([a.unverified for a in answers]), res.unverified)
    np.testing.assert_array_equal(np.array([a.envelope for a in answers]), res.envelope)
    np.testing.assert_array_equal(np.array([a.omega for a in answers]), res.omega)
    assert [e for a in answers for e in a.events] == res.events


@pytest.mark.parametrize("bad", [None, "x", float("nan"), -3, 2.5, [1, 2], 1e300])
def test_a_bad_envelope_code_counts_as_inside(tmp_path, bad):
    cal = triads(tmp_path, 3, seed=2)
    t, raw = flight(cal, 5, [], seed=1)
    a = Monitor(cal).step(t[0], raw[0], envelope=bad)
    assert a.envelope == 0 and np.all(np.isfinite(a.omega))
