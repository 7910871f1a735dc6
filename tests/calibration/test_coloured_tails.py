"""Heavy bias tails under coloured noise: is error/σ Student-t with a derivable ν? (No.)

Question (issue 7, the coloured-noise honesty on held-out seeds). With a Gauss-Markov bias
(tetrad-paper, 1 °/h, τc 100 s) ``calibrate(noise_model="auto")`` gives bias sd(z) ≈ 1 but
3-4 of 100 biases beyond 3σ where a normal z allows ≤ 2. Hypothesis tested here: σ̂ is
estimated from the same 576 s session (T/τc ≈ 6), so ``z = error/σ̂`` is Student-t with a
small ν that the fit itself can tell, and the honesty statements should be t_ν-aware.

Derivation of ν (Satterthwaite through the delta method). A bias variance is linear in the
covariance of the segment-mean estimates, ``v = v_w + σ_b²·x(τc)`` at fixed estimates, so
with ``θ = (log σ_b², log τc)``::

    g = ∂ log v / ∂θ = ( σ_b² x / v ,  σ_b² ∂x/∂ log τc / v )
    Var(log v̂) ≈ gᵀ Σ_θ g,     Σ_θ = H⁻¹,  H the Hessian of the Whittle −log L at θ̂

(``GaussMarkovFit.cov_log``, white levels held fixed: they come from thousands of
frequencies). If ``v̂ ~ v·χ²_ν/ν`` then ``Var(log v̂) = ψ'(ν/2)`` (trigamma; ≈ 2/ν for large
ν, Satterthwaite's ν = 2/Var), so ν solves ``ψ'(ν/2) = gᵀ Σ_θ g`` (ν ≥ 1), and with the error
normal and independent of v̂, ``z ~ t_ν``.

Result: the hypothesis is wrong, so nothing in ``calibrate`` or ``compare`` uses ν. Measured
(400 biases per set, model method / whole-turn method):

================================  ====================  ====================
                                  seeds 0-99 (chosen)   seeds 1000-1099 (once)
================================  ====================  ====================
ν median [5 %, 95 %]              1.1 [1.0, 8.1]        1.2 [1.0, 8.1]
|z| > 3 observed                  7 / 5                 9 / 6
|z| > 3 expected under t_ν        52.9 / 51.5           52.6 / 51.2
P_tν < 0.27 % observed (exp 1.1)  2 / 1                 4 / 1
P_tν < 32 % (expected 32 %)       17.7 % / 17.5 %       17.2 % / 15.5 %
KS p of P_tν against uniform      6e-25 / 4e-21         1e-35 / 8e-30
================================  ====================  ====================

The t_ν-aware beyond-3σ count (two-sided t_ν probability below 0.27 %) would come out
right at the 0.27 % level, but only because ν ≈ 1 for 58 % of the biases, whose |z| would
need to exceed ≈ 236 to count: the distribution is badly wrong elsewhere (half the expected
count below P = 32 %). The ν is also backwards: it is smallest where z is smallest. By
ν (seeds 0-99, model biases): ν < 1.5: n 216, sd(z) 0.48, 0 beyond 3; ν 6-12: n 32,
sd(z) 2.03, 5 beyond 3 (t_ν expects 0.6). Held-out: ν < 1.5: sd(z) 0.42; ν 12-30: n 12,
sd(z) 2.33, 3 beyond 3 (t_ν expects 0.1).

What does describe the tails is the fitted correlation time: a scale mixture in which σ̂ is
too small when τ̂c is short and much too large when it is long (sd(z) per τ̂c class,
model biases, seeds 0-99 / 1000-1099): τ̂c < 60 s 1.79 / 1.95 (6 / 9 beyond 3σ, all the
tail); 60-150 s 1.09 / 1.09; 150-400 s 0.54 / 0.61; > 400 s 0.15 / 0.18. A session whose
Gauss-Markov path looks short-correlated has a sharply curved likelihood (ν 6-20) and is
confidently wrong; one whose τ̂c runs to the grid's end (4 records) has a flat likelihood
(ν ≈ 1) and a σ̂ 2-6× too large. The information matrix itself is right where asymptotics
hold (τc 5 s, T/τc ≈ 115: :func:`test_information_matches_the_spread_when_the_record_is_long`)
but understates the spread about 2× at τc 100 s (MC sd of log τ̂c 0.84 against 0.42).

What ``calibrate`` does about it since: its σ are no longer those of the maximum-likelihood
(σ̂_b², τ̂c), studied here (:func:`_bias_z_dof` recomputes them), but those of the τc with
the largest bias variance within the 90 % profile-likelihood interval of τc, cut at a
quarter of the record (:func:`calibration.residuals.gauss_markov_sigma_candidates`). On the
seeds above that gives 0 / 0 and 0 / 1 biases beyond 3σ, and on fresh seeds 2000-2099
0 / 0 (test_calibrate_coloured_holdout.py).
"""

import numpy as np
import pytest
import scipy.optimize
import scipy.special
import scipy.stats
from scipy.signal import lfilter

from calibration.calibrate import gyro_stages
from calibration.presets import preset
from calibration.residuals import fit_gauss_markov, gauss_markov_segment_corr
from calibration.simulate import SessionNoise, simulate_session
from calibration.uncertainty import segment_times, split_with_cov
from fdi.units import DPH

DEV_SEEDS = range(100)
DOF_MIN = 1.0


def _gm_records(tau_c, seed, fs=100.0, N=57_600, n=4, sd_b=4.0, white=36.0):
    """White + first-order Gauss-Markov samples (N, n), stationary from the start."""
    rng = np.random.default_rng(seed)
    phi = np.exp(-1 / (fs * tau_c))
    gm = lfilter([1.0], [1.0, -phi], rng.standard_normal((N, n)) * sd_b * np.sqrt(1 - phi**2),
                 axis=0, zi=(phi * sd_b * rng.standard_normal(n))[None, :])[0]
    return white * rng.standard_normal((N, n)) + gm


def test_information_matches_the_spread_when_the_record_is_long():
    """τc 5 s in a 576 s record (115 correlation times): over 30 seeds the spread of the
    fitted (log σ_b², log τc) agrees with the observed-information sd of ``cov_log``
    (measured MC/information 1.17 and 1.28; the τc grid's rounding, log step 0.2, adds
    ≈ 0.06 to the MC spread of log τc). Bounds 0.8-1.6: a 30-sample sd has a standard
    error of 13 %."""
    fits = [fit_gauss_markov(_gm_records(5.0, seed), 100.0) for seed in range(30)]
    assert all(f.bias_var > 0 and f.cov_log is not None for f in fits)
    est = np.array([[np.log(f.bias_var), np.log(f.tau_c)] for f in fits])
    info_sd = np.sqrt(np.median([np.diag(f.cov_log) for f in fits], axis=0))
    ratio = est.std(axis=0, ddof=1) / info_sd
    assert np.all((0.8 < ratio) & (ratio < 1.6)), (ratio, info_sd)
    # white noise: no term, no covariance
    f0 = fit_gauss_markov(36.0 * np.random.default_rng(1).standard_normal((57_600, 4)), 100.0)
    assert f0.bias_var == 0.0 and f0.cov_log is None


def dof_from_log_var(var_log):
    """ν with ψ'(ν/2) = var_log (Var(log χ²_ν) = ψ'(ν/2)); at least DOF_MIN."""
    if not np.isfinite(var_log) or var_log >= scipy.special.polygamma(1, DOF_MIN / 2):
        return DOF_MIN
    if var_log <= 1e-8:
        return np.inf
    return 2 * scipy.optimize.brentq(lambda x: scipy.special.polygamma(1, x) - var_log,
                                     DOF_MIN / 2, 1e9)


def _bias_z_dof(session, truth):
    """(z, ν, τ̂c) of each gyro bias, model and whole-turn methods; None when white kept.

    z uses the σ at the maximum-likelihood (σ̂_b², τ̂c), which is what ``calibrate``
    reported before its σ moved to the upper end of the profile interval of τc."""
    g = gyro_stages(session, noise_model="auto", allan=False)
    unc, fit, p = g.uncertainty, g.fit, g.problem
    cn = unc.coloured
    if not cn.applied:
        return None
    start, length = segment_times(p.t, p.segment, p.seg_count, p.sample_rate_hz)
    tc, h, eps = cn.correlation_s, 1e-3, 1e-3
    K = gauss_markov_segment_corr(start, length, tc)
    dK = (gauss_markov_segment_corr(start, length, tc * np.exp(h))
          - gauss_markov_segment_corr(start, length, tc * np.exp(-h))) / (2 * h)
    H0 = session.gyro_config.H
    sig = np.diag(g.residuals.noise_cov_raw)
    out = []
    for op, theta, est in ((fit.op, fit.theta, unc.estimates),
                           (fit.op_turns, fit.theta_turns, unc.estimates_turns)):
        a, c = theta[:3].T, theta[3]
        var_raw = cn.bias_instability**2 * np.linalg.norm(a, axis=1) ** 2   # σ_b²/SF²
        ex = var_raw[:, None, None] * (op @ K @ op.T)[None, :4, :4]
        dex = var_raw[:, None, None] * (op @ dK @ op.T)[None, :4, :4]
        Q = (op * fit.inv_count) @ op.T
        C = sig[:, None, None] * Q[None, :4, :4] + ex

        def v(C_, a=a, c=c):
            return np.array([e.bias_sd**2 for e in split_with_cov(a, c, C_, H0)])

        v0 = v(C)    # the σ at the maximum-likelihood (σ_b², τc), not the one calibrate reports
        G = np.stack([(v(C + eps * d) - v(C - eps * d)) / (2 * eps * v0) for d in (ex, dex)],
                     axis=1)
        var_log = np.einsum("ki,ij,kj->k", G, cn.cov_log, G)
        for i, e in enumerate(est):
            z = (e.bias - truth.gyro.sensors[i].bias) / np.sqrt(v0[i])
            out.append((z, dof_from_log_var(var_log[i]), tc))
    return np.array(out)


@pytest.mark.slow
def test_bias_z_is_not_student_t_with_the_fitted_dof():
    """Seeds 0-99 (where the selection threshold was chosen; ≈ 20 s): the refutation in
    the module docstring, 800 biases (4 gyros × 2 methods × 100 sessions).

    - Under z ~ t_ν the count of |z| > 3 has mean μ = Σ P_tν(|z| > 3) (measured 104) and
      is at least the 0.1 % quantile of Poisson(μ) (a Poisson-binomial has less spread
      than Poisson(μ)); observed 12.
    - Under z ~ t_ν, P_tν(|Z| ≥ |z|) is uniform: the fraction below 0.32 lies inside the
      99.9 % binomial interval of p = 0.32; observed 0.18.
    - The tails sit with short fitted τc, not with small ν: sd(z) > 1.4 where τ̂c < 60 s
      (measured 1.68) and < 0.5 where τ̂c > 400 s (0.16); all |z| > 3 have τ̂c < 150 s.
    """
    seq, truth, _ = preset("tetrad-paper")
    nm = SessionNoise(bias_instability={"gyro": 1.0 * DPH}, bias_correlation_s=100.0)
    rows = [_bias_z_dof(simulate_session(None, seq, truth, seed=s, noise=nm), truth)
            for s in DEV_SEEDS]
    assert all(r is not None for r in rows), "the Gauss-Markov term is kept in every session"
    z, nu, tau = np.concatenate(rows).T
    n_out = int(np.sum(np.abs(z) > 3))
    mu = float(np.sum(2 * scipy.stats.t.sf(3.0, nu)))
    assert n_out < scipy.stats.poisson.ppf(0.001, mu), (n_out, mu)
    pit = 2 * scipy.stats.t.sf(np.abs(z), nu)
    lo, hi = scipy.stats.binom.interval(0.999, z.size, 0.32)
    frac = int(np.sum(pit < 0.32))
    assert not lo <= frac <= hi, (frac, lo, hi)
    short, long_ = tau < 60.0, tau > 400.0
    assert np.std(z[short], ddof=1) > 1.4 and np.std(z[long_], ddof=1) < 0.5, (
        np.std(z[short], ddof=1), np.std(z[long_], ddof=1))
    assert np.all(tau[np.abs(z) > 3] < 150.0), tau[np.abs(z) > 3]
