"""The in-flight selection uses Holm's step-down (as the session selection): the k-th effect
accepted passes α/(M − k). A second effect whose p-value lies between α/M (Bonferroni) and
α/(M − 1) enters; one above α/(M − 1) does not."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq

from calibration.inflight.diagnose import _Cand, _holm_rest, _pvalues, _select

N, ALPHA, M = 3000, 0.01, 4


def _per_axis(v: np.ndarray) -> np.ndarray:
    X = np.zeros((v.shape[0], 3, 3))
    for k in range(3):
        X[:, k, k] = v
    return X


def _case(p_target: float) -> tuple[dict, dict, np.ndarray]:
    """A strong effect A and an effect B sized so that its p-value, once A is in, is
    ``p_target``; two null candidates make M = 4."""
    t = np.linspace(0.0, 100.0, N)
    rng = np.random.default_rng(7)
    noise = rng.standard_normal((N, 3))
    cands = [_Cand("a", "imu2", _per_axis(np.sin(2 * np.pi * t / 7.0)), "-", 1.0),
             _Cand("b", "imu2", _per_axis(np.cos(2 * np.pi * t / 3.1)), "-", 1.0),
             _Cand("c", "imu2", _per_axis(np.sin(2 * np.pi * t / 1.3)), "-", 1.0),
             _Cand("d", "imu2", _per_axis(np.cos(2 * np.pi * t / 0.7)), "-", 1.0)]
    keep = np.ones(N, bool)

    def resid(amp: float) -> np.ndarray:
        return noise + 2.0 * cands[0].X.sum(axis=2) + amp * cands[1].X.sum(axis=2)

    def logp(amp: float) -> float:
        p = _pvalues(resid(amp), [cands[0]], [cands[1]], keep)[0]
        return np.log(max(p, 1e-300)) - np.log(p_target)

    amp = brentq(logp, 0.0, 1.0, xtol=1e-12)
    return {"imu2": resid(amp)}, {"imu2": cands}, keep


@pytest.mark.parametrize(("p_target", "enters"), [
    (np.sqrt(ALPHA / M * ALPHA / (M - 1)), True),        # between Bonferroni and Holm
    (1.2 * ALPHA / (M - 1), False),                       # above Holm's second threshold
])
def test_second_effect_enters_at_holms_threshold(p_target, enters):
    res, cands, keep = _case(p_target)
    p_b = _pvalues(res["imu2"], [cands["imu2"][0]], [cands["imu2"][1]], keep)[0]
    assert p_b == pytest.approx(p_target, rel=1e-6)
    assert p_b > ALPHA / M                                # Bonferroni would refuse it
    chosen, k = _select(res, cands, keep, ALPHA, M)
    names = [c.name for c in chosen["imu2"][0]]
    assert names == (["a", "b"] if enters else ["a"])
    assert k == len(names)


def test_holm_rest_continues_the_step_down():
    # two accepted of M = 6: the next thresholds are α/4, then α/3
    ps = {"x": 0.9 * ALPHA / 4, "y": 0.9 * ALPHA / 3, "z": 0.5}
    assert _holm_rest(ps, ALPHA, 6, 2) == {"x", "y"}
    # y first (α/4), then x against α/3
    assert _holm_rest({"x": 1.1 * ALPHA / 4, "y": 0.0}, ALPHA, 6, 2) == {"x", "y"}
    assert _holm_rest({"x": 1.1 * ALPHA / 3, "y": 0.0}, ALPHA, 6, 2) == {"y"}
    assert _holm_rest({"x": 1.1 * ALPHA / 4}, ALPHA, 6, 2) == set()
