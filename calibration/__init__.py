"""rimu.calibration: turntable sessions (simulated or recorded) → calibration files.

Conventions are those of :mod:`fdi` (SI inside, MB frame, sensors numbered from 1 outside).
"""

from calibration.calibrate import calibrate
from calibration.compare import compare, format_comparison
from calibration.earth_rate import fit_earth_rate
from calibration.multiposition import multiposition
from calibration.presets import preset
from calibration.rate_test import rate_test
from calibration.repeat import repeat_sessions, repeatability
from calibration.sequence import Sequence, SequenceStep, load_sequence
from calibration.session import Session, Step
from calibration.session_io import load_session, save_session
from calibration.simulate import NoiseModel, simulate_session
from calibration.stack import stack_sessions
from calibration.truth import load_truth, save_truth
from calibration.turntable import MOUNTS, body_inputs, earth_rate_n, gravity_local, mat_nb
from calibration.wavelet import denoise

__all__ = [
    "MOUNTS",
    "NoiseModel",
    "Sequence",
    "SequenceStep",
    "Session",
    "Step",
    "body_inputs",
    "calibrate",
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
