"""rimu.calibration: turntable sessions (simulated or recorded) → calibration files.

Conventions are those of :mod:`fdi` (SI inside, MB frame, sensors numbered from 1 outside).
"""

from calibration.sequence import Sequence, SequenceStep, load_sequence
from calibration.session import Session, Step
from calibration.turntable import MOUNTS, body_inputs, earth_rate_n, gravity_local, mat_nb

__all__ = ["MOUNTS", "Sequence", "SequenceStep", "Session", "Step", "body_inputs",
           "earth_rate_n", "gravity_local", "load_sequence", "mat_nb"]
