"""Clean sessions: how often does rimu diagnose claim an effect or "unexplained"?

The selection (Holm at α/2 over candidates × sensors) and the probes (Bonferroni at α/2
over probes × sensors) together bound the family-wise false-claim rate by α. Over n clean
sessions the count of sessions with any claim must not exceed the 99.9 % quantile of
Binomial(n, α) (a test that fails by chance once in a thousand runs). α = 0.05 here so that
the bound has teeth (expected ≤ 5 of 100).
"""

import pytest
import scipy.stats
from _diagnose_sessions import calibrate_fast, clean_fast

from calibration.diagnose import assess

ALPHA = 0.05


def _claims(name, seeds):
    bad = []
    for seed in seeds:
        s, _ = clean_fast(name, seed)
        sel = assess(s, calibrate_fast(s), alpha=ALPHA)
        if sel.claimed or sel.unexplained or sel.partial:
            bad.append((seed, [(c.candidate.name, c.kind, c.sensor + 1) for c in sel.claimed],
                        [(u["kind"], u["sensor"], u["test"]) for u in sel.unexplained]))
    return bad


def _bound(n):
    return int(scipy.stats.binom.ppf(0.999, n, ALPHA))


@pytest.mark.parametrize("name", ["tetrad-paper", "cone-paper"])
def test_clean_sessions_few_claims(name):
    seeds = range(3)
    bad = _claims(name, seeds)
    assert len(bad) <= _bound(len(seeds)), bad


@pytest.mark.slow
@pytest.mark.parametrize("name", ["tetrad-paper", "cone-paper"])
def test_clean_sessions_false_claim_rate(name):
    seeds = range(100, 200)
    bad = _claims(name, seeds)
    assert len(bad) <= _bound(len(seeds)), bad
