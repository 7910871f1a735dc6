"""The time stamps of a flight folder: the rate they show, their gaps and duplicates.

A flight folder states its sample rate in its manifest; the monitor's windows, the noise
per sample and the envelope all count samples at that rate. :func:`check_rate` refuses a
manifest whose rate the time stamps contradict (500 Hz stated over 50 Hz data), and
:func:`time_base` counts what a reader must say rather than pass over in silence: gaps
(intervals longer than :data:`GAP_PERIODS` sample periods), duplicate time stamps and rows
that hold no finite value. :func:`replay.flight_io.load_flight_dir` does both for every
command that reads a flight folder and logs one warning line with the counts; the commands
that write JSON carry :meth:`TimeBase.to_dict` in it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from fdi.errors import FileFormatError

__all__ = ["GAP_PERIODS", "RATE_TOLERANCE", "TimeBase", "check_rate", "time_base",
           "with_time_base"]

GAP_PERIODS = 2.5
"""An interval between consecutive time stamps longer than this many sample periods is a
gap (at least one sample missing, beyond the jitter of a real logger)."""
RATE_TOLERANCE = 1.5
"""Largest factor between the manifest's rate and the rate the time stamps show (both the
median interval's and the mean over the span) before the manifest is refused."""


@dataclass(frozen=True)
class TimeBase:
    """What the time stamps of a flight hold beyond a regular grid.

    Attributes
    ----------
    samples : int
        Rows.
    span_s : float
        Last minus first time stamp (s).
    gaps : int
        Intervals longer than :data:`GAP_PERIODS` sample periods.
    gap_total_s, gap_longest_s : float
        Their summed length beyond one period, and the longest interval (s); 0 without gaps.
    gap_first_t : float or None
        Time stamp (s) where the first gap starts.
    duplicates : int
        Rows whose time stamp equals the previous row's.
    empty_rows : int
        Rows in which no sensor holds a finite value (a command that needs values drops them).
    """

    samples: int
    span_s: float
    gaps: int = 0
    gap_total_s: float = 0.0
    gap_longest_s: float = 0.0
    gap_first_t: float | None = None
    duplicates: int = 0
    empty_rows: int = 0

    @property
    def clean(self) -> bool:
        """No gap, no duplicate time stamp, no empty row."""
        return not (self.gaps or self.duplicates or self.empty_rows)

    @property
    def covered_s(self) -> float:
        """Span minus the gaps (s): the time the samples really cover."""
        return max(self.span_s - self.gap_total_s, 0.0)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (times in s)."""
        return {"samples": self.samples, "span_s": self.span_s, "covered_s": self.covered_s,
                "gaps": self.gaps, "gap_total_s": self.gap_total_s,
                "gap_longest_s": self.gap_longest_s, "gap_first_t_s": self.gap_first_t,
                "duplicate_time_stamps": self.duplicates, "empty_rows": self.empty_rows,
                "gap_periods": GAP_PERIODS}

    def text(self) -> str:
        """One line: what was found (empty when clean)."""
        parts = []
        if self.gaps:
            parts.append(f"{self.gaps} gap{'s' * (self.gaps != 1)} in the time stamps "
                         f"(longer than {GAP_PERIODS:g} sample periods; {self.gap_total_s:.4g} s "
                         f"in all, longest {self.gap_longest_s:.4g} s, first at t = "
                         f"{self.gap_first_t:.6g} s)")
        if self.duplicates:
            parts.append(f"{self.duplicates} duplicate time stamp"
                         f"{'s' * (self.duplicates != 1)}")
        if self.empty_rows:
            parts.append(f"{self.empty_rows} row{'s' * (self.empty_rows != 1)} without any "
                         "finite value (dropped where values are needed)")
        return "; ".join(parts)


def time_base(t: np.ndarray, raw: np.ndarray, sample_rate_hz: float) -> TimeBase:
    """Count the gaps, duplicate time stamps and empty rows of a flight.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Time stamps (s), non-decreasing.
    raw : ndarray, shape (N, n)
        Sensor values (NaN where missing).
    sample_rate_hz : float
        The stated rate.
    """
    t = np.asarray(t, float)
    n = int(t.shape[0])
    if n == 0:
        return TimeBase(0, 0.0)
    dt = np.diff(t)
    period = 1.0 / float(sample_rate_hz)
    big = np.flatnonzero(dt > GAP_PERIODS * period)
    raw = np.asarray(raw, float)
    empty = int(np.count_nonzero(~np.isfinite(raw).any(axis=1))) if raw.size else 0
    return TimeBase(
        samples=n, span_s=float(t[-1] - t[0]), gaps=int(big.size),
        gap_total_s=float(np.sum(dt[big] - period)) if big.size else 0.0,
        gap_longest_s=float(dt[big].max()) if big.size else 0.0,
        gap_first_t=float(t[big[0]]) if big.size else None,
        duplicates=int(np.count_nonzero(dt == 0)), empty_rows=empty)


def check_rate(sample_rate_hz: float, t: np.ndarray, manifest: str) -> None:
    """Refuse a stated rate the time stamps contradict.

    The rate of the median positive interval and the mean rate over the span (rows − 1
    over the span) are compared with the stated one; when both differ from it by more than
    a factor :data:`RATE_TOLERANCE` the manifest is refused (quantised stamps move the
    median, gaps move the mean: real logs pass on one of them).

    Raises
    ------
    FileFormatError
        Naming the manifest's ``sample_rate_hz`` and both rates the stamps show.
    """
    t = np.asarray(t, float)
    dt = np.diff(t)
    pos = dt[dt > 0]
    if pos.size < 2:
        return
    median_hz = 1.0 / float(np.median(pos))
    span = float(t[-1] - t[0])
    mean_hz = (t.size - 1) / span if span > 0 else math.inf
    fs = float(sample_rate_hz)

    def off(x: float) -> bool:
        return not (fs / RATE_TOLERANCE <= x <= fs * RATE_TOLERANCE)

    if off(median_hz) and off(mean_hz):
        raise FileFormatError(manifest, f"{fs:g} Hz, but the time stamps show {median_hz:.4g} "
                              f"Hz (median interval) and {mean_hz:.4g} Hz (rows over the "
                              "span): correct the manifest's rate", field="sample_rate_hz")


def with_time_base(cal: Any, flight: Any) -> Any:
    """A calibration made from ``flight`` with ``extra["time_base"]`` recording the flight's
    gaps, duplicates and empty rows (:meth:`TimeBase.to_dict`); unchanged for a clean one
    (its file and fingerprint stay as they were)."""
    from dataclasses import replace

    tb = flight.time_base
    if tb.clean:
        return cal
    return replace(cal, extra={**dict(cal.extra), "time_base": tb.to_dict()})
