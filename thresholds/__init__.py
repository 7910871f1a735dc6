"""rimu.thresholds: detection thresholds from calibration statistics, their selection and
tuning for a false-alarm rate, the oracle detector, and synthetic calibrations for tuning
and tests.

Evaluation campaigns (:mod:`thresholds.evaluate`, :mod:`thresholds.campaign`), the real
static noise checks (:mod:`thresholds.realnoise`) and the evidence on measured recordings
(:mod:`thresholds.field`) are imported from their modules: they use the flight simulation,
the flight folders and the readers of :mod:`replay`.
"""

from thresholds.compute import allan_from_residuals, compute_thresholds
from thresholds.oracle import OracleResult, oracle_detect
from thresholds.select import ThresholdChoice, load_any_thresholds, select
from thresholds.synthetic import SyntheticTruth, draw_truth, raw_samples, synthetic_calibration
from thresholds.tune import DetectableSize, Tuning, detectable_sizes, tune

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
