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

:meth:`fdi.monitor.Monitor.step` runs the same comparisons inline per sample (speed);
:func:`first_trigger` finds the first sample of a block at which any of them fires. They
decide identically: comparisons and counting only, no arithmetic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fdi.settings import MonitorSettings

__all__ = ["HealthLimits", "first_trigger", "health_limits", "value_reason"]

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


def first_trigger(X: np.ndarray, lo: np.ndarray, hi: np.ndarray, last: np.ndarray,
                  run0: np.ndarray, stuck_count: int) -> tuple[int, np.ndarray | None]:
    """First row of a block (every sample valid) at which a value or stuck check fires.

    Parameters
    ----------
    X : ndarray, shape (L, m)
        Raw values of the m checked sensors.
    lo, hi : ndarray, shape (m,)
        Raw bounds.
    last : ndarray, shape (m,)
        Each sensor's previous raw value.
    run0 : ndarray of int, shape (m,)
        Identical consecutive values up to and including ``last``.
    stuck_count : int

    Returns
    -------
    row : int
        First triggering row, L when none.
    run : ndarray of int, shape (L, m), or None
        Identical-run length at each row as the scalar path counts it (None: every run is
        1, no value repeats).
    """
    L = X.shape[0]
    if (lo < X.min(axis=0)).all() and (X.max(axis=0) < hi).all():
        trig = np.zeros(L, bool)                            # fast path (NaN fails it)
    else:
        trig = (~((lo < X) & (X < hi))).any(axis=1)
    eq = np.empty(X.shape, bool)
    eq[0] = X[0] == last
    np.equal(X[1:], X[:-1], out=eq[1:])
    run = None
    if eq.any():
        ii = np.arange(L)[:, None]
        lastne = np.maximum.accumulate(np.where(eq, -1, ii), axis=0)
        run = np.where(lastne < 0, run0[None, :] + ii + 1, ii - lastne + 1)
        trig |= (run >= stuck_count).any(axis=1)
    return (int(np.argmax(trig)) if trig.any() else L), run
