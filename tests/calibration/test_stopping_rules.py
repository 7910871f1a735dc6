"""Deterministic checks of the stopping rules (a mutation of either must fail here):

- the turntable diagnosis' forward selection is Holm's step-down at α/2: at each round the
  smallest p is accepted while p < (α/2)/m, m the members left (calibration.diagnose.
  selection._forward);
- the flight diagnosis enters its k-th candidate only when p < α/(M − k), M all candidates
  of all IMUs (Holm's step-down, as the turntable diagnosis; Bonferroni α/M until issue
  21), and stops at the first that does not pass.
"""

from __future__ import annotations

import numpy as np

import calibration.inflight.diagnose as fd
from calibration.diagnose.selection import Selection, _forward
from calibration.inflight.regression import stacked_lstsq, wald_test
from replay.imu_set import ImuSetSpec, simulate_imu_set


class _Model:
    """Stands in for a sensor's model: records what is added."""

    def __init__(self) -> None:
        self.added = 0

    def add(self, Z) -> None:
        self.added += 1

    def basis(self, Z):
        return np.zeros((1, 1))


def _run(ps: list[float], alpha: float) -> Selection:
    """Each member on its own sensor (nothing is re-evaluated after an acceptance)."""
    out = Selection()
    cache = {}
    for i, p in enumerate(ps):
        out.models[("gyro", i)] = _Model()
        cache[("gyro", i, f"e{i}")] = (p, float(np.log(p)), {}, np.zeros((4, 1)), 1.0)
    _forward({}, {f"e{i}": f"cand{i}" for i in range(len(ps))}, cache, out, alpha)
    return out


def test_holm_step_down_thresholds_are_alpha_half_over_members_left() -> None:
    # α = 0.05 → α/2 = 0.025; thresholds 0.025/4, /3, /2, /1 = 0.00625, 0.00833, 0.0125, 0.025
    out = _run([0.024, 0.011, 0.001, 0.007], 0.05)
    assert [s.sensor for s in out.claimed] == [2, 3, 1, 0]          # in order of p
    np.testing.assert_allclose([s.threshold for s in out.claimed],
                               [0.025 / 4, 0.025 / 3, 0.025 / 2, 0.025 / 1])
    # 0.007 passes only because m shrank (Bonferroni at m = 4 would stop there)
    assert out.claimed[1].p_value == 0.007 > 0.025 / 4


def test_holm_stops_at_the_first_non_rejection() -> None:
    # 0.0130 > 0.025 / 2 stops the procedure: 0.020 < 0.025 is never reached
    out = _run([0.001, 0.013, 0.020], 0.05)
    assert [s.p_value for s in out.claimed] == [0.001]


def test_alpha_is_halved_for_the_selection() -> None:
    assert _run([0.008], 0.01).claimed == []            # 0.008 > 0.01 / 2
    assert len(_run([0.004], 0.01).claimed) == 1


def _per_axis(v):
    X = np.zeros((v.shape[0], 3, 3))
    for k in range(3):
        X[:, k, k] = v
    return X


def _cands_data(seed: int = 0):
    rng = np.random.default_rng(seed)
    N = 3000
    t = np.arange(N) / 50.0
    u1, u2 = rng.normal(size=N), rng.normal(size=N)
    r = rng.normal(0, 1.0, (N, 3))
    r[:, 0] += 0.08 * u1                                  # strong
    r[:, 1] += 0.05 * u2                                  # weaker
    cands = [fd._Cand("a", "imu2", _per_axis(u1), "u", 1.0),
             fd._Cand("b", "imu2", _per_axis(u2), "u", 1.0)]
    return t, r, cands


def _p_alone(r, cand, keep, chosen=()):
    base = np.zeros((r.shape[0], 3, 3))
    for k in range(3):
        base[:, k, k] = 1.0
    X, sl = fd._design(base, [*chosen, cand])
    fit = stacked_lstsq(X[keep], r[keep])
    return wald_test(fit, np.arange(sl[-1].start, sl[-1].stop))[2]


def test_flight_selection_enters_only_below_alpha_each_and_stops() -> None:
    t, r, cands = _cands_data()
    keep = np.ones(t.shape[0], bool)
    pa = _p_alone(r, cands[0], keep)
    pb = _p_alone(r, cands[1], keep, (cands[0],))
    assert pa < pb < 0.01

    def select(alpha, M=1):             # M = 1: the threshold is alpha at every step
        return fd._select({"imu2": r}, {"imu2": cands}, keep, alpha, M)[0]["imu2"][0]

    chosen = select(pb * 1.01)
    assert [c.name for c in chosen] == ["a", "b"]
    chosen = select(pb * 0.99)
    assert [c.name for c in chosen] == ["a"]
    chosen = select(pa * 0.99)
    assert chosen == []
    # M = 2: a against alpha/2, then b against alpha/1 (Holm), not alpha/2 (Bonferroni)
    assert pa < pb / 2
    assert [c.name for c in select(pb * 1.01, 2)] == ["a", "b"]


def test_flight_diagnosis_applies_holm_over_all_candidates(monkeypatch) -> None:
    seen = []
    real = fd._select

    def spy(res, cands, keep, alpha, M):
        seen.append(({g: len(c) for g, c in cands.items()}, alpha, M))
        return real(res, cands, keep, alpha, M)

    monkeypatch.setattr(fd, "_select", spy)
    f = simulate_imu_set(ImuSetSpec(imus=3, duration_s=30, seed=3))
    from calibration.inflight.calfile import calibration_from_fit
    from calibration.inflight.fit import fit_inflight

    doc = fd.diagnose_flight(f, calibration_from_fit(fit_inflight(f), f), alpha=0.02)
    (n, a, M) = seen[0]                                     # one family for every IMU
    assert len(seen) == 1 and len(n) == 2                  # two IMUs besides the reference
    assert M == doc["candidates"]
    assert M >= sum(n.values())                            # every candidate of every IMU
    assert a == 0.02 and doc["correction"].startswith("Holm")
