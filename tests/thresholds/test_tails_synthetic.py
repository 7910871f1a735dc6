"""The tail-threshold check on a synthetic static set with a known heavy tail, so that it
runs without the shared recordings (tests/thresholds/test_realnoise.py skips without them).

Four three-axis IMUs at rest, 43.5 Hz, 0.1 deg/s white noise; two channels carry Student-t
noise with 3 degrees of freedom (same variance; tail index 1/3, the generalised Pareto
shape of its exceedances). Tuned on the first half (studies.realnoise.static_holdout):
the Gaussian design's single-sample statistic exceeds its level far more often than α on
the held-out half, the tail-aware levels do not; on the all-Gaussian control neither does.
"""

import numpy as np
import pytest

from studies.realnoise import static_holdout

FS, N = 43.5, 20000
SIG = 0.1 * np.pi / 180
NAMES = tuple(f"imu{k // 3 + 1}.{'xyz'[k % 3]}" for k in range(12))


def _set(heavy: bool, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    y = rng.normal(0, SIG, (N, 12))
    if heavy:
        df = 3.0
        y[:, [1, 7]] = SIG * rng.standard_t(df, (N, 2)) / np.sqrt(df / (df - 2))
    return np.arange(N) / FS, y


def test_known_heavy_tail_breaks_the_gaussian_design_and_the_tail_levels_hold():
    t, y = _set(True)
    r = static_holdout(t, y, NAMES, false_alarms_per_hour=60.0, simulate_hours=0.0)
    kurt = np.array(r["noise_tuning_part"]["excess_kurtosis"])
    assert kurt[1] > 5 and kurt[7] > 5 and np.all(np.abs(np.delete(kurt, [1, 7])) < 0.3)
    assert r["tuned_allan"]["exceedance_over_alpha_per_scale"][0] > 10
    tail = r["drift_and_tail_aware"]
    assert tail["exceedance_over_alpha_per_scale"][0] <= 1.0
    assert tail["time_in_alarm_fraction"] < r["tuned_allan"]["time_in_alarm_fraction"] / 10


@pytest.mark.slow
def test_gaussian_control_meets_its_level_either_way():
    t, y = _set(False)
    r = static_holdout(t, y, NAMES, false_alarms_per_hour=60.0, simulate_hours=0.0)
    for k in ("tuned_allan", "drift_and_tail_aware"):
        assert r[k]["exceedance_over_alpha_per_scale"][0] < 3, (k, r[k])
