"""fdi: geometry, parity space and the streaming fault detection and isolation runtime.

Imported as ``fdi`` (``from fdi import Monitor``); rimu installs the packages ``fdi``,
``calibration``, ``thresholds``, ``replay`` and the command line ``rimu``.

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

from fdi.lazy import attach

_EXPORTS = {
    "AllanTable": "fdi.calfile",
    "Answer": "fdi.answer",
    "BlockResult": "fdi.answer",
    "CALIBRATION_SCHEMA": "fdi.calfile",
    "Calibration": "fdi.calfile",
    "CalibrationExtras": "fdi.extras",
    "CalibrationError": "fdi.errors",
    "CompensatedMonitor": "fdi.effects_monitor",
    "Compensator": "fdi.effects",
    "ConfigError": "fdi.errors",
    "Configuration": "fdi.geometry",
    "EnvelopeSettings": "fdi.envelope",
    "EnvelopeTracker": "fdi.envelope",
    "Event": "fdi.answer",
    "ExportError": "fdi.errors",
    "FileFormatError": "fdi.errors",
    "Monitor": "fdi.monitor",
    "MonitorSettings": "fdi.settings",
    "ReplayError": "fdi.errors",
    "RimuError": "fdi.errors",
    "SensorCal": "fdi.calfile",
    "SensorSet": "fdi.calfile",
    "Thresholds": "fdi.settings",
    "calibrated_axes": "fdi.parity",
    "calibration_from_dict": "fdi.calfile",
    "cone6": "fdi.geometry",
    "isolability": "fdi.parity",
    "load_calibration": "fdi.calfile",
    "load_configuration": "fdi.geometry",
    "load_thresholds": "fdi.settings",
    "parity_matrix": "fdi.parity",
    "reason_names": "fdi.envelope",
    "reconstruction_matrix": "fdi.parity",
    "tetrad": "fdi.geometry",
    "triad": "fdi.geometry",
}
"""Public name → module defining it (imported on first use, PEP 562)."""
__all__ = [
    "CALIBRATION_SCHEMA",
    "AllanTable",
    "Answer",
    "BlockResult",
    "Calibration",
    "CalibrationError",
    "CalibrationExtras",
    "CompensatedMonitor",
    "Compensator",
    "ConfigError",
    "Configuration",
    "EnvelopeSettings",
    "EnvelopeTracker",
    "Event",
    "ExportError",
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

__getattr__, __dir__ = attach(__name__, _EXPORTS)
