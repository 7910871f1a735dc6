"""Monte Carlo truth tests of the in-flight calibration and the flight diagnosis (--slow).

Simulated two-IMU flights (replay.imu_set, truth sidecar): estimates within 3 sd with
honest sds (spread of error/sd near 1 over seeds), a 5 ms offset found in every flight,
no offset claimed where there is none (binomial bound), and diagnose finds each injected
effect while a clean flight shows none.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from calibration.inflight.calfile import calibration_from_fit
from calibration.inflight.diagnose import diagnose_flight
from calibration.inflight.fit import decompose, fit_inflight
from fdi.units import DPH, DPS, G0
from replay.imu_set import ImuEffects, ImuSetSpec, simulate_imu_set

SEEDS = range(30)
Z3 = 2 * stats.norm.sf(3)                     # P(|z| > 3) for an honest sd


def _z(seed: int, tau: float) -> dict[str, np.ndarray]:
    f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=60, seed=seed,
                                    time_offset_s=(0.0, tau)))
    a = fit_inflight(f).alignments["imu2"]
    tr = f.truth["relative_to_reference"]["imu2"]
    out = {}
    parts, true = decompose(a.A, a.A_cov), decompose(np.array(tr["A"]))
    for name in ("rotation", "scale", "nonorthogonality"):
        est, sd = parts[name]
        out[name] = (est - true[name][0]) / sd
    out["bias"] = (a.c - tr["c"]) / np.sqrt(np.diag(a.c_cov))
    out["time_offset"] = np.array([(a.time_offset_s - tau) / a.time_offset_sd_s])
    out["tau_over_sd"] = np.array([a.time_offset_s / a.time_offset_sd_s])
    return out


@pytest.fixture(scope="module")
def runs() -> dict[float, list[dict[str, np.ndarray]]]:
    return {tau: [_z(s, tau) for s in SEEDS] for tau in (0.0, 0.005)}


@pytest.mark.slow
@pytest.mark.parametrize("name", ["rotation", "scale", "nonorthogonality", "bias",
                                  "time_offset"])
def test_estimates_within_3_sd_with_honest_sd(runs, name: str) -> None:
    z = np.concatenate([r[name] for tau in runs for r in runs[tau]])
    n = z.size
    # |z| > 3 at most as often as an honest sd allows (binomial, 1e-3 one-sided)
    assert np.sum(np.abs(z) > 3) <= stats.binom.isf(1e-3, n, Z3)
    assert abs(np.mean(z)) < 4 / np.sqrt(n)           # no bias beyond 4 standard errors
    assert 0.8 < np.std(z) < 1.25                    # 60..180 values: sd of sd <= 0.09


@pytest.mark.slow
def test_5ms_offset_found_and_none_claimed_where_there_is_none(runs) -> None:
    found = [abs(r["tau_over_sd"][0]) > 3 for r in runs[0.005]]
    assert all(found)
    claimed = sum(abs(r["tau_over_sd"][0]) > 3 for r in runs[0.0])
    # P(claims >= k) <= 1e-3 with an honest sd
    assert claimed <= stats.binom.isf(1e-3, len(SEEDS), Z3)


EFFECTS = {
    "g_sensitivity": (ImuEffects(g_sensitivity=0.05 * DPS / G0, imus=(2,)), 120),
    "temperature": (ImuEffects(temperature_coeff=0.03 * DPS, imus=(2,)), 120),
    "warm_up": (ImuEffects(warm_up=0.1 * DPS, warm_up_s=40.0, imus=(2,)), 300),
    "bias_drift": (ImuEffects(random_walk=100 * DPH, imus=(2,)), 120),
    "vibration": (ImuEffects(vibration_hz=73.0, vibration=0.1 * DPS, imus=(2,)), 120),
    "vibration_noise": (ImuEffects(vibration_noise=0.3 * DPS, imus=(2,)), 120),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_diagnose_finds_the_injected_effect(name: str) -> None:
    eff, duration = EFFECTS[name]
    for seed in range(3):
        f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=duration, seed=seed, effects=eff))
        doc = diagnose_flight(f, calibration_from_fit(fit_inflight(f), f))
        # warm-up and drift chosen together are one claim (slow_bias_change, its members)
        names = [m for e in doc["effects"] for m in (e.get("members") or [e["name"]])]
        assert name in names if name == "vibration_noise" else \
            any(n.startswith(name) and n != "vibration_noise" for n in names), (seed, names)
        assert all(e["sensors"] == [4, 5, 6] for e in doc["effects"])
        if name == "vibration":                 # 73 Hz sampled at 50 Hz aliases to 23 Hz
            assert "vibration_23.00Hz" in names
        if name != "vibration_noise":          # a variance effect is not subtracted
            assert sum(doc["error_after"]["rms"]) < sum(doc["error_before"]["rms"])


@pytest.mark.slow
def test_diagnose_claims_nothing_in_clean_flights() -> None:
    n = 15
    flagged = 0
    for seed in range(100, 100 + n):
        f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=120, seed=seed))
        doc = diagnose_flight(f, calibration_from_fit(fit_inflight(f), f), alpha=0.01)
        flagged += bool(doc["effects"])
    # family-wise alpha 0.01 per flight: P(flagged >= 2 of 15) = 0.01
    assert flagged <= 1
