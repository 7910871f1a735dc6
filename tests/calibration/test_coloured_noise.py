"""Honest uncertainties under coloured noise (``calibrate(..., noise_model="auto")``).

The white-noise covariances are exact only for white noise. With a Gauss-Markov bias
instability the step means are correlated over several steps and the bias σ is several
times too small; ``noise_model="auto"`` fits a white + Gauss-Markov model common to the set
to the residual spectrum and adds its exact covariance over the segment means, at the
correlation time with the largest bias variance within the profile-likelihood interval,
cut at a quarter of the record. Seeds 0-99 are the development seeds: the selection
threshold and the two constants of that σ rule were chosen on them; the check on seeds
never used for choosing is test_calibrate_coloured_holdout.py.
"""

import numpy as np
import pytest

from calibration.calibrate import calibrate
from calibration.compare import compare
from calibration.presets import preset
from calibration.residuals import (
    GM_LR_THRESHOLD,
    GM_SIGMA_CAP_RECORDS,
    GM_SIGMA_DELTA_NLL,
    GaussMarkovFit,
    fit_gauss_markov,
    gauss_markov_segment_corr,
    gauss_markov_sigma_candidates,
)
from calibration.simulate import SessionNoise, simulate_session
from fdi.errors import CalibrationError
from fdi.units import DPH

BI_DPH = 1.0
TAU_C_S = 100.0
MC_SEEDS = range(100)


def _coloured(bi_dph=BI_DPH, seed=0):
    seq, truth, _ = preset("tetrad-paper")
    nm = SessionNoise(bias_instability={"gyro": bi_dph * DPH}, bias_correlation_s=TAU_C_S)
    return simulate_session(None, seq, truth, seed=seed, noise=nm), truth


def test_segment_corr_matches_a_discrete_sum():
    """Closed form of the Gauss-Markov covariance of interval means against a direct sum
    of exp(-|t-s|/τc) over a fine grid (three adjacent intervals and one after a gap)."""
    fs, tc = 20.0, 7.0
    start = np.array([0.0, 3.0, 8.0, 20.0])
    length = np.array([3.0, 5.0, 2.0, 4.0])
    K = gauss_markov_segment_corr(start, length, tc)
    ts = [s + (np.arange(int(L * fs)) + 0.5) / fs for s, L in zip(start, length, strict=True)]
    Kd = np.array([[np.mean(np.exp(-np.abs(a[:, None] - b[None, :]) / tc)) for b in ts]
                   for a in ts])
    np.testing.assert_allclose(K, Kd, rtol=2e-3, err_msg="segment-mean covariance")


def test_fit_finds_a_gauss_markov_bias_and_keeps_white_noise_white():
    rng = np.random.default_rng(3)
    fs, N, n, sd_b, tc = 100.0, 57_600, 4, 1.0, 100.0
    phi = np.exp(-1 / (fs * tc))
    from scipy.signal import lfilter
    gm = lfilter([1.0], [1.0, -phi], rng.standard_normal((N, n)) * sd_b * np.sqrt(1 - phi**2),
                 axis=0, zi=(phi * sd_b * rng.standard_normal(n))[None, :])[0]
    white = 36.0 * rng.standard_normal((N, n))
    f = fit_gauss_markov(white + gm, fs)
    assert f.bias_var > 0 and f.lr > GM_LR_THRESHOLD, f
    # one fit: the amplitude within a factor 2, the correlation time within a factor 4
    assert 0.5 < np.sqrt(f.bias_var) / sd_b < 2.0, f
    assert tc / 4 < f.tau_c < tc * 4, f
    np.testing.assert_allclose(f.white_var, 36.0**2, rtol=0.05, err_msg="white variance")
    f0 = fit_gauss_markov(white, fs)
    assert f0.bias_var == 0.0 and np.isinf(f0.tau_c), f0


def test_sigma_candidates_are_the_profile_interval_below_the_cut():
    """The interval {−log L ≤ min + Δ} over the τc grid, cut at a quarter of the record; the
    best point below the cut when the whole interval lies beyond it; nothing when white."""
    tau = np.array([10.0, 50.0, 100.0, 200.0, 400.0])
    bv = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    d = GM_SIGMA_DELTA_NLL

    def fit(nll, record_s=400.0):
        return GaussMarkovFit(np.ones(4), 2.0, 50.0, 10.0, None, tau, bv,
                              np.asarray(nll, float), record_s)

    t, v, cut = gauss_markov_sigma_candidates(fit([d + 1, 0.0, d - 0.1, d + 0.1, d + 2]))
    assert list(t) == [50.0, 100.0] and list(v) == [2.0, 3.0] and not cut
    t, _, cut = gauss_markov_sigma_candidates(fit([d + 1, 0.0, 0.1, 0.2, 0.3], 400.0))
    assert list(t) == [50.0, 100.0] and cut, "interval runs past record/4 = 100 s"
    assert GM_SIGMA_CAP_RECORDS * 400.0 == 100.0
    t, v, cut = gauss_markov_sigma_candidates(fit([9.0, 5.0, 6.0, 0.0, 0.1], 400.0))
    assert list(t) == [50.0] and list(v) == [2.0] and cut, "best below the cut"
    white = GaussMarkovFit(np.ones(4), 0.0, np.inf, 1.0, record_s=400.0)
    assert [x.size for x in gauss_markov_sigma_candidates(white)[:2]] == [0, 0]


def test_auto_equals_white_on_a_white_session(tetrad_session):
    cw = calibrate(tetrad_session, allan=False, noise_model="white")
    ca = calibrate(tetrad_session, allan=False, noise_model="auto")
    assert ca.extra["noise_model"]["gyro"]["applied"] is False
    for w, a in zip(cw.gyro.sensors, ca.gyro.sensors, strict=True):
        assert a.bias_sd == w.bias_sd and a.scale_factor_sd == w.scale_factor_sd, a.name


def test_auto_widens_the_coloured_session_and_records_it():
    s, _ = _coloured(seed=1)
    cw = calibrate(s, allan=False, earth_rate=False, noise_model="white")
    ca = calibrate(s, allan=False, earth_rate=False)
    rec = ca.extra["noise_model"]["gyro"]
    assert rec["applied"] is True and rec["likelihood_ratio"] > GM_LR_THRESHOLD
    assert 0 < rec["sigma_correlation_s"] <= GM_SIGMA_CAP_RECORDS * rec["record_s"], rec
    assert isinstance(rec["sigma_cut"], bool)
    assert "auto" in ca.extra["noise_model"]["method"]
    for i, (w, a) in enumerate(zip(cw.gyro.sensors, ca.gyro.sensors, strict=True)):
        assert a.bias == w.bias and a.scale_factor == w.scale_factor, "estimates unchanged"
        assert a.bias_sd > 1.5 * w.bias_sd, f"bias sd of {a.name}"
        assert a.scale_factor_sd >= w.scale_factor_sd, f"SF sd of {a.name}"
        np.testing.assert_allclose(rec["sd_factor"]["bias"][i], a.bias_sd / w.bias_sd,
                                   rtol=1e-9, err_msg=f"recorded bias factor of {a.name}")
        assert np.all(np.linalg.eigvalsh(a.input_error_cov - w.input_error_cov) > -1e-30)
    Vw = np.asarray(cw.extra["parity_calibrated_sd"])
    Va = np.asarray(ca.extra["parity_calibrated_sd"])
    assert np.all(Va >= Vw * (1 - 1e-12)), "v_c sd"


def test_unknown_noise_model_is_refused(tetrad_session):
    with pytest.raises(CalibrationError, match="noise model"):
        calibrate(tetrad_session, noise_model="pink")


def _z_scores(bi_dph, seeds):
    """z = error/σ per "sensor parameter" (auto noise model) and, for the biases and scale
    factors, the z the white-noise σ would give (from the recorded sd factors)."""
    z_auto: dict[str, list[float]] = {}
    z_white: dict[str, list[float]] = {}
    for seed in seeds:
        s, truth = _coloured(bi_dph, seed=seed)
        cal = calibrate(s, allan=False, earth_rate=False)
        fac = cal.extra["noise_model"]["gyro"]["sd_factor"]
        names = [c.name for c in truth.gyro.sensors]
        for r in compare(cal, truth):
            z_auto.setdefault(f"{r.sensor} {r.parameter}", []).append(r.z)
            if r.parameter in ("bias", "scale_factor"):
                z_white.setdefault(f"{r.sensor} {r.parameter}", []).append(
                    r.z * fac[r.parameter][names.index(r.sensor)])
        gb = cal.extra["gyro_bias"]
        f = DPH if gb["unit"] == "deg/h" else 3600.0 * DPH
        for i, c in enumerate(truth.gyro.sensors):
            z_auto.setdefault(f"{c.name} bias_turns", []).append(
                (gb["turns"][i] * f - c.bias) / (gb["turns_sd"][i] * f))
    assert len(z_auto) == 4 * 5, sorted(z_auto)
    return ({k: np.asarray(v) for k, v in z_auto.items()},
            {k: np.std(v, ddof=1) for k, v in z_white.items()})


def _bad(zs, max_out):
    bad = []
    for k, z in zs.items():
        sd, mean, n_out = np.std(z, ddof=1), np.mean(z), int(np.sum(np.abs(z) > 3))
        if not (0.75 <= sd <= 1.25) or abs(mean) > 3 / np.sqrt(z.size) or (
                max_out is not None and n_out > max_out):
            bad.append(f"{k}: sd(z) {sd:.2f}, mean(z) {mean:+.2f}, |z|>3: {n_out}")
    return bad


@pytest.mark.slow
def test_coloured_noise_z_spread_1dph():
    """100 seeds, bias instability 1 °/h (τc 100 s) on tetrad-paper: every bias (both
    methods), scale factor and misalignment angle has sd(error/σ) within ±25 % of 1 (the
    sd of a 100-sample sd is ≈ 0.07, so ±25 % is 3.5 standard errors), mean within 3/√100
    and at most 2 |z| > 3 (the criteria of the white-noise acceptance test). With the
    white-noise covariance the bias spread is ≈ 3.5 (measured; asserted > 2.5 as the
    reason for the model). Measured: biases 0.80-0.88, 0 of 800 beyond 3σ (0.87-1.05 and
    12 of 800 with the σ at the maximum-likelihood τc); SF 0.93-1.05; angles 0.95-1.10."""
    zs, sd_white = _z_scores(1.0, MC_SEEDS)
    assert min(v for k, v in sd_white.items() if k.endswith("bias")) > 2.5, sd_white
    bad = _bad(zs, max_out=2)
    assert not bad, "dishonest uncertainties under coloured noise:\n" + "\n".join(bad)


@pytest.mark.slow
def test_coloured_noise_z_spread_half_dph():
    """60 other seeds (100-159), 0.5 °/h: scale factors and misalignment angles keep
    sd(z) within ±25 % of 1 (2.7 standard errors of a 60-sample sd), mean within 3/√60.

    NOT asserted, because it does not hold: the biases. At 0.5 °/h the Gauss-Markov term is
    near the detection limit of a 576 s session; the likelihood-ratio test keeps white
    noise in about 1 session in 5, whose bias σ stay ≈ 2× too small. Measured sd(z) of the
    biases (both methods): 1.05-1.42 over seeds 100-199 (white σ: ≈ 2.0), 0.93-1.10 over
    seeds 0-99 (on which the threshold 2.71 was chosen), with the σ at the
    maximum-likelihood τc; with the profile-interval σ 1.09-1.47 over seeds 100-159."""
    zs, sd_white = _z_scores(0.5, range(100, 160))
    assert min(v for k, v in sd_white.items() if k.endswith("bias")) > 1.5, sd_white
    bad = _bad({k: v for k, v in zs.items() if "bias" not in k}, max_out=None)
    assert not bad, "dishonest uncertainties under coloured noise:\n" + "\n".join(bad)
