"""rimu.fdi: geometry, parity space and the streaming fault detection and isolation runtime.

Conventions (hold for every rimu package)
-----------------------------------------
- Units: SI inside: rad/s, m/s², s. Other units only at the edges, through the named
  constants of :mod:`fdi.units`; names carry the unit where it is not SI (``rate_dps``).
- Frames: the master-body (MB) frame of seed 001; ``vec_b`` is a vector in MB, ``mat_nb``
  the direction-cosine matrix from MB to the navigation (local-level ENU) frame, as pyins
  names them. Sensor input axes are the rows of ``H`` (n, 3).
- Time: seconds, float64, monotonic within a recording; ``t`` shape (N,).
- Arrays: one sample of n sensors is shape (n,); a block of N samples is (N, n).
- Sensors are numbered from 1 in files, CLI and messages, from 0 in arrays.

``fdi`` imports none of the other rimu packages.
"""

from fdi.answer import Answer, BlockResult, Event
from fdi.calfile import (
    CALIBRATION_SCHEMA,
    AllanTable,
    Calibration,
    SensorCal,
    SensorSet,
    calibration_from_dict,
    load_calibration,
)
from fdi.effects import Compensator
from fdi.effects_monitor import CompensatedMonitor
from fdi.envelope import EnvelopeSettings, EnvelopeTracker, reason_names
from fdi.errors import CalibrationError, ConfigError, FileFormatError, ReplayError, RimuError
from fdi.geometry import Configuration, cone6, load_configuration, tetrad, triad
from fdi.monitor import Monitor
from fdi.parity import calibrated_axes, isolability, parity_matrix, reconstruction_matrix
from fdi.settings import MonitorSettings, Thresholds, load_thresholds

__all__ = [
    "CALIBRATION_SCHEMA",
    "AllanTable",
    "Answer",
    "BlockResult",
    "Calibration",
    "CalibrationError",
    "CompensatedMonitor",
    "Compensator",
    "ConfigError",
    "Configuration",
    "EnvelopeSettings",
    "EnvelopeTracker",
    "Event",
    "FileFormatError",
    "Monitor",
    "MonitorSettings",
    "ReplayError",
    "RimuError",
    "SensorCal",
    "SensorSet",
    "Thresholds",
    "calibrated_axes",
    "calibration_from_dict",
    "cone6",
    "isolability",
    "load_calibration",
    "load_configuration",
    "load_thresholds",
    "parity_matrix",
    "reason_names",
    "reconstruction_matrix",
    "tetrad",
    "triad",
]
