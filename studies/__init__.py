"""studies: the evidence behind the docs, and the simulated truth the tests draw from.

Not part of the product: the wheel installs ``fdi``, ``calibration``, ``replay``,
``thresholds`` and ``rimu`` only (``pyproject.toml``), and no product module imports this
package (``tests/test_layers.py``). Run from a clone, at its root:

- ``python studies/make_drift.py``, ``make_field_results.py``, ``make_findings.py``,
  ``make_inflight_plots.py``, ``make_noise_tails.py``, ``make_timing_jitter.py``: each
  recomputes one evidence page of ``docs/`` from the recordings in ``../shared/data``
  (``RIMU_SHARED_DATA`` overrides), writing its numbers to ``studies/*.json`` and its
  figures to ``docs/img/``; the slow tests named in each page recompute and check them;
- :mod:`studies.field`, :mod:`studies.field_claims`: the monitor on measured flights and
  the claims checked on it (``docs/field-results.md``);
- :mod:`studies.realnoise`, :mod:`studies.tails_holdout`: held-out false alarms on real
  static noise and flights (``docs/noise-tails.md``, ``docs/drift.md``);
- :mod:`studies.synthetic`, :mod:`studies.oracle`, :mod:`studies.ferraris_sim`: synthetic
  calibrations, sensor samples with known truth, the oracle detector and simulated
  Ferraris sessions that the tests and benchmarks use as truth.
"""
