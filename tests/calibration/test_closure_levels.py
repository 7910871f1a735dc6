"""Level of the two probes issue 18's closure added (campaign: several minutes).

- Change points named ``bias_step`` (:func:`calibration.diagnose.selection._promote_steps`)
  and the stationarity of fitted lines (:mod:`calibration.diagnose.stationarity`) on clean
  sessions (white tetrad-paper and cone-paper, coloured tetrad-paper), α = 0.05 as in
  test_diagnose_clean.py: each session is assessed with both (the product) and without
  them (the selection as it was: no promotion, no stationarity probe, the probe family
  without the lines), and the count of sessions with anything found (a claim, a partial
  fit or "unexplained") must not exceed the 99.9 % quantile of Binomial(n, α), with and
  without; the sessions that gain a finding with the two probes must be none (they only
  relabel a failing change point, or act where a line is already claimed).
- The stationarity probe on honest lines: clean sessions with a line of constant
  amplitude (3 °/h, frequency and phase drawn per seed, on a drawn gyro) added by hand:
  the line is claimed on its gyro and the probe refuses it in at most the 99.9 %
  binomial quantile at the probe's own threshold; the probe's p-values below 0.05 (read
  on the final model of every session that claimed the line) at most the 99.9 % quantile
  of Binomial(n, 0.05).

The figures measured are quoted in docs/diagnose.md ("Line stationarity", "Change points
named bias_step").
"""

import numpy as np
import pytest
import scipy.stats
from _diagnose_sessions import add_signal, calibrate_fast, clean_fast
from test_diagnose_coloured import _coloured

from calibration.diagnose import assess, get_candidate
from calibration.diagnose import selection as selection_module
from calibration.diagnose.context import kind_data
from calibration.diagnose.stationarity import line_stationarity
from fdi.units import DPH

ALPHA = 0.05


def _found(sel):
    return bool(sel.claimed or sel.unexplained or sel.partial)


def _before_after(s, monkeypatch):
    """(found with the two probes, found without, the selection with them)."""
    cal = calibrate_fast(s)
    after = assess(s, cal, alpha=ALPHA)
    with monkeypatch.context() as m:
        m.setattr(selection_module, "_promote_steps", lambda *a, **k: None)
        m.setattr(selection_module, "_line_terms", lambda *a, **k: [])
        before = assess(s, cal, alpha=ALPHA)
    return _found(after), _found(before), after


def _interval(k, n):
    """Clopper-Pearson 95 % interval of k of n."""
    lo = scipy.stats.beta.ppf(0.025, k, n - k + 1) if k else 0.0
    hi = scipy.stats.beta.ppf(0.975, k + 1, n - k) if k < n else 1.0
    return round(float(lo), 4), round(float(hi), 4)


CLEAN = {"tetrad-paper": range(100, 200), "cone-paper": range(100, 200),
         "coloured tetrad-paper": range(300, 350)}


@pytest.mark.slow
@pytest.mark.campaign
@pytest.mark.parametrize("case", sorted(CLEAN))
def test_clean_sessions_level_with_and_without_the_closure_probes(case, monkeypatch):
    seeds = CLEAN[case]
    after, before, gained, promoted = [], [], [], []
    for seed in seeds:
        s = _coloured(seed)[0] if case.startswith("coloured") else clean_fast(case, seed)[0]
        a, b, sel = _before_after(s, monkeypatch)
        after.append(a)
        before.append(b)
        if a and not b:
            gained.append(seed)
        promoted += [(seed, p) for p in sel.promoted]
    n, ka, kb = len(seeds), sum(after), sum(before)
    print(f"\n{case}: anything found {ka}/{n} {_interval(ka, n)} with the closure probes, "
          f"{kb}/{n} {_interval(kb, n)} without; promoted {promoted}")
    bound = scipy.stats.binom.ppf(0.999, n, ALPHA)
    assert ka <= bound and kb <= bound, (ka, kb)
    assert not gained, gained


def _line_session(seed, coloured):
    rng = np.random.default_rng(5_000 + seed)
    s, truth = _coloured(seed) if coloured else clean_fast("tetrad-paper", seed)
    sensor = int(rng.integers(0, 4))
    f = float(rng.uniform(0.01, 0.2))
    t = s.t - s.t[0]
    line = 3.0 * DPH * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    return add_signal(s, truth, sensor, line), sensor, f


@pytest.mark.slow
@pytest.mark.campaign
@pytest.mark.parametrize("coloured,seeds", [(False, range(400, 500)), (True, range(300, 340))],
                         ids=["white", "coloured"])
def test_stationarity_probe_level_on_honest_lines(coloured, seeds):
    line = get_candidate("periodic_line")
    missed, refused, ps = [], [], []
    for seed in seeds:
        s, sensor, f = _line_session(seed, coloured)
        cal = calibrate_fast(s)
        sel = assess(s, cal, alpha=ALPHA)
        if any(u["test"] == "line_stationarity" for u in sel.unexplained):
            refused.append((seed, sensor, f))
        held = [c for c in sel.claimed + sel.partial
                if c.candidate.name == "periodic_line" and c.sensor == sensor]
        if not held:
            missed.append((seed, sensor, f))
            continue
        d = kind_data(s, cal)["gyro"]
        rec = line_stationarity(d, sensor, sel.models[("gyro", sensor)], line,
                                held[0].params)
        ps.append(rec["p_value"])
    ps = np.asarray(ps)
    n, k05 = ps.size, int(np.sum(ps < 0.05))
    print(f"\n{'coloured' if coloured else 'white'}: lines held {n}/{len(seeds)}, missed "
          f"{missed}; refused {len(refused)} {_interval(len(refused), len(seeds))}; "
          f"p < 0.05: {k05}/{n} {_interval(k05, n)}; p < 0.01: {int(np.sum(ps < 0.01))}; "
          f"KS uniform p {scipy.stats.kstest(ps, 'uniform').pvalue:.3g}")
    assert not missed, missed
    thr = (ALPHA / 2) / (len(selection_module.PROBES) * 4 + 1)
    assert len(refused) <= scipy.stats.binom.ppf(0.999, len(seeds), thr), refused
    assert k05 <= scipy.stats.binom.ppf(0.999, n, 0.05), (k05, n)
