"""calibration: turntable sessions (simulated or recorded) → calibration files (imported as
``calibration``).

Conventions are those of :mod:`fdi` (SI inside, MB frame, sensors numbered from 1 outside).
"""

from fdi.lazy import attach

_EXPORTS = {
    "MOUNTS": "calibration.turntable",
    "Sequence": "calibration.sequence",
    "SequenceStep": "calibration.sequence",
    "Session": "calibration.session",
    "SessionNoise": "calibration.simulate",
    "Step": "calibration.session",
    "body_inputs": "calibration.turntable",
    "calibrate": "calibration.calibrate",
    "calibrate_checked": "calibration.calibrate_checked",
    "compare": "calibration.compare",
    "denoise": "calibration.wavelet",
    "earth_rate_n": "calibration.turntable",
    "fit_earth_rate": "calibration.earth_rate",
    "format_comparison": "calibration.compare",
    "gravity_local": "calibration.turntable",
    "load_sequence": "calibration.sequence",
    "load_session": "calibration.session_io",
    "load_truth": "calibration.truth",
    "mat_nb": "calibration.turntable",
    "multiposition": "calibration.multiposition",
    "preset": "calibration.presets",
    "rate_test": "calibration.rate_test",
    "repeat_sessions": "calibration.repeat",
    "repeatability": "calibration.repeat",
    "save_session": "calibration.session_io",
    "save_truth": "calibration.truth",
    "simulate_session": "calibration.simulate",
    "stack_sessions": "calibration.stack",
}
"""Public name → module defining it (imported on first use, PEP 562)."""
__all__ = [
    "MOUNTS",
    "Sequence",
    "SequenceStep",
    "Session",
    "SessionNoise",
    "Step",
    "body_inputs",
    "calibrate",
    "calibrate_checked",
    "compare",
    "denoise",
    "earth_rate_n",
    "fit_earth_rate",
    "format_comparison",
    "gravity_local",
    "load_sequence",
    "load_session",
    "load_truth",
    "mat_nb",
    "multiposition",
    "preset",
    "rate_test",
    "repeat_sessions",
    "repeatability",
    "save_session",
    "save_truth",
    "simulate_session",
    "stack_sessions",
]

__getattr__, __dir__ = attach(__name__, _EXPORTS)
