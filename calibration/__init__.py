"""rimu.calibration: turntable sessions (simulated or recorded) → calibration files.

Conventions are those of :mod:`fdi` (SI inside, MB frame, sensors numbered from 1 outside).
"""

from calibration.presets import preset
from calibration.sequence import Sequence, SequenceStep, load_sequence
from calibration.session import Session, Step
from calibration.session_io import load_session, save_session
from calibration.simulate import NoiseModel, simulate_session
from calibration.truth import load_truth, save_truth
from calibration.turntable import MOUNTS, body_inputs, earth_rate_n, gravity_local, mat_nb

__all__ = ["MOUNTS", "NoiseModel", "Sequence", "SequenceStep", "Session", "Step",
           "body_inputs", "earth_rate_n", "gravity_local", "load_sequence", "load_session",
           "load_truth", "mat_nb", "preset", "save_session", "save_truth", "simulate_session"]
