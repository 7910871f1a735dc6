"""Model adequacy under coloured noise (issue 7.1): a genuine bias instability is noise, an
effect is not.

A Gauss-Markov bias instability (tetrad-paper, 1 °/h, τc 100 s, the case of
test_coloured_noise.py) leaves slow structure that the white-noise F-tests read as an
effect: with them 9 of 10 such clean sessions were flagged and ``rimu calibrate`` withheld
the Gauss-Markov widening, leaving the bias σ ≈ 3.5× too small. Where the calibration's
noise-model selection keeps a Gauss-Markov term, the diagnosis now tests against white +
Gauss-Markov noise with its parameters profiled out (:mod:`calibration.diagnose.coloured`).

Checked here:

- the null distribution of the profile likelihood ratio: mean LR/r near 1 for slow
  regressors (a warm-up, a trend, Legendre polynomials, per-step means) over simulated white
  + Gauss-Markov sets (Monte Carlo, seeds fixed);
- clean coloured sessions: flagged (any effect or "unexplained") no more often than the
  99.9 % binomial quantile for α; calibrate's verdict is not "effects suspected" and the
  Gauss-Markov widening is applied, and the bias errors honest (sd of error/σ near 1, tails
  within the binomial bound). Since the detectability check (:mod:`calibration.diagnose.
  detect`) the verdict of such a session is "effects not ruled out" rather than "adequate":
  against a profiled Gauss-Markov wander of this size a slow effect (warm-up, drift) that
  moves a bias by 5 σ is found with probability well below 0.99, and the session says so;
- coloured sessions with an effect that biases a parameter beyond 5 σ (scale asymmetry,
  g-sensitivity, warm-up): never "adequate", widening withheld.
"""

import numpy as np
import pytest
import scipy.stats
from _diagnose_sessions import calibrate_fast
from scipy.signal import lfilter
from threadpoolctl import threadpool_limits

from calibration.calibrate import calibrate
from calibration.calibrate_checked import calibrate_checked
from calibration.compare import compare
from calibration.diagnose import assess, diagnose
from calibration.diagnose.coloured import GlsModel, NoiseSet, block_corr, block_noise
from calibration.presets import preset
from calibration.residuals import gauss_markov_segment_corr
from calibration.simulate import SessionNoise, simulate_session
from fdi.units import DPH

BI_DPH, TAU_C_S = 1.0, 100.0


def _coloured(seed, effects=None, sensors=None, name="tetrad-paper"):
    seq, truth, _ = preset(name)
    nm = SessionNoise(bias_instability={"gyro": BI_DPH * DPH}, bias_correlation_s=TAU_C_S)
    return simulate_session(None, seq, truth, seed=seed, noise=nm, effects=effects or {},
                            effect_sensors=sensors), truth


def test_block_corr_is_the_segment_corr():
    start = np.r_[0.0, np.cumsum(np.full(30, 1.0))]
    length = np.r_[np.full(30, 1.0), 1.4]
    for tc in (0.7, 5.0, 300.0):
        np.testing.assert_allclose(block_corr(start, length, tc),
                                   gauss_markov_segment_corr(start, length, tc),
                                   rtol=1e-10, atol=1e-14)


def _null_lr(reps, seed):
    """LR/r of slow regressors on sensor 1 of a set of 4 white + Gauss-Markov sensors."""
    fs, N, n, sw, sb, tc = 100.0, 57_600, 4, 36.0, 1.0, 100.0
    t = np.arange(N) / fs
    u = 2 * t / t[-1] - 1
    tests = {"warmup": np.exp(-t / 300)[:, None], "trend": t[:, None],
             "legendre": np.polynomial.legendre.legvander(u, 10)[:, 1:],
             "steps": (np.floor(t / 36)[:, None] == np.arange(1, 16)[None, :]).astype(float)}
    rng = np.random.default_rng(seed)
    phi = np.exp(-1 / (fs * tc))
    bn = block_noise(N, fs)
    out = {k: [] for k in tests}
    with threadpool_limits(limits=1, user_api="blas"):
        for _ in range(reps):
            _draw(rng, phi, sb, sw, N, n, bn, tests, out)
    return {k: np.array(v) for k, v in out.items()}


def _draw(rng, phi, sb, sw, N, n, bn, tests, out):
    """One set of n white + Gauss-Markov sensors; LR/r and p of each test on sensor 1."""
    w = rng.standard_normal((N, n)) * sb * np.sqrt(1 - phi**2)
    g = lfilter([1.0], [1.0, -phi], w, axis=0,
                zi=(phi * sb * rng.standard_normal(n))[None, :])[0]
    y = sw * rng.standard_normal((N, n)) + g
    grp = NoiseSet(bn)
    models = [GlsModel(y[:, i], np.ones((N, 1)), grp, i) for i in range(n)]
    for k, Z in tests.items():
        ft = models[0].test(Z)
        out[k].append((ft.ss / ft.rank, ft.p_value))


def test_profile_likelihood_ratio_null_is_chi2():
    """Mean of LR/r is 1 under the null for χ²_r; over 12 draws its sd is at most
    √(2/r)/√12 ≤ 0.41: accept 1 ± 0.6 (the ML profile without the restricted terms gave
    1.7-1.9 for the warm-up and the trend)."""
    res = _null_lr(12, seed=7)
    for k, v in res.items():
        assert 0.4 < v[:, 0].mean() < 1.6, (k, v[:, 0].mean())


@pytest.mark.slow
def test_profile_likelihood_ratio_null_tail():
    """30 draws: the fraction of p < 0.05 per regressor within the 99.9 % binomial bound."""
    res = _null_lr(30, seed=8)
    hi = scipy.stats.binom.ppf(0.999, 30, 0.05)
    for k, v in res.items():
        assert 0.6 < v[:, 0].mean() < 1.4, (k, v[:, 0].mean())
        assert np.sum(v[:, 1] < 0.05) <= hi, (k, np.sum(v[:, 1] < 0.05))


def test_coloured_clean_session_is_not_ruled_out_and_widened():
    """Nothing suspected, the widening applied; the verdict (was "adequate" before the
    detectability check) is "effects not ruled out", naming the slow effects the wander
    could hide at 5 σ, with the advice and a warning."""
    s, _ = _coloured(seed=1)
    cal = calibrate_checked(s, allan=False, earth_rate=False)
    a = cal.adequacy
    assert a["noise_null"]["gyro"] == "white + Gauss-Markov"
    assert a["where"] == []
    assert a["verdict"] == "effects not ruled out"
    assert a["noise_model_applied"] == "auto"
    assert cal.extra["noise_model"]["gyro"]["applied"] is True
    names = {r["name"] for r in a["not_ruled_out"]}
    assert {"warmup", "bias_drift"} <= names, names
    for r in a["not_ruled_out"]:
        assert r["power"] < 0.99 <= r["power_white"] and r["shift_sigma"] == 5.0
        assert r["size_for_power"] > r["size"] > 0
    assert "repeat the session" in a["advice"]
    assert any("effects not ruled out" in w for w in cal.extra["warnings"])


CASES = [("scale_asymmetry", 0.01, None), ("g_sensitivity", 300.0, [1]),
         ("warmup", 60.0, [3])]


def _effect_case(case, seed):
    """Premise: the effect moves a gyro parameter beyond 5 *honest* σ, the σ that the
    coloured-noise calibration gives the same seed without the effect (the white-noise σ
    are ≈ 3.5× too small for the biases under this noise, so beyond 5 of them says
    little)."""
    name, value, sens = case
    s0, truth = _coloured(seed)
    sd = {(r.sensor, r.parameter): r.sd
          for r in compare(calibrate(s0, allan=False, earth_rate=False), truth)}
    s, truth = _coloured(seed, {name: value}, sens)
    z = [r.error / sd[(r.sensor, r.parameter)]
         for r in compare(calibrate_fast(s), truth, {name: value}) if r.kind == "gyro"]
    assert np.max(np.abs(z)) > 5                              # premise
    cal = calibrate_checked(s, allan=False, earth_rate=False)
    a = cal.adequacy
    assert a["verdict"] == "effects suspected", a
    assert a["noise_model_applied"] == "white"
    assert not cal.extra["noise_model"]["gyro"].get("applied")
    return a


def test_coloured_session_with_an_effect_is_never_adequate():
    a = _effect_case(CASES[0], seed=11)
    assert any(CASES[0][0] in w for w in a["where"]), a["where"]


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES, ids=lambda c: c[0])
def test_coloured_session_with_an_effect_is_never_adequate_mc(case):
    for seed in (12, 13):
        a = _effect_case(case, seed)
        assert any(case[0] in w for w in a["where"]), (seed, a["where"])


ALPHA = 0.05
CLEAN_SEEDS = range(300, 350)


@pytest.mark.slow
def test_coloured_clean_sessions_flag_rate_and_honest_biases():
    """50 clean coloured tetrad-paper sessions at α = 0.05 (seeds not used in development):
    flagged ≤ the 99.9 % quantile of Binomial(50, 0.05); the others (verdict "adequate" or,
    since the detectability check, "effects not ruled out": nothing suspected either way)
    get the Gauss-Markov widening, and their bias errors are honest: sd(error/σ) in
    0.75-1.3 and at most the 99.9 % binomial quantile beyond 3σ. The detectability limits
    change none of these (only "adequate" into "effects not ruled out") and are skipped
    here to keep the run short; the verdict with them is tested on seeds 1 and 2 in the
    default run (test_coloured_clean_session_is_not_ruled_out_and_widened,
    test_diagnose_verdict.py)."""
    flagged, z = [], []
    for seed in CLEAN_SEEDS:
        s, truth = _coloured(seed)
        cal = calibrate_checked(s, alpha=ALPHA, allan=False, earth_rate=False,
                                detectability=False)
        a = cal.adequacy
        if a["verdict"] == "effects suspected":
            flagged.append((seed, a["where"]))
            continue
        assert a["noise_null"]["gyro"] == "white + Gauss-Markov", seed
        assert cal.extra["noise_model"]["gyro"]["applied"] is True, seed
        z += [r.z for r in compare(cal, truth) if r.kind == "gyro" and r.parameter == "bias"]
    n = len(CLEAN_SEEDS)
    assert len(flagged) <= scipy.stats.binom.ppf(0.999, n, ALPHA), flagged
    z = np.asarray(z)
    assert 0.75 <= np.std(z, ddof=1) <= 1.3, np.std(z, ddof=1)
    assert np.sum(np.abs(z) > 3) <= scipy.stats.binom.ppf(0.999, z.size, 0.0027), z


@pytest.mark.slow
def test_white_null_flags_coloured_sessions():
    """The premise: with the white-noise null the same sessions are flagged far more often
    than α (the measured 9 of 10)."""
    flagged = 0
    for seed in CLEAN_SEEDS[:10]:
        s, _ = _coloured(seed)
        sel = assess(s, calibrate_fast(s), alpha=ALPHA, noise="white")
        flagged += bool(sel.claimed or sel.unexplained or sel.partial)
    assert flagged >= 5, flagged


@pytest.mark.slow
def test_refit_under_coloured_noise_is_honest():
    """10 coloured sessions (seeds 520-529) with a 60 °/h warm-up on gyro 3: found there
    every time; with the Gauss-Markov sandwich in the refit covariance the warm-up estimate
    and gyro 3's refit parameters are honest: |error/σ| < 4, sd(error/σ) in 0.6-1.5 (with
    the white-noise covariance, measured on seeds 500-514: sd 3.3 for the warm-up, 2.0 for
    the parameters, 8 of 60 beyond 3σ)."""
    ze, zp = [], []
    for seed in range(520, 530):
        s, truth = _coloured(seed, {"warmup": 60.0}, [3])
        d = diagnose(s, calibrate_fast(s), truth=(truth, {"warmup": 60.0}),
                     detectability=False)            # estimates only: limits not needed
        assert d.noise_null["gyro"] == "white + Gauss-Markov", seed
        mine = [e for e in d.effects if e["name"] == "warmup" and e["sensors"] == [3]]
        assert len(mine) == 1, (seed, d.effects, d.unexplained_detail)
        ze.append((mine[0]["estimate"] - 60.0) / mine[0]["estimate_sd"])
        zp += [p["z"] for p in d.error_after["truth"]["parameters"]
               if p["kind"] == "gyro" and p["sensor"] in (3, "g3")]
    ze, zp = np.asarray(ze), np.asarray(zp)
    assert zp.size >= 30, zp.size
    assert np.max(np.abs(ze)) < 4 and 0.6 <= np.std(ze, ddof=1) <= 1.5, ze
    assert np.max(np.abs(zp)) < 4 and 0.6 <= np.std(zp, ddof=1) <= 1.5, zp
