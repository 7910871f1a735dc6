"""rimu.thresholds: detection thresholds from calibration statistics, the oracle detector,
and synthetic calibrations for tuning and tests."""

from thresholds.compute import allan_from_residuals, compute_thresholds
from thresholds.oracle import OracleResult, oracle_detect
from thresholds.synthetic import SyntheticTruth, draw_truth, raw_samples, synthetic_calibration

__all__ = [
    "OracleResult",
    "SyntheticTruth",
    "allan_from_residuals",
    "compute_thresholds",
    "draw_truth",
    "oracle_detect",
    "raw_samples",
    "synthetic_calibration",
]
