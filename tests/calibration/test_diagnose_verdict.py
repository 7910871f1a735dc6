"""The detectability-aware adequacy verdict (issue 7.1: "no session with an effect beyond 5 σ
comes out of calibrate marked adequate, whatever the noise model").

Under a Gauss-Markov bias instability (tetrad-paper, 1 °/h, τc 100 s) a slow effect on one
gyro near the wander's size (warm-up 5 and 15 °/h, bias step 3 °/h, drift 10 °/h) moved a
parameter beyond 5 honest σ and still came out "adequate" in 1-3 of 10 sessions: one
session cannot tell it from the wander. "Adequate" now also requires that the session
*could* have seen every library effect that moves a parameter by 5 σ
(:mod:`calibration.diagnose.detect`); otherwise the verdict is "effects not ruled out",
with the limits.

Checked here:

- the power the rule computes for the profiled Gauss-Markov test is not optimistic where
  it matters: at the size the rule says is found with probability 0.99 the test finds the
  effect at least that often (binomial slack), and at mid-range sizes at least as often as
  predicted; the known-noise noncentrality, which the rule does not use, is shown to be
  optimistic (Monte Carlo on simulated white + Gauss-Markov sets, fixed seeds);
- the four failing cases, premise checked per seed against the honest σ: never
  "adequate";
- clean white sessions stay "adequate"; the file and the printout carry the verdict.
"""

import json

import numpy as np
import pytest
import scipy.stats
from _diagnose_sessions import add_signal, calibrate_fast, clean_fast
from scipy.signal import lfilter
from test_diagnose_coloured import _coloured
from threadpoolctl import threadpool_limits

from calibration.calibrate import calibrate
from calibration.calibrate_checked import calibrate_checked
from calibration.compare import compare
from calibration.diagnose import format_adequacy
from calibration.diagnose.coloured import GlsModel, NoiseSet, block_noise
from calibration.diagnose.detect import POWER, asimov_lr, power_at, size_for_power
from fdi.calfile import load_calibration
from fdi.errors import FileFormatError
from fdi.units import DPH

# -- power of the profiled test: Monte Carlo on simulated white + Gauss-Markov sets -------
FS, N, NS, SW, SB, TC = 100.0, 57_600, 4, 36.0, 1.0, 100.0
THR = 0.005 / 36                # the first Holm threshold at α 0.01 over 36 pairs
T_S = np.arange(N) / FS
EFFECTS = {"warmup": np.exp(-T_S / 300)[:, None], "drift": (T_S / T_S[-1])[:, None]}
MID = {"warmup": 16.0, "drift": 12.0}   # predicted power 0.6-0.8 (units of SW = 36)
LOW = {"warmup": 8.0, "drift": 6.0}     # known-noise prediction 0.6-0.75, observed ≤ 0.2


def _power_mc(reps, seed):
    """Per draw and effect: (predicted power at MID, its known-noise version at LOW,
    detected at MID, detected at LOW, detected at the size the rule gives power 0.99)."""
    rng = np.random.default_rng(seed)
    phi = np.exp(-1 / (FS * TC))
    bn = block_noise(N, FS)
    crit = float(scipy.stats.chi2.isf(THR, 1))
    out = {k: [] for k in EFFECTS}
    with threadpool_limits(limits=1, user_api="blas"):
        for _ in range(reps):
            w = rng.standard_normal((N, NS)) * SB * np.sqrt(1 - phi**2)
            g = lfilter([1.0], [1.0, -phi], w, axis=0,
                        zi=(phi * SB * rng.standard_normal(NS))[None, :])[0]
            y = SW * rng.standard_normal((N, NS)) + g
            grp = NoiseSet(bn)
            ones = np.ones((N, 1))
            models = [GlsModel(y[:, i], ones, grp, i) for i in range(NS)]
            for k, Z in EFFECTS.items():
                gr = models[0].detect_grids(Z)           # on the clean draw, as the rule
                gk, sw2 = models[0].known_noise(Z)
                b, a_mid = np.ones(1), MID[k]
                a99 = size_for_power(lambda m, gr=gr, b=b, a=a_mid: asimov_lr(gr, b, m * a),
                                     crit, 1, a_mid)
                row = [power_at(asimov_lr(gr, b, MID[k]), crit, 1),
                       power_at(LOW[k] ** 2 * gk[0, 0] / sw2, crit, 1)]
                for a in (MID[k], LOW[k], a99):
                    ft = GlsModel(y[:, 0] + a * Z[:, 0], ones, grp, 0).test(Z)
                    row.append(ft.ss > crit)
                GlsModel(y[:, 0], ones, grp, 0)          # restore the clean grid
                out[k].append(row)
    return {k: np.array(v, float) for k, v in out.items()}


def _check_power(res, reps):
    lo = scipy.stats.binom.ppf(0.001, reps, POWER)
    for k, v in res.items():
        pred_mid, known_low, det_mid, det_low, det99 = v.T
        # where the rule says "found with probability 0.99", it is
        assert det99.sum() >= lo, (k, det99.sum(), lo)
        # mid-range: found at least as often as predicted (lower 99.9 % binomial bound)
        assert det_mid.sum() >= scipy.stats.binom.ppf(0.001, reps, pred_mid.mean()), \
            (k, det_mid.mean(), pred_mid.mean())
        # the known-noise noncentrality would have been optimistic (why the rule re-fits
        # the noise): fewer detections than even its lower 99.9 % bound
        assert det_low.sum() < scipy.stats.binom.ppf(0.001, reps, known_low.mean()), \
            (k, det_low.mean(), known_low.mean())


def test_profiled_power_is_not_optimistic():
    """15 draws (seed 21); the slow version runs 30 more."""
    _check_power(_power_mc(15, seed=21), 15)


@pytest.mark.slow
def test_profiled_power_is_not_optimistic_mc():
    _check_power(_power_mc(30, seed=22), 30)


# -- the failing cases under coloured noise -------------------------------------------------
def _honest_z(seed, make):
    """Largest |error/σ| of the gyro parameters, σ the coloured-noise calibration's of the
    same seed without the effect (the premise of ``_effect_case`` in
    test_diagnose_coloured.py), and the session with the effect."""
    s0, truth = _coloured(seed)
    sd = {(r.sensor, r.parameter): r.sd
          for r in compare(calibrate(s0, allan=False, earth_rate=False), truth)}
    s, truth, eff = make(seed, s0, truth)
    z = [r.error / sd[(r.sensor, r.parameter)]
         for r in compare(calibrate_fast(s), truth, eff) if r.kind == "gyro"]
    return float(np.max(np.abs(z))), s


def _knob(name, value, sensors):
    def make(seed, s0, truth):
        s, truth = _coloured(seed, {name: value}, sensors)
        return s, truth, {name: value}
    return make


def _step(value):
    def make(seed, s0, truth):
        t = s0.t - s0.t[0]
        return add_signal(s0, truth, 0, value * DPH * (t >= t[-1] / 2)), truth, {}
    return make


FAILING = {"warmup 5 deg/h": (_knob("warmup", 5.0, [3]), (402,)),
           "warmup 15 deg/h": (_knob("warmup", 15.0, [3]), (400, 408)),
           "bias step 5 deg/h": (_step(5.0), (401, 402)),
           "bias drift 10 deg/h": (_knob("bias_drift", 10.0, [2]), (404, 408))}
"""Per case, seeds of 400-409 whose premise holds (the measured largest |error/σ|, σ of the
coloured-noise calibration at the upper end of the τc interval: warm-up 5 °/h 6.1 on 402,
also run by default; warm-up 15 °/h 8.8, 8.5; step 5 °/h 5.5, 5.9; drift 6.0, 6.2). With the
earlier σ (maximum-likelihood τc) they were 12.1 on 402 and 6.2 on 401; 5.8, 8.5; a 3 °/h
step 7.8, 5.7 on 401, 402; 9.6, 6.2. With the present σ a 3 °/h step is beyond 5σ on none
of 400-409 (at most 3.8), so the case is run at 5 °/h. Over
all of 400-409 (docs/diagnose.md) the four cases came out "effects suspected" or "effects
not ruled out", never "adequate"."""


def _never_adequate(make, seeds):
    checked = 0
    for seed in seeds:
        z, s = _honest_z(seed, make)
        if z <= 5:                      # premise not met on this seed: nothing to claim
            continue
        checked += 1
        a = calibrate_checked(s, allan=False, earth_rate=False).adequacy
        assert a["verdict"] in ("effects not ruled out", "effects suspected"), (seed, z, a)
        if a["verdict"] == "effects not ruled out":
            assert a["not_ruled_out"] and a["noise_model_applied"] == "auto", (seed, a)
    return checked


def test_warmup_near_the_wander_is_never_adequate():
    """Warm-up 5 °/h on gyro 3 under the wander, seed 402: 6.1 honest σ off; never
    "adequate"."""
    assert _never_adequate(FAILING["warmup 5 deg/h"][0], (402,)) == 1


@pytest.mark.slow
@pytest.mark.parametrize("case", list(FAILING), ids=lambda c: c.replace(" ", "_"))
def test_failing_cases_are_never_adequate_mc(case):
    """Seeds whose premise holds (:data:`FAILING`; before this check the four cases came
    out "adequate" beyond 5 honest σ in 1-3 of 10 sessions)."""
    make, seeds = FAILING[case]
    assert _never_adequate(make, seeds) == len(seeds)


# -- clean white sessions, the file, the printout ---------------------------------------------
def test_clean_white_session_stays_adequate_and_lists_the_sequence_limits():
    """White noise: the session's power is the white-noise power, so no "session" limit
    can arise; what the sequence itself cannot separate at 5 σ (a warm-up or drift that
    also moves the bias) is listed apart as ``sequence_limits``, printed, and qualifies the
    verdict: "adequate within sequence limits" (tetrad-paper has such limits in every
    session), with what to do."""
    s, _ = clean_fast("tetrad-paper", 4)
    cal = calibrate_checked(s, allan=False, earth_rate=False)
    a = cal.adequacy
    assert a["noise_null"]["gyro"] == "white"
    assert a["verdict"] == "adequate within sequence limits" and a["not_ruled_out"] == []
    names = {r["name"] for r in a["sequence_limits"]}
    assert "warmup" in names, names
    for r in a["sequence_limits"]:
        assert r["power"] < POWER and r["power_white"] == pytest.approx(r["power"], abs=1e-9)
    text = "\n".join(format_adequacy(cal))
    assert "limits of the sequence" in text and "not ruled out" not in text
    assert "what to do: no repetition of this sequence" in text


def test_power_beyond_scipys_range_is_one_not_nan():
    """scipy's ncx2.sf gives NaN for a noncentrality near 1e22 (a time skew on the
    cone-paper accelerometers, whose static positions it barely touches: it needs ~1e7 s to
    move a misalignment by 5 σ and was listed as a sequence limit with power NaN). The
    normal approximation takes over there; where both are defined they agree."""
    assert power_at(4.0e22, 16.1, 1) == 1.0
    assert power_at(1.0, 16.1, 1) == pytest.approx(scipy.stats.ncx2.sf(16.1, 1, 1.0))
    for lam in (1e5, 1e7):
        sd = np.sqrt(2 * (1 + 2 * lam))
        for k in (-2.0, 0.0, 2.0):
            crit = lam + 1 + k * sd
            normal = scipy.stats.norm.sf((crit - 1 - lam) / sd)
            assert abs(scipy.stats.ncx2.sf(crit, 1, lam) - normal) < 0.01, (lam, k)


def test_cone_paper_limits_are_finite_and_physical():
    """The regression behind the test above, on the session where it was seen."""
    s, _ = clean_fast("cone-paper", 3)
    cal = calibrate_checked(s, allan=False, earth_rate=False)
    recs = cal.adequacy["sequence_limits"] + cal.adequacy["not_ruled_out"]
    assert all(np.isfinite(r["power"]) and r["power"] < POWER for r in recs), recs
    assert "time_skew" not in {r["name"] for r in recs}


def test_not_ruled_out_file_round_trip_and_bad_verdict(tmp_path):
    s, _ = _coloured(seed=2)
    cal = calibrate_checked(s, allan=False, earth_rate=False)
    assert cal.adequacy["verdict"] == "effects not ruled out"
    p = tmp_path / "cal.json"
    cal.save(p)
    back = load_calibration(p)
    assert back.adequacy["verdict"] == "effects not ruled out"
    assert back.adequacy["not_ruled_out"] == json.loads(json.dumps(
        cal.adequacy["not_ruled_out"]))
    assert format_adequacy(back) == format_adequacy(cal)
    # a /2 file written before the check (two verdicts, no limits) still loads
    doc = json.loads(p.read_text())
    doc["adequacy"] = {"verdict": "adequate", "alpha": 0.01, "where": []}
    p.write_text(json.dumps(doc))
    assert load_calibration(p).adequacy["verdict"] == "adequate"
    doc["adequacy"]["verdict"] = "fine"
    p.write_text(json.dumps(doc))
    with pytest.raises(FileFormatError, match=r"adequacy.*verdict"):
        load_calibration(p)
