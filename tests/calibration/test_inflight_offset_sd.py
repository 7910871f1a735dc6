"""The in-flight time offset's sd says what it covers (calibration.inflight.offset_check).

A fast Monte Carlo of the reported sd over short simulated flights (band from the sampling
sd of a sample sd), the block bootstrap against the exact OLS sd on white errors, the
piece-consistency χ² by hand, and a flight whose lag changes halfway (the test fails and
the sd is widened to the pieces' scatter).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from calibration.inflight.fit import fit_inflight
from calibration.inflight.offset_check import block_bootstrap_sd, check_lines, consistency
from replay.imu_set import ImuSetSpec, simulate_imu_set

TAU = 0.003


def test_consistency_chi2_by_hand() -> None:
    tau = np.array([1.0, 2.0, 4.0])
    sd = np.array([1.0, 1.0, 2.0])
    m = (1 + 2 + 1) / 2.25                       # Σ w τ / Σ w with w = 1/sd² = 1, 1, 1/4
    chi2 = (1 - m) ** 2 + (2 - m) ** 2 + (4 - m) ** 2 / 4
    c = consistency(tau, sd)
    assert c["mean_s"] == pytest.approx(m)
    assert c["chi2"] == pytest.approx(chi2)
    assert c["dof"] == 2
    assert c["p_value"] == pytest.approx(stats.chi2.sf(chi2, 2))
    assert c["sd_internal_s"] == pytest.approx(1 / np.sqrt(2.25))
    assert c["sd_external_s"] == pytest.approx(np.sqrt(chi2 / 2 / 2.25))


def test_block_bootstrap_matches_ols_sd_on_white_errors() -> None:
    rng = np.random.default_rng(3)
    N = 20000
    X = np.zeros((N, 1, 2))
    X[:, 0, 0] = 1.0
    X[:, 0, 1] = rng.normal(size=N)
    e = rng.normal(size=(N, 1))
    ols = np.sqrt(np.diag(np.linalg.inv(X[:, 0].T @ X[:, 0])))
    boot = block_bootstrap_sd(X, e, block=50, n_boot=800)
    # 400 blocks of 50: the block estimate of the sd has a relative sd near
    # sqrt(b/(3N)) = 3 % (plus 2.5 % from 800 replicates); 15 % is beyond 3.5 of those
    assert np.all(np.abs(boot / ols - 1) < 0.15)


def test_reported_offset_sd_is_honest_over_short_flights() -> None:
    """20 flights of 15 s with a 3 ms lag: (τ̂ − τ)/sd has sd 1 when the sd is honest (it
    may be larger than needed, never smaller). The sample sd of n values of unit sd has
    sampling sd 1/sqrt(2(n-1)); a band of 3 of those catches an sd doubled or halved."""
    z = []
    for seed in range(20):
        f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=15, seed=seed,
                                        time_offset_s=(0.0, TAU)))
        a = fit_inflight(f).alignments["imu2"]
        assert a.time_offset_sd_s >= 1e-3 * a.offset_check["sd_hac_ms"] - 1e-15
        z.append((a.time_offset_s - TAU) / a.time_offset_sd_s)
    n = len(z)
    s = float(np.sqrt(np.mean(np.square(z))))           # the truth is known: mean 0
    band = 3 / np.sqrt(2 * n)
    assert 1 - band < s < 1 + band, s


def test_a_lag_that_changes_halfway_fails_the_piece_test_and_widens_the_sd() -> None:
    spec = ImuSetSpec(imus=2, duration_s=60, seed=7, time_offset_s=(0.0, 0.002))
    f1 = simulate_imu_set(spec)
    f2 = simulate_imu_set(replace(spec, time_offset_s=(0.0, 0.010)))
    half = f1.t.shape[0] // 2
    raw = f1.raw.copy()
    raw[half:, 3:] = f2.raw[half:, 3:]                   # IMU2 lags 10 ms in the 2nd half
    a = fit_inflight(replace(f1, raw=raw)).alignments["imu2"]
    chk = a.offset_check
    assert not chk["consistent"] and chk["consistency"]["p_value"] < 1e-6
    good = [q["offset_ms"] for q in chk["pieces"] if q["offset_ms"] is not None]
    assert min(good) < 3.5 and max(good) > 8.5
    assert a.time_offset_sd_s == pytest.approx(1e-3 * chk["sd_pieces_ms"])
    assert a.time_offset_sd_s > 1.5 * 1e-3 * max(chk["sd_hac_ms"], chk["sd_bootstrap_ms"])
    text = "\n".join(check_lines(chk))
    assert "the offset varies within this flight" in text
    assert "belongs to this flight" in text


def test_a_calibration_from_another_flight_is_named() -> None:
    from calibration.inflight.calfile import calibration_from_fit
    from calibration.inflight.diagnose import diagnose_flight
    from calibration.inflight.timing import other_flight_warning

    f1 = simulate_imu_set(ImuSetSpec(imus=2, duration_s=20, seed=1, time_offset_s=(0.0, TAU)))
    f2 = simulate_imu_set(ImuSetSpec(imus=2, duration_s=20, seed=2, time_offset_s=(0.0, TAU)))
    cal1 = calibration_from_fit(fit_inflight(f1), f1)
    assert cal1.extra["inflight"]["flight"]["samples"] == f1.t.shape[0]
    assert other_flight_warning(cal1, f1) is None
    w = other_flight_warning(cal1, f2)
    assert w is not None and "another flight" in w
    assert diagnose_flight(f2, cal1)["warnings"] == [w]
    assert diagnose_flight(f1, cal1)["warnings"] == []
