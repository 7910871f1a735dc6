"""The one exception tree of rimu.

Every error a user can cause (a bad file, a bad option, a sequence that cannot be
calibrated) is a :class:`RimuError`; the CLI prints it as one line and exits non-zero.
The streaming runtime never raises on bad *numbers*: it marks the sensor unhealthy.
"""

from __future__ import annotations

__all__ = ["CalibrationError", "ConfigError", "ExportError", "FileFormatError", "ReplayError",
           "RimuError"]


class RimuError(Exception):
    """Base class of every error rimu raises on purpose."""


class ConfigError(RimuError):
    """A configuration (geometry, thresholds, option) is invalid."""


class FileFormatError(RimuError):
    """A file does not match its documented format.

    Parameters
    ----------
    path : str
        The file.
    message : str
        What was expected and what was found.
    line : int, optional
        1-based line (or row / record) number.
    field : str, optional
        The field, column or key.
    step : int, optional
        The 1-based test-sequence step, for session files.
    """

    def __init__(self, path: str, message: str, *, line: int | None = None,
                 field: str | None = None, step: int | None = None) -> None:
        self.path = str(path)
        self.line = line
        self.field = field
        self.step = step
        self.detail = message
        where = self.path
        if line is not None:
            where += f":{line}"
        parts = [where]
        if step is not None:
            parts.append(f"step {step}")
        if field is not None:
            parts.append(f"field '{field}'")
        super().__init__(", ".join(parts) + ": " + message)


class CalibrationError(RimuError):
    """The data cannot give the requested calibration (e.g. rank-deficient R)."""


class ReplayError(RimuError):
    """A log could not be replayed (in strict mode: any corrupt frame or record)."""


class ExportError(RimuError):
    """A calibration or thresholds file holds something the exported C monitor cannot carry
    faithfully (``rimu export c``); the message names it."""
