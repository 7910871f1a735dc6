"""thresholds: detection thresholds from calibration statistics, their selection and tuning
for a false-alarm rate (imported as ``thresholds``).

Evaluation campaigns (:mod:`thresholds.evaluate`, :mod:`thresholds.campaign`) are imported
from their modules: they use the flight simulation and the readers of :mod:`replay`. The
evidence studies on measured recordings and the synthetic calibrations of the tests live in
the repository's ``studies/`` folder, which the wheel does not install.
"""

from fdi.lazy import attach

_EXPORTS = {
    "DetectableSize": "thresholds.tune",
    "ThresholdChoice": "replay.threshold_choice",
    "Tuning": "thresholds.tune",
    "allan_from_residuals": "thresholds.compute",
    "compute_thresholds": "thresholds.compute",
    "detectable_sizes": "thresholds.tune",
    "load_any_thresholds": "replay.threshold_choice",
    "select": "replay.threshold_choice",
    "tune": "thresholds.tune",
}
"""Public name → module defining it (imported on first use, PEP 562)."""
__all__ = [
    "DetectableSize",
    "ThresholdChoice",
    "Tuning",
    "allan_from_residuals",
    "compute_thresholds",
    "detectable_sizes",
    "load_any_thresholds",
    "select",
    "tune",
]

__getattr__, __dir__ = attach(__name__, _EXPORTS)
