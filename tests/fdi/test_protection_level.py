"""The protection level checked from both sides, on faults sized by the test itself.

The monitor states PL = max_i MDB_i·|G e_i| + k·σ_max (at ρ = 0; :mod:`fdi.integrity`):
the rate error of the worst undetected single-sensor bias plus k = Φ⁻¹(1 − P_md/2)
standard deviations of the noise along its worst direction. Here every quantity is
recomputed from the calibration with scipy (null space of Hᵀ, weighted least squares, the
noncentral χ²), not from the monitor's model, and each of the two terms is checked against
simulation at the stated risk:

- with a bias of exactly MDB_i on sensor i the single-sample test misses at rate P_md
  (binomial bounds) and moves ω̂ by MDB_i·|G e_i| (3 Monte Carlo sd);
- without a fault, |ω̂ − ω| along the worst direction exceeds k·σ_max at rate P_md;
- the reported PL equals the sum (a PL 10× too large, or too small, fails);
- and the integrity claim itself: with the worst-case undetected fault, error above PL
  and no detection happen together at most at rate P_md.

The PL is a sum of two worst cases, hence conservative: its joint exceedance rate is far
below P_md by construction, which is why tightness is tested term by term.
"""

from __future__ import annotations

import numpy as np
from scipy import linalg, optimize, stats

from fdi.detector import default_thresholds
from fdi.monitor import Monitor
from fdi.settings import MonitorSettings
from studies.synthetic import raw_samples, synthetic_calibration

FS = 100.0
P_MD = 0.01
N = 40_000


def _binomial_ok(k: int, n: int, p: float) -> bool:
    """k/n within 3 sd of p (normal approximation; n·p ≥ 400 here)."""
    return abs(k / n - p) <= 3.0 * np.sqrt(p * (1 - p) / n)


def _setup():
    cal = synthetic_calibration("cone6", seed=8, allan=False, bias_uncertainty=0.0,
                                noise_sd_spread=0.3, input_error_sd=1e-6)
    th = default_thresholds(cal, scales=(1,))
    mset = MonitorSettings(missed_detection=P_MD, persistence=10**9)
    return cal, th, mset


def _independent(cal, th) -> dict:
    """MDB per sensor, G, worst noise direction and PL from the definitions (scipy)."""
    H = cal.gyro.H
    Sig = np.asarray(cal.gyro.noise_covariance, float)
    n = H.shape[0]
    V = linalg.null_space(H.T).T                          # any basis of the parity space
    S_inv = np.linalg.inv(V @ Sig @ V.T)
    u2 = np.einsum("ji,jk,ki->i", V, S_inv, V)             # |u_i|² = v_iᵀ (VΣVᵀ)⁻¹ v_i
    df = n - 3
    T = stats.chi2.isf(th.alpha[0], df)
    lam = optimize.brentq(lambda x: stats.ncx2.cdf(T, df, x) - P_MD, 1e-6, 1e4, xtol=1e-12)
    mdb = np.sqrt(lam / u2)
    Wi = np.linalg.inv(Sig)
    G = np.linalg.solve(H.T @ Wi @ H, H.T @ Wi)
    P = G @ Sig @ G.T
    ev, evec = np.linalg.eigh(P)
    k = stats.norm.isf(P_MD / 2)
    bias_term = mdb * np.linalg.norm(G, axis=0)
    return {"mdb": mdb, "G": G, "d": evec[:, -1], "sigma_max": np.sqrt(ev[-1]), "k": k,
            "bias_term": bias_term, "pl": bias_term.max() + k * np.sqrt(ev[-1])}


def _rates(n_rows: int, seed: int) -> np.ndarray:
    """Slow rates (≤ 0.05 rad/s: ρ negligible), (N, 3)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_rows) / FS
    return 0.05 * np.sin(2 * np.pi * rng.uniform(0.05, 0.3, 3) * t[:, None]
                         + rng.uniform(0, 6, 3))


def test_reported_protection_level_equals_the_independent_one():
    cal, th, mset = _setup()
    ind = _independent(cal, th)
    mon = Monitor(cal, th, settings=mset)
    np.testing.assert_allclose(mon.model.pl.mdb, ind["mdb"], rtol=1e-6)
    om = _rates(200, 1)
    res = mon.run(np.arange(200) / FS, raw_samples(cal, om, seed=2))
    np.testing.assert_allclose(res.protection_level, ind["pl"], rtol=1e-4)


def test_protection_level_terms_hold_at_the_stated_risk():
    cal, th, mset = _setup()
    ind = _independent(cal, th)
    # noise term: fault-free, error along the worst direction beyond k·σ_max at rate P_md
    om = _rates(N, 3)
    res = Monitor(cal, th, settings=mset).run(np.arange(N) / FS, raw_samples(cal, om, seed=4))
    e = res.omega - om
    beyond = int((np.abs(e @ ind["d"]) > ind["k"] * ind["sigma_max"]).sum())
    assert _binomial_ok(beyond, N, P_MD), (beyond, N)
    # bias term: a bias of MDB_i is missed at rate P_md and moves ω̂ by MDB_i·|G e_i|
    worst = int(np.argmax(ind["bias_term"]))
    for i in range(6):
        om = _rates(N, 10 + i)
        f = np.zeros((N, 6))
        f[:, i] = ind["mdb"][i]
        res = Monitor(cal, th, settings=mset).run(np.arange(N) / FS,
                                                   raw_samples(cal, om, seed=20 + i, fault=f))
        missed = res.statistics[:, 0] <= res.thresholds[:, 0]
        assert _binomial_ok(int(missed.sum()), N, P_MD), (i, int(missed.sum()))
        e = res.omega - om
        shift = e.mean(axis=0)
        sd_mean = np.sqrt(np.trace(ind["G"] @ cal.gyro.noise_covariance @ ind["G"].T) / N)
        assert abs(np.linalg.norm(shift) - ind["bias_term"][i]) < 3 * sd_mean, i
        if i == worst:
            # the integrity claim: undetected and beyond PL together at most at rate P_md
            bad = int((missed & (np.linalg.norm(e, axis=1) > res.protection_level)).sum())
            assert bad / N <= P_MD + 3 * np.sqrt(P_MD / N), bad
