"""rimu: fault detection and isolation for redundant inertial measurement units.

This package holds only the command-line interface; the library lives in the top-level
packages ``fdi`` (runtime), ``calibration``, ``thresholds`` and ``replay``.
"""

__all__ = ["__version__"]

__version__ = "0.1.0"
