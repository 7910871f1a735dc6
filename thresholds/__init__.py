"""rimu.thresholds: detection thresholds from calibration statistics, their selection and
tuning for a false-alarm rate, the oracle detector, and synthetic calibrations for tuning
and tests.

Evaluation campaigns (:mod:`thresholds.evaluate`, :mod:`thresholds.campaign`), the real
static noise checks (:mod:`thresholds.realnoise`) and the evidence on measured recordings
(:mod:`thresholds.field`) are imported from their modules: they use the flight simulation,
the flight folders and the readers of :mod:`replay`.
"""

from fdi.lazy import attach

_EXPORTS = {
    "DetectableSize": "thresholds.tune",
    "OracleResult": "thresholds.oracle",
    "SyntheticTruth": "thresholds.synthetic",
    "ThresholdChoice": "thresholds.select",
    "Tuning": "thresholds.tune",
    "allan_from_residuals": "thresholds.compute",
    "compute_thresholds": "thresholds.compute",
    "detectable_sizes": "thresholds.tune",
    "draw_truth": "thresholds.synthetic",
    "load_any_thresholds": "thresholds.select",
    "oracle_detect": "thresholds.oracle",
    "raw_samples": "thresholds.synthetic",
    "select": "thresholds.select",
    "synthetic_calibration": "thresholds.synthetic",
    "tune": "thresholds.tune",
}
"""Public name → module defining it (imported on first use, PEP 562)."""
__all__ = [
    "DetectableSize",
    "OracleResult",
    "SyntheticTruth",
    "ThresholdChoice",
    "Tuning",
    "allan_from_residuals",
    "compute_thresholds",
    "detectable_sizes",
    "draw_truth",
    "load_any_thresholds",
    "oracle_detect",
    "raw_samples",
    "select",
    "synthetic_calibration",
    "tune",
]

__getattr__, __dir__ = attach(__name__, _EXPORTS)
