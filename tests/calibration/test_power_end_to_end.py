"""End-to-end power through the product's own limits (calibration.diagnose.detect): the
size the rule reports as found with probability 0.99 (its critical value, scan
multiplicity included) is injected by hand into fresh white-noise sessions and the
selection must find it on the right sensor at least as often as Binomial(n, 0.99) allows.
Measured: found on the right sensor 30 of 30, named ``bias_step`` 26 of 30 (the others
named a slow drift or warm-up, which a mid-session step resembles): the power promised is
that of the step's own test, not of its identification against the other candidates.

White noise, where the power formula is exact: a wrong critical value in the limits (a
scan multiplicity dropped, α not halved) moves the reported size, and the detections
fall below the band.
"""

import numpy as np
import pytest
import scipy.stats
from _diagnose_sessions import add_signal, calibrate_fast, clean_fast

import calibration.diagnose.detect as det
from calibration.diagnose.context import kind_data
from calibration.diagnose.library import get_candidate, model_effects
from calibration.diagnose.run import assess
from fdi.units import DPH

ALPHA = 0.01


def _limit(name: str, monkeypatch) -> dict:
    """The product's least detectable point of ``name`` on a clean session (seed 0), asked
    at a small shift so that a record is returned."""
    s, _ = clean_fast("tetrad-paper", 0)
    cal = calibrate_fast(s)
    sel = assess(s, cal, alpha=ALPHA, noise="white")
    monkeypatch.setattr(det, "SHIFT_SIGMA", 0.3)
    datas = model_effects(kind_data(s, cal), cal.effects)
    (rec, *_) = det.limits(datas, sel.models, cal, ALPHA, sel.family_size,
                           cands=[get_candidate(name)])
    return rec


@pytest.mark.slow
def test_bias_step_at_the_reported_99_percent_size_is_found(monkeypatch) -> None:
    rec = _limit("bias_step", monkeypatch)
    i, t0, size = rec["sensor"] - 1, rec["params"]["time_s"], rec["size_for_power"]
    n, found, named = 30, 0, 0
    for seed in range(300, 300 + n):
        s, truth = clean_fast("tetrad-paper", seed)
        s = add_signal(s, truth, i, size * DPH * (s.t - s.t[0] >= t0))
        sel = assess(s, calibrate_fast(s), alpha=ALPHA, noise="white")
        on_i = [c.candidate.name for c in sel.claimed if c.sensor == i and c.kind == "gyro"]
        found += bool(on_i)
        named += "bias_step" in on_i
        assert all(c.sensor == i for c in sel.claimed), sel.claimed
    # found on the right sensor as often as the rule promises (measured: 30 of 30)
    assert found >= scipy.stats.binom.ppf(0.001, n, det.POWER), (found, n, size)
    # ... but a step at mid-session competes with the slow candidates: measured 26 of 30
    # named bias_step, 4 named bias_drift or warmup (the power is the step test's alone)
    assert named >= n // 2, named
    # and not trivially: at 40 % of that size (power near 0.2 for one degree of freedom
    # at these thresholds) it is found far less often
    low = 0
    for seed in range(400, 410):
        s, truth = clean_fast("tetrad-paper", seed)
        s = add_signal(s, truth, i, 0.4 * size * DPH * (s.t - s.t[0] >= t0))
        sel = assess(s, calibrate_fast(s), alpha=ALPHA, noise="white")
        low += any(c.candidate.name == "bias_step" and c.sensor == i for c in sel.claimed)
    assert low <= 8, low
    assert np.isfinite(size) and size > 0


@pytest.mark.slow
def test_predicted_power_mid_range_matches_the_products_own_test(monkeypatch) -> None:
    """At the size the limit reports for a 5-σ shift (predicted power in mid-range), the
    product's own step test (scan multiplicity in its p, first Holm threshold) on fresh
    sessions detects it as often as predicted: within the two-sided 99.8 % binomial band
    (measured: predicted 0.45, detected 23 of 40; with the scan multiplicity dropped from
    the limit's critical value the band moves to 26-40 and the test fails).
    The test scans the step time while the prediction is for the reported time, so
    detections may run a little above the prediction, never far below."""
    from calibration.diagnose.selection import Selection, _evaluate, _family

    s, _ = clean_fast("tetrad-paper", 0)
    cal = calibrate_fast(s)
    sel = assess(s, cal, alpha=ALPHA, noise="white")
    c = get_candidate("bias_step")
    datas = model_effects(kind_data(s, cal), cal.effects)
    rec = min(det.limits(datas, sel.models, cal, ALPHA, sel.family_size, cands=[c]),
              key=lambda r: abs(r["power"] - 0.5))
    pred, size = rec["power"], rec["size"]
    assert 0.1 < pred < 0.9, pred
    i, t0 = rec["sensor"] - 1, rec["params"]["time_s"]
    thr = (ALPHA / 2) / sel.family_size
    n, hits = 40, 0
    for seed in range(500, 500 + n):
        s, truth = clean_fast("tetrad-paper", seed)
        s = add_signal(s, truth, i, size * DPH * (s.t - s.t[0] >= t0))
        cal = calibrate_fast(s)
        d = model_effects(kind_data(s, cal), cal.effects)
        out = Selection()
        _family(d, [c], out, "white")
        _, logp, *_ = _evaluate(d["gyro"], i, c, out.models[("gyro", i)])
        hits += logp < np.log(thr)
    lo = scipy.stats.binom.ppf(0.001, n, pred)
    hi = scipy.stats.binom.isf(0.001, n, min(1.0, pred + 0.15))
    assert lo <= hits <= hi, (hits, n, pred)
