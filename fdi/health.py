"""Health checks independent of parity: stale, non-finite, range limit, stuck.

They isolate a sensor at once, without waiting for the parity test (PX4's
``DataValidator`` does the same: timeout, 100 identical values = stale/stuck).

- ``"stale"``: no valid sample for longer than ``stale_timeout_s`` (checked at each sample
  the sensor misses).
- ``"nonfinite"``: NaN or ±inf with ``valid = True``.
- ``"range"``: a raw value at or beyond the raw range, or a compensated value at or beyond
  ``max_input`` (the sensor's measuring range): both become one pair of raw bounds
  ``lo < u < hi`` per sensor, so that the check costs one chained comparison.
- ``"stuck"``: ``stuck_count`` identical consecutive raw values.

:func:`fdi.kernel.health_checks` runs them per sample inside the compiled monitor kernel;
this module computes the limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fdi.settings import MonitorSettings

__all__ = ["HealthLimits", "health_limits", "value_reason"]

DEFAULT_MAX_INPUT = {"gyro": 35.0, "accel": 160.0}
"""Measuring range used when none is configured: 2000 °/s, 16 g (SI)."""


@dataclass(frozen=True)
class HealthLimits:
    """Per-sensor raw bounds and the counting limits.

    Attributes
    ----------
    lo, hi : tuple of float
        Open raw interval of plausible values per sensor.
    stuck_count : int
    stale_timeout_s : float
    """

    lo: tuple[float, ...]
    hi: tuple[float, ...]
    stuck_count: int
    stale_timeout_s: float


def health_limits(settings: MonitorSettings, kind: str, sf: np.ndarray,
                  bias: np.ndarray) -> HealthLimits:
    """Raw bounds from the measuring range (SI) and the optional raw range."""
    max_in = settings.max_input if settings.max_input is not None else DEFAULT_MAX_INPUT[kind]
    lo, hi = [], []
    for s, b in zip(np.asarray(sf, float), np.asarray(bias, float), strict=True):
        a1, a2 = (b - max_in) / s, (b + max_in) / s      # y = s·u − b = ±max_in
        low, high = min(a1, a2), max(a1, a2)
        if settings.raw_range is not None:
            low = max(low, float(settings.raw_range[0]))
            high = min(high, float(settings.raw_range[1]))
        lo.append(float(low))
        hi.append(float(high))
    return HealthLimits(tuple(lo), tuple(hi), int(settings.stuck_count),
                        float(settings.stale_timeout_s))


def value_reason(v: float, lo: float, hi: float) -> str | None:
    """``"nonfinite"``/``"range"`` for a bad raw value, None when it is plausible."""
    if lo < v < hi:
        return None
    return "nonfinite" if not math.isfinite(v) else "range"
